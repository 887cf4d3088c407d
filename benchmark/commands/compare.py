"""``uavbench compare A B``: the same units of two workdirs (trained in another precision, on
another device or CPU kind) compared on the same frames, paired by variant and seed
(:mod:`benchmark.runner.compare`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "compare two workdirs' units on the same frames: paired differences, equivalence"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("a", type=Path, help="workdir A (runs/<profile>, with units/)")
    parser.add_argument("b", type=Path, help="workdir B, the same variants trained another way")
    parser.add_argument(
        "--split",
        default="standard/val",
        help="split compared (default "
        "standard/val: no choice or verdict is made on it by the report)",
    )
    parser.add_argument("--a-name", default="A", help="name of A in the output (e.g. fp32)")
    parser.add_argument("--b-name", default="B", help="name of B in the output (e.g. bf16)")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="write the markdown here (and the table beside it as .csv); default: print it",
    )
    parser.add_argument(
        "--n-boot", type=int, default=None, help="bootstrap replicates (default: the claims')"
    )
    parser.add_argument(
        "--reports",
        type=Path,
        nargs=2,
        metavar=("A_REPORTS", "B_REPORTS"),
        default=None,
        help="the two reproductions' report directories (reports/<profile>): add the claims "
        "whose verdicts differ between them",
    )


def run(args: argparse.Namespace) -> int:
    from benchmark.runner.claims.evidence import N_BOOT
    from benchmark.runner.compare import (
        compare_markdown,
        compare_units,
        differences_frame,
        verdict_changes_markdown,
    )

    differences, left = compare_units(
        args.a / "units", args.b / "units", args.split, n_boot=args.n_boot or N_BOOT
    )
    text = compare_markdown(differences, left, a_name=args.a_name, b_name=args.b_name,
                            split=args.split)  # fmt: skip
    if args.reports is not None:
        a_report, b_report = (d / "README.md" for d in args.reports)
        text += "\n" + verdict_changes_markdown(
            a_report, b_report, a_name=args.a_name, b_name=args.b_name
        )
    if args.out is None:
        sys.stdout.write(text)
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # written whole, then renamed: an interrupted run leaves the previous files intact
    table = args.out.with_suffix(".csv")
    for path, write in ((table, lambda p: differences_frame(differences).to_csv(p, index=False)),
                        (args.out, lambda p: p.write_text(text))):  # fmt: skip
        tmp = path.with_name(path.name + ".tmp")
        write(tmp)
        tmp.replace(path)
    print(f"wrote {args.out} and {table}")
    return 0
