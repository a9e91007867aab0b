"""Two ``popbench run heldout`` tables of the same problems, row by row, paired: for every row
both hold, B − A per problem (median and mean of the differences with bootstrap 95 % CIs that
resample whole problems, the share of problems where B is lower), for F after the consensus,
the robots' local F and ATE (popbench.harness.heldout.paired).

    python benchmarks/compare_heldout.py runs/A/heldout.csv runs/B/heldout.csv [--names A,B]

Used for the choice of the environment's step rule (docs/environment.md, "The step rule").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from popbench.harness.heldout import paired


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a", type=Path)
    parser.add_argument("b", type=Path)
    parser.add_argument("--names", default="A,B", help="the two tables' names, A,B")
    args = parser.parse_args()
    name_a, name_b = args.names.split(",")
    frame_a, frame_b = pd.read_csv(args.a), pd.read_csv(args.b)
    rows = [row for row in frame_a["row"].unique() if row in set(frame_b["row"])]
    frame = pd.concat(
        [
            frame_a.assign(row=frame_a["row"] + f" ({name_a})"),
            frame_b.assign(row=frame_b["row"] + f" ({name_b})"),
        ]
    )
    pairs = tuple((f"{row} ({name_b})", f"{row} ({name_a})") for row in rows)
    table = paired(frame, pairs)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.to_string(index=False, float_format=lambda value: f"{value:.4g}"))


if __name__ == "__main__":
    main()
