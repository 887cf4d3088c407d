"""Paper Table 6 (``kind: cost`` specs) in Markdown: size, MFLOPs and CPU latency beside the
paper's, from the measurements taken before the report (``benchmark.runner.execute.costs``,
which caches them in ``<workdir>/costs/``).
"""

from __future__ import annotations

from pathlib import Path

from benchmark.runner.execute.costs import CostRow
from benchmark.runner.plan.specs import TableSpec, default_spec_dir
from benchmark.runner.report.tables import load_paper, paper_value


def cost_table(spec: TableSpec, rows: list[CostRow], cache_dir: Path | None = None) -> str:
    """Table 6 in Markdown from its measured ``rows``
    (:func:`~benchmark.runner.execute.costs.measure_costs`) beside the paper's values;
    ``cache_dir`` the measurements' cache (named in the note), None: not cached."""
    paper = load_paper(default_spec_dir().parent / "paper_tables.csv")
    threads = sorted({int(r["threads"]) for *_, r in rows})
    lines = [
        f"## {spec.title}", "",
        "Size = float32 parameters (4 bytes each, 1 MB = 1e6 bytes); FLOPs counted with "
        "`torch.utils.flop_counter` (2 per multiply-add) for one pair at batch 1 in inference "
        "(no auxiliary heads); latency = median of 10 CPU forward passes at batch 1 "
        f"({'/'.join(map(str, threads))} torch thread(s)) on this machine.", "",
        "| model | config | params | size MB paper | size MB ours | MFLOPs paper | MFLOPs ours | "
        "of which dense layers | median latency ms |",
        "|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for label, paper_model, name, r in rows:
        ps = paper_value(paper, spec.paper_table, None, paper_model, "size_MB")
        pf = paper_value(paper, spec.paper_table, None, paper_model, "MFLOPs")
        lines.append(
            f"| {label} | {name} | {r['parameters']:,} | {ps:.2f} | {r['size_mb']:.2f} | "
            f"{pf:.2f} | {r['mflops_inference']:.1f} | {r['mflops_dense_inference']:.1f} | "
            f"{r['latency_ms']:.1f} |"
        )
    note = (
        "The paper does not say how it counts MFLOPs. Two 224 px GoogLeNet passes cost about "
        "3.2 G multiply-adds (6.3 GFLOPs) by any count, so its 24.43 and 90.96 MFLOPs cannot be "
        "full forward passes; our fully connected layers alone come close to them (Re-Net 25.2 vs "
        "24.43 at the paper config), so Table 6 most likely counts the dense layers only. The "
        "sizes match ours within 1% (the lattice decoder width, unpublished, was chosen for that)."
    )
    cached = "" if cache_dir is None else (
        f" Measurements are cached per model, input size, torch version and machine "
        f"(`{Path(cache_dir).name}/` in the work directory) and reused by a rerun."
    )  # fmt: skip
    lines += ["", note + cached]
    return "\n".join(lines) + "\n"
