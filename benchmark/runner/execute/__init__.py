"""Running the planned units: what a worker runs (``worker``), how it logs its training run
(``live``), the executors (``pool``, the default, and ``ray_executor``) and the non-learned
reference rows evaluated like models (``reference_rows``). Imports ``runner.plan`` only."""
