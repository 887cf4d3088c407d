"""uavbench: absolute UAV pose estimation from a pre-loaded satellite image.

The package is laid out along the pipeline:
``geometry`` -> ``sim`` -> ``data`` -> ``models`` -> ``training``/``evaluation`` -> ``runner``
-> ``tracking`` / ``reports``. Imports only point down that list.
"""

__version__ = "0.1.0"
