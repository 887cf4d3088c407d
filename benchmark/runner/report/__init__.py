"""Writing what was decided: Markdown tables beside the paper's (``tables``, ``sweeps``), the
report directory (``outputs``), Table 6's costs, provenance, the tracking logbook and its texts
(``logbook``, ``descriptions``). The last floor of the runner: may import every other one."""
