"""Deciding from the units' predictions: per-frame errors (``frame_errors``), intervals
(``spread``), the paired-statistics machinery (``evidence``), the claims themselves (``paper``,
``ranking``, ``satellite``, gathered in report order by ``all_claims``), claims beside tables
kept from an earlier run (``earlier``), the generated findings and the dataset audit. Imports
``runner.plan`` and ``runner.execute``, never ``runner.report``."""
