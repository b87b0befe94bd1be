"""One finding as ``findings.json`` holds it (docs/evaluation.md, The paper's findings): the
per-seed ratios' geometric mean, its interval and verdict (:func:`finding_item`), replicated on
both halves of the seeds (:func:`replicate`: ``reproduced`` or ``contradicted`` only when both
halves say so on their own), and the numbers as text. The findings themselves:
:mod:`qsls.pipeline.fly.paired` (1, 2, 4) and :mod:`qsls.pipeline.fly.bound_finding` (3)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pandas as pd

from qsls.pipeline.fly.paper import halves, replicated
from qsls.pipeline.fly.stats import LEVEL, Direction, Interval, ratio_interval, verdict

FINDINGS_FILE = "findings.json"
"""The findings document: ``{n_seeds, findings: [item, ...], ...}``
(:func:`qsls.pipeline.fly.paired.paired_findings`)."""


def num(v: float) -> str:
    return f"{v:.3g}" if math.isfinite(v) else "n/a"


def interval_text(iv: Interval) -> str:
    lo, hi = iv.ci
    none = "(one seed: no interval)" if iv.n == 1 else "(no interval)"
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{num(iv.mean)} {none}"
    ci = f"[{num(lo)}, {num(hi)}]"
    return f"{num(iv.mean)} {ci}"


def finding_item(
    fid: int,
    claim: str,
    definition: str,
    per_seed: pd.Series,
    direction: Direction,
    detail: str,
    mechanism: Callable[[], str] | None = None,
    level: float = LEVEL,
    **extra: Any,
) -> dict[str, Any]:
    """One finding: the per-seed ratios' geometric mean, interval (at ``level``) and verdict
    (against 1)."""
    iv = ratio_interval(per_seed.to_numpy(float), level)
    v = verdict(iv, 1.0, direction)
    item: dict[str, Any] = {
        "id": fid,
        "claim": claim,
        "effect": float(iv.mean) if math.isfinite(iv.mean) else None,
        "ci": iv.ci,
        "verdict": v,
        "n_seeds": iv.n,
        "level": level,
        "effect_definition": definition,
        "paper_direction": f"{'>' if direction == 'greater' else '<'} 1",
        "per_seed": {str(int(s)): float(r) for s, r in per_seed.items()},
        "detail": f"effect {interval_text(iv)} over {iv.n} seeds: {v}; {detail}",
    }
    if mechanism is not None:
        item["why"] = mechanism()
    if v != "reproduced" and mechanism is not None:
        item["mechanism"] = item["detail"] + "; why: " + item["why"]
    return {**item, **extra}


def replicate(
    build: Callable[[pd.DataFrame, str], dict[str, Any] | None],
    flights: pd.DataFrame,
    whole: bool = True,
) -> dict[str, Any] | None:
    """``build`` on all seeds, on each half of the seeds (the replication split) and, when
    ``whole``, on the whole flight's metrics; the verdict is the halves' (module docstring)."""
    item = build(flights, "circle")
    if item is None:
        return None
    seeds = flights["seed"].unique() if len(flights) else []
    hs = []
    for half in halves(seeds):
        sub = build(flights[flights["seed"].isin(half)], "circle") if half else None
        hs.append(
            {
                "seeds": half,
                "effect": sub["effect"] if sub else None,
                "ci": sub["ci"] if sub else [None, None],
                "verdict": sub["verdict"] if sub else "inconclusive",
            }
        )
    final = replicated(str(hs[0]["verdict"]), str(hs[1]["verdict"]))
    item["verdict_all_seeds"] = item["verdict"]
    item["verdict"] = final
    item["halves"] = hs

    def span(h: dict[str, Any]) -> str:
        s = h["seeds"]
        return f"seeds {s[0]} to {s[-1]}" if s else "no seeds"

    def eff(h: dict[str, Any]) -> str:
        lo, hi = h["ci"]
        e = "n/a" if h["effect"] is None else num(float(h["effect"]))
        return e + (f" [{num(lo)}, {num(hi)}]" if lo is not None and hi is not None else "")

    item["detail"] += (
        f"; on all seeds: {item['verdict_all_seeds']}; replication: "
        + ", ".join(f"{span(h)} {eff(h)} {h['verdict']}" if h["seeds"] else NO_HALF for h in hs)
        + f", so {final}"
    )
    if whole and "metric" in item and str(item["metric"]).endswith("_circle"):
        w = build(flights, "flight")
        if w is not None:
            item["whole_flight"] = {k: w[k] for k in ("effect", "ci", "verdict", "metric")}
            item["detail"] += (
                f"; whole flight (take-off included, unsmoothed): {eff(w)} {w['verdict']}"
            )
    if final != "reproduced":
        why = item.get("why")
        item["mechanism"] = item["detail"] + (f"; why: {why}" if why else "")
    else:
        item.pop("mechanism", None)
    return item


NO_HALF = "one half without seeds (too few flights to split), not tested"
"""A half of the seeds that holds none: said in words, never as a verdict with no effect."""
