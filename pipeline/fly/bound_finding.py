"""Finding 3, the bound (docs/evaluation.md, The paper's findings): every controller's
perception error stays below the theoretical bound, read two ways.

- qsls's certificate decides the verdict: every assumption of the guarantee on the robust
  controllers' own flights, every estimator's (:func:`finding3_assumptions`: ``contradicted``
  if any flight breaks an assumption or the bound, a counterexample to "every flight" that
  needs no replication; ``reproduced`` only when both halves of the seeds have flights and none
  breaks), with the share and its Clopper-Pearson interval, each failing flight named; without
  the assumption table ``r_i = max_flights max_k ||e_k|| / gamma`` per seed
  (:func:`finding3_bound`);
- the paper's strict bound ``R0 / (1 - S ||Phi_xe||)`` (undefined when ``S ||Phi_xe|| >= 1``;
  :mod:`qsls.pipeline.fly.paper`) is reported beside it with its own verdict
  (:func:`strict_bounds`, :func:`strict_bound_text`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.fly.items import FINDINGS_FILE, NO_HALF, finding_item, num, replicate
from qsls.pipeline.fly.paper import PAPER_BOUND_SIM, PAPER_S_SIM, halves, replicated, strict_bound
from qsls.pipeline.premise.honest import clopper_pearson


def finding3_bound(
    checks: pd.DataFrame, flights: pd.DataFrame, ref_name: str | None
) -> dict | None:
    """Finding 3 without the assumption table (module docstring): the largest max ||e|| /
    gamma per seed."""
    if checks.empty:
        return None
    seed_of = dict(zip(flights["flight"], flights["seed"], strict=True))
    checks = checks[checks["flight"].isin(seed_of)]
    checks = checks.assign(seed=checks["flight"].map(seed_of))
    nominal = "gamma_nominal" in checks and checks["gamma_nominal"].notna().any()
    if nominal:
        rows = checks[(checks["controller"] == checks["flown_by"]) & checks["has_guarantee"]]
        rows = rows[np.isfinite(rows["gamma_nominal"].astype(float))]
        ratio = rows["max_error_norm"].astype(float) / rows["gamma_nominal"].astype(float)
        basis = "gamma_nominal (the theorem, own flights of the certified controllers)"
    else:
        rows = checks[checks["controller"] == ref_name]
        ratio = rows["max_ratio_strict"].astype(float)
        basis = f"gamma_strict of {ref_name} on every flight (the paper's comparison)"
    if rows.empty:
        return None
    frame = pd.DataFrame({"seed": rows["seed"], "ratio": ratio, "by": rows["flown_by"]})
    for col in ("frac_premise_holds", "max_premise_ratio", "condition"):
        if col in rows:
            frame[col] = rows[col]
    per_seed = frame.groupby("seed")["ratio"].max()
    by = frame.groupby("by")["ratio"].max().sort_values()
    detail = f"bound: {basis}; worst max ||e|| / gamma per controller: " + ", ".join(
        f"{c} {num(v)}" for c, v in by.items()
    )

    def why() -> str:
        worst = frame.loc[frame["ratio"].idxmax()]
        cond = f", {worst['condition']}" if "condition" in frame else ""
        text = (
            f"the worst flight ({worst['by']}{cond}, seed {int(worst['seed'])}) reaches "
            f"{num(float(worst['ratio']))} x gamma; the bound holds only under its premise "
            "||e|| <= eps_e + S d (the certificate's eps_e and S)"
        )
        if "frac_premise_holds" in frame and "max_premise_ratio" in frame:
            text += (
                f", which holds on {100 * float(frame['frac_premise_holds'].mean()):.1f}% of "
                f"the samples of these flights, the error reaching "
                f"{num(float(frame['max_premise_ratio'].max()))} x (eps_e + S d)"
            )
        return text

    return finding_item(
        3,
        "every controller's perception error stays below the bound",
        "per seed, the largest max ||e|| / gamma over the flights of that seed (< 1: below)",
        per_seed,
        "less",
        detail,
        why,
        bound=("gamma_nominal" if nominal else "gamma_strict"),
    )


def finding3_assumptions(assumptions: pd.DataFrame) -> dict | None:
    """Finding 3 on the robust controllers' own flights (every estimator's), read through
    every assumption of the guarantee (:mod:`qsls.pipeline.evaluate.assumptions`):
    ``contradicted`` if any flight breaks an assumption or the bound, with the share of such
    flights and its Clopper-Pearson 95% interval, each failing flight named; ``reproduced``
    only when none does. The paper's claim is about its robust controllers, whatever their
    status here: the detail counts the failures per status (a ``relaxed`` certificate promises
    nothing) and those flown outside their certificate's calibration."""
    if assumptions is None or not len(assumptions):
        return None
    ok = assumptions["assumptions_hold"].astype(bool) & assumptions["bound_held"].astype(bool)
    bad = assumptions[~ok]
    n, k = len(assumptions), len(bad)
    lo, hi = clopper_pearson(k, n)
    named = [f"{r.flight} ({r.first_failed or 'bound'})" for r in bad.itertuples()]
    per_est = ""
    if "estimator" in assumptions:
        parts = []
        for est, g in assumptions.groupby("estimator", sort=False):
            g_ok = g["assumptions_hold"].astype(bool) & g["bound_held"].astype(bool)
            parts.append(f"{est} {int((~g_ok).sum())} of {len(g)}")
        per_est = " (" + ", ".join(parts) + ")"
    by_status = ""
    if "status" in assumptions:
        parts = [
            f"{st} {int((~ok[g.index]).sum())} of {len(g)}"
            for st, g in assumptions.groupby("status", sort=False)
        ]
        by_status = "; by status: " + ", ".join(parts)
    outside = ""
    if "outside_calibration" in assumptions:
        away = int((bad["outside_calibration"].fillna("").astype(str) != "").sum())
        outside = f"; {away} of the {k} outside their certificate's calibration" if away else ""
    detail = (
        f"{k} of {n} flights of the robust controllers{per_est} break an assumption or the "
        f"bound (share {k / n:.3g}, 95% Clopper-Pearson {lo:.3g} to {hi:.3g}){by_status}"
        f"{outside}" + (": " + _names_all(named) if k else "")
    )
    item = {
        "id": 3,
        "claim": "every controller's perception error stays below the bound",
        "effect": k / n,
        "ci": [lo, hi],
        "verdict": "contradicted" if k else "reproduced",
        "n_flights": n,
        "n_violating": k,
        "violating": named,
        "level": 0.95,
        "effect_definition": "share of the robust controllers' own flights (certified or "
        "relaxed: the detail counts each) on which an assumption of the guarantee, or the bound "
        "itself, fails (the paper: 0)",
        "paper_direction": "= 0",
        "detail": detail,
        "bound": "every assumption (docs/guarantee.md)",
    }
    if k:
        item["mechanism"] = detail
    return item


def _names_all(items: Sequence[str], most: int = 12) -> str:
    more = f" and {len(items) - most} more ({FINDINGS_FILE} lists all)" if len(items) > most else ""
    return ", ".join(items[:most]) + more


def strict_bounds(
    controllers: Sequence[dict[str, Any]], flights: pd.DataFrame
) -> list[dict[str, Any]]:
    """Per controller with a premise (``{name, status, R0, S, norm_phi_xe}``), the paper's
    strict bound ``R0 / (1 - S ||Phi_xe||)`` with the controller's own S (``None``: undefined,
    ``S ||Phi_xe|| >= 1``) and at the paper's ``S = 11.7``, against the largest ``||e||``
    over the controller's own flights."""
    out = []
    for c in controllers:
        S, n, R0 = float(c["S"]), float(c["norm_phi_xe"]), float(c["R0"])
        mine = flights[flights["controller"] == c["name"]] if len(flights) else flights
        worst = float(mine["perception_error_max"].max()) if len(mine) else math.nan
        b = strict_bound(R0, S, n)
        bp = strict_bound(R0, PAPER_S_SIM, n)
        out.append(
            {
                "controller": c["name"],
                "status": c.get("status"),
                "R0": R0,
                "S": S,
                "norm_phi_xe": n,
                "norm_phi_ue": c.get("norm_phi_ue"),
                "S_norm_phi_xe": S * n,
                "bound": b,
                "max_error": worst,
                "max_error_over_bound": worst / b if b is not None and b > 0 else None,
                "paper_S": PAPER_S_SIM,
                "paper_S_norm_phi_xe": PAPER_S_SIM * n,
                "bound_at_paper_S": bp,
            }
        )
    return out


def strict_bound_text(rows: Sequence[dict[str, Any]]) -> tuple[str, str]:
    """``(verdict, text)`` of the paper's strict bound over ``rows`` (:func:`strict_bounds`):
    ``reproduced`` when every defined bound holds on its controller's flights, ``contradicted``
    when one does not, ``undefined`` when no controller has one."""
    if not rows:
        return "undefined", ""
    parts, defined, broken = [], 0, 0
    for r in rows:
        if r["bound"] is None:
            parts.append(
                f"{r['controller']}: S {num(r['S'])} x ||Phi_xe|| {num(r['norm_phi_xe'])} = "
                f"{num(r['S_norm_phi_xe'])} >= 1, undefined"
            )
            continue
        defined += 1
        ratio = r["max_error_over_bound"]
        broken += ratio is not None and ratio >= 1
        parts.append(
            f"{r['controller']}: S {num(r['S'])}, ||Phi_xe|| {num(r['norm_phi_xe'])}, bound "
            f"{num(r['bound'])}, max ||e|| / bound {num(ratio if ratio is not None else math.nan)}"
        )
    v = "undefined" if not defined else "contradicted" if broken else "reproduced"
    smallest = min(r["norm_phi_xe"] for r in rows)
    paper = (
        f"at the paper's S = {PAPER_S_SIM:g} every controller has S ||Phi_xe|| >= "
        f"{num(PAPER_S_SIM * smallest)} >= 1, so R0 / (1 - S ||Phi_xe||) is undefined: the "
        f"paper's {PAPER_BOUND_SIM:g} cannot come from that formula at S = {PAPER_S_SIM:g}"
        if PAPER_S_SIM * smallest >= 1
        else f"at the paper's S = {PAPER_S_SIM:g} the smallest S ||Phi_xe|| is "
        f"{num(PAPER_S_SIM * smallest)} < 1"
    )
    return v, "the paper's strict bound R0 / (1 - S ||Phi_xe||): " + "; ".join(parts) + (
        f" ({v}); {paper}"
    )


def _assumption_halves(item: dict[str, Any], assumptions: pd.DataFrame) -> dict[str, Any]:
    """Finding 3 on the assumptions, replicated on both halves of the seeds."""
    hs = []
    for half in halves(assumptions["seed"].unique() if "seed" in assumptions else []):
        sub = finding3_assumptions(assumptions[assumptions["seed"].isin(half)]) if half else None
        hs.append(
            {
                "seeds": half,
                "effect": sub["effect"] if sub else None,
                "ci": sub["ci"] if sub else [None, None],
                "verdict": sub["verdict"] if sub else "inconclusive",
            }
        )
    # a failing flight is a counterexample to "every flight": it needs no replication
    final = (
        "contradicted"
        if item["verdict"] == "contradicted"
        else replicated(str(hs[0]["verdict"]), str(hs[1]["verdict"]))
    )
    item["verdict_all_seeds"], item["verdict"], item["halves"] = item["verdict"], final, hs
    item["detail"] += (
        "; replication: "
        + ", ".join(
            f"seeds {h['seeds'][0]} to {h['seeds'][-1]} {h['verdict']}" if h["seeds"] else
            NO_HALF for h in hs
        )
        + f", so {final}"
    )  # fmt: skip
    if final != "reproduced":
        item["mechanism"] = item["detail"]
    else:
        item.pop("mechanism", None)
    return item


def finding3(
    checks: pd.DataFrame,
    flights: pd.DataFrame,
    ref_name: str | None,
    assumptions: pd.DataFrame | None,
    strict: Sequence[dict[str, Any]] = (),
) -> dict[str, Any] | None:
    """Finding 3 both ways (module docstring): qsls's certificate (every assumption, or the
    bound check without the assumption table) decides the verdict; the paper's strict bound
    is reported beside it with its own verdict (``strict_bound``)."""
    if assumptions is not None and len(assumptions):
        item = finding3_assumptions(assumptions)
        if item is not None:
            item = _assumption_halves(item, assumptions)
    else:
        item = replicate(lambda fl, _w: finding3_bound(checks, fl, ref_name), flights, whole=False)
    if item is None:
        return None
    rows = strict_bounds(strict, flights)
    if rows:
        v, text = strict_bound_text(rows)
        item["strict_bound"] = {"verdict": v, "controllers": rows}
        item["detail"] += "; " + text
        if "mechanism" in item:
            item["mechanism"] += "; " + text
    return item
