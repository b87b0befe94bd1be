"""CI: the batch sweep's feasibility column must equal the committed expectation."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

KEYS = ["S", "T", "cost"]


def main(table: str, expected: str) -> int:
    got = pd.read_csv(table)
    want = pd.read_csv(expected)
    keys = [k for k in KEYS if k in want.columns]
    merged = want.merge(got[[*keys, "feasible"]], on=keys, how="left", suffixes=("_expected", ""))
    missing = merged["feasible"].isna()
    changed = ~missing & (merged["feasible"].astype(str) != merged["feasible_expected"].astype(str))
    if len(got) != len(want) or missing.any() or changed.any():
        print(f"sweep feasibility changed: {len(got)} points (expected {len(want)})")
        print(merged[missing | changed].to_string(index=False))
        return 1
    print(
        f"sweep feasibility matches {Path(expected).name}: {len(want)} points, "
        f"{int(want['feasible'].astype(str).eq('True').sum())} feasible"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
