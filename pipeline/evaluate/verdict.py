"""The answer of an evaluation, per controller: does the certified bound hold on every
flight (``||e_k|| <= gamma_k``, DESIGN.md Evaluation), and the worst ratio ``||e|| / gamma``.

Read from the evaluation table (``evaluation.parquet``, one row per flight and controller):
its ``bound_holds`` column when present (else ``max_ratio <= 1``), ``max_ratio``, and
``has_guarantee`` (a controller without a certified bound has no verdict to give).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd


@dataclass(frozen=True)
class Verdict:
    controller: str
    flights: int
    certified: bool  # has a certified bound to check
    holds: bool  # the bound held on every flight (False when not certified)
    worst_ratio: float  # max over flights of max_k ||e_k|| / gamma_k
    worst_flight: str

    @property
    def word(self) -> str:
        if not self.certified:
            return "no certified bound"
        return "holds" if self.holds else "FAILS"

    def line(self) -> str:
        ratio = f"{self.worst_ratio:.3g}" if math.isfinite(self.worst_ratio) else "n/a"
        where = f" ({self.worst_flight})" if self.worst_flight else ""
        return (
            f"{self.controller}: {self.word}, worst ||e||/gamma {ratio}{where}, "
            f"{self.flights} flight{'s' if self.flights != 1 else ''}"
        )


def verdicts(table: pd.DataFrame) -> list[Verdict]:
    """One :class:`Verdict` per controller of an evaluation table, in table order."""
    out: list[Verdict] = []
    if table is None or not len(table) or "controller" not in table:
        return out
    for name, g in table.groupby("controller", sort=False):
        ratio = pd.to_numeric(g["max_ratio"], errors="coerce") if "max_ratio" in g else None
        certified = bool(g["has_guarantee"].all()) if "has_guarantee" in g else True
        if "bound_holds" in g:
            holds = bool(g["bound_holds"].astype(bool).all())
        else:
            holds = ratio is not None and bool((ratio <= 1.0).all())
        worst, flight = math.nan, ""
        if ratio is not None and ratio.notna().any():
            k = ratio.idxmax()
            worst, flight = float(ratio[k]), str(g.loc[k, "flight"]) if "flight" in g else ""
        out.append(Verdict(str(name), len(g), certified, holds and certified, worst, flight))
    return out


def read_verdicts(folder: Path) -> list[Verdict]:
    """The verdicts of an evaluate stage folder (empty when it holds no table)."""
    from qsls.pipeline.evaluate.table import Evaluation

    return verdicts(Evaluation.load(folder).rows) if Evaluation.exists(folder) else []
