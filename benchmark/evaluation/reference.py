"""Not a reference: the constant predictor's label helpers, under their old module name.

The constant predictor lives in :mod:`benchmark.evaluation.constant` ("reference" means only the
non-learned references of ``benchmark/references/``). This module stays for
``benchmark/references/evaluate.py``, which imports ``dataset_labels`` and ``mean_rotation`` from
here and may not change: the sha256 of that folder's source keys the cache of the references'
evaluations. Import :mod:`benchmark.evaluation.constant` everywhere else.
"""

from benchmark.evaluation.constant import dataset_labels, mean_rotation

__all__ = ["dataset_labels", "mean_rotation"]
