"""The paper's four findings paired by seed, with 95% intervals (``fly/findings.json``).

The same seed gives every controller the same emulator randomness, so each finding is one
effect per seed, compared between controllers flown with that seed in the same condition;
:mod:`qsls.pipeline.evaluate.stats` turns the per-seed effects into a mean, a 95% interval
and a verdict (``reproduced`` / ``contradicted`` / ``inconclusive``). Ratios are tested on
their logarithm and reported as geometric means (no effect: 1):

1. regular perception, PD tracks best: ``r_i(c) = rms_track(c, i) / rms_track(pd, i)`` for each
   other controller ``c`` (the paper: ``> 1`` for every ``c``); whether every controller
   tracks is reported beside it.
2. degraded perception, ``l1_robust`` has the lowest perception error:
   ``r_i(c) = rms||e||(c, i) / rms||e||(l1_robust, i)`` for each other ``c`` (the paper: ``> 1``).

"Best of all" is a claim about every pair, so findings 1 and 2 test each pair against 1
with simultaneous 95% intervals (Bonferroni: each at ``1 - 0.05 / m`` for ``m`` pairs):
``reproduced`` when every pair reproduces, ``contradicted`` when any pair contradicts,
``inconclusive`` otherwise; the finding's effect and interval are those of the pair that
decides (among the pairs with the finding's verdict, the one least in the paper's favour).
The per-seed minimum over the others would not do: the minimum of ``m`` noisy ratios lies
below 1 when all controllers tie, and read as "contradicted" about half the time.
3. the perception error stays below the bound: ``r_i = max_flights max_k ||e_k|| / gamma`` over
   the flights of seed ``i`` (the paper: ``< 1``). ``gamma`` is the theorem's
   ``gamma_nominal`` on the certified controllers' own flights when the bound check has it,
   else ``gamma_strict`` of the reference robust controller on every flight (the paper's
   comparison, its 1.602).
4. the robust controllers react more softly than PD would on the same estimate:
   ``r_i`` = geometric mean over the robust controllers and conditions of
   ``RMS(u_att - u_ff) / RMS(u_PD,att - u_ff)`` (their feedback attitude command against PD's
   ``K (y - r)`` on the estimate they flew on; the paper: ``< 1``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.evaluate.stats import (
    LEVEL,
    Direction,
    Interval,
    ratio_interval,
    t_interval,
    verdict,
)

ROBUST = ("l1_robust", "l1_robust_imitation")
FINDINGS_FILE = "findings.json"


def _g(v: float) -> str:
    return f"{v:.3g}" if math.isfinite(v) else "n/a"


def _iv_text(iv: Interval) -> str:
    lo, hi = iv.ci
    none = "(one seed: no interval)" if iv.n == 1 else "(no interval)"
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{_g(iv.mean)} {none}"
    ci = f"[{_g(lo)}, {_g(hi)}]"
    return f"{_g(iv.mean)} {ci}"


def _pivot(flights: pd.DataFrame, condition: str, col: str) -> pd.DataFrame:
    """``col`` as (seed x controller) for one condition (seeds flown by every column)."""
    sub = flights[flights["condition"] == condition]
    if sub.empty or col not in sub:
        return pd.DataFrame()
    return sub.pivot_table(index="seed", columns="controller", values=col, aggfunc="first")


def _item(
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
        "detail": f"effect {_iv_text(iv)} over {iv.n} seeds: {v}; {detail}",
    }
    if v != "reproduced" and mechanism is not None:
        item["mechanism"] = item["detail"] + "; why: " + mechanism()
    return {**item, **extra}


@dataclass(frozen=True)
class Pairs:
    """Every other controller against one (module docstring, findings 1 and 2)."""

    per_seed: dict[str, pd.Series]  # c -> piv[c] / piv[who], per seed
    intervals: dict[str, Interval]  # simultaneous, each at ``level``
    level: float
    decider: str  # the pair whose interval gives the finding's verdict


def _against_each(piv: pd.DataFrame, who: str, direction: Direction) -> Pairs:
    """``piv[c] / piv[who]`` per seed for every ``c != who`` (seeds where all flew), with
    Bonferroni-simultaneous 95% intervals, and the pair that decides the verdict."""
    piv = piv.dropna()
    others = [c for c in piv.columns if c != who]
    level = 1.0 - (1.0 - LEVEL) / len(others)
    per_seed = {c: piv[c] / piv[who] for c in others}
    ivs = {c: ratio_interval(r.to_numpy(float), level) for c, r in per_seed.items()}
    says = {c: verdict(iv, 1.0, direction) for c, iv in ivs.items()}
    overall = (
        "contradicted"
        if "contradicted" in says.values()
        else "reproduced"
        if all(v == "reproduced" for v in says.values())
        else "inconclusive"
    )
    sign = 1.0 if direction == "greater" else -1.0
    decider = min((c for c in others if says[c] == overall), key=lambda c: sign * ivs[c].mean)
    return Pairs(per_seed, ivs, level, decider)


def _pairs_text(p: Pairs) -> str:
    return ", ".join(f"{c} {_iv_text(iv)}" for c, iv in p.intervals.items())


def finding1_tracking(
    flights: pd.DataFrame, paper4: Sequence[str], threshold: float
) -> dict | None:
    """Finding 1 (module docstring): PD tracks best in regular perception."""
    piv = _pivot(flights, "regular", "tracking_rms_m")
    cols = [c for c in paper4 if c in piv.columns]
    if "pd" not in cols or len(cols) < 2:
        return None
    piv = piv[cols]
    reg = flights[(flights["condition"] == "regular") & flights["controller"].isin(cols)]
    bad = sorted(set(reg.loc[reg["crashed"] | (reg["tracking_rms_m"] >= threshold), "controller"]))
    means = piv.mean().sort_values()
    detail = (
        "tracking RMS (m), mean over seeds: "
        + ", ".join(f"{c} {means[c]:.3f}" for c in means.index)
        + ("; all track" if not bad else f"; not tracking (crash or RMS >= {threshold:g} m) on "
           f"some seed: {', '.join(bad)}")
    )  # fmt: skip

    def why() -> str:
        best, runner = means.index[0], means.index[1]
        other = runner if best == "pd" else best
        return (
            f"lowest mean tracking RMS: {best} ({means[best]:.4f} m); PD {means['pd']:.4f} m, "
            f"{other} {means[other]:.4f} m"
        )

    pairs = _against_each(piv, "pd", "greater")
    detail += (
        f"; each controller's tracking RMS / PD's (simultaneous {100 * pairs.level:.4g}% "
        f"intervals): {_pairs_text(pairs)}"
    )
    return _item(
        1,
        "regular perception: all controllers track, PD tracks best",
        f"per seed, {pairs.decider}'s tracking RMS / PD's (> 1: PD better); every other "
        "controller is tested against PD and this pair decides the verdict",
        pairs.per_seed[pairs.decider],
        "greater",
        detail,
        why,
        level=pairs.level,
        all_track=not bad,
        pairwise={c: {"effect": iv.mean, "ci": iv.ci} for c, iv in pairs.intervals.items()},
    )


def finding2_degraded(
    flights: pd.DataFrame, paper4: Sequence[str], motion_parts: Sequence[str] = ()
) -> dict | None:
    """Finding 2 (module docstring): ``l1_robust`` lowest perception error in degraded."""
    piv = _pivot(flights, "degraded", "perception_error_rms")
    cols = [c for c in paper4 if c in piv.columns]
    if "l1_robust" not in cols or len(cols) < 2:
        return None
    pairs = _against_each(piv[cols], "l1_robust", "greater")
    detail = (
        f"each controller's ||e|| RMS / l1_robust's (> 1: l1_robust lower; simultaneous "
        f"{100 * pairs.level:.4g}% intervals): {_pairs_text(pairs)}"
    )

    def why() -> str:
        return _motion_mechanism(flights, cols, motion_parts)

    return _item(
        2,
        "degraded perception: the robust qr-cost controller (l1_robust) has the lowest "
        "perception error",
        f"per seed, {pairs.decider}'s ||e||_inf RMS / l1_robust's (> 1: l1_robust lower); "
        "every other controller is tested against l1_robust and this pair decides the verdict",
        pairs.per_seed[pairs.decider],
        "greater",
        detail,
        why,
        level=pairs.level,
        pairwise={c: {"effect": iv.mean, "ci": iv.ci} for c, iv in pairs.intervals.items()},
    )


def _motion_mechanism(
    flights: pd.DataFrame, cols: Sequence[str], motion_parts: Sequence[str]
) -> str:
    """Which controller flies roughest, and how much blur (and error) that makes."""
    deg = flights[(flights["condition"] == "degraded") & flights["controller"].isin(cols)]
    have = [c for c in ("attitude_smoothness", "angular_rate_rms", "blur_px_mean") if c in deg]
    m = deg.groupby("controller")[[*have, "perception_error_rms"]].mean()
    parts = []
    for c in m.index:
        r = m.loc[c]
        bits = []
        if "attitude_smoothness" in have:
            bits.append(f"attitude step {r['attitude_smoothness']:.3g} rad")
        if "angular_rate_rms" in have:
            bits.append(f"body rate RMS {r['angular_rate_rms']:.3g} rad/s")
        if "blur_px_mean" in have:
            bits.append(f"blur {r['blur_px_mean']:.3g} px")
        parts.append(f"{c}: " + ", ".join([*bits, f"||e|| RMS {r['perception_error_rms']:.4g}"]))
    on = (
        f"on in these flights: {', '.join(motion_parts)}"
        if motion_parts
        else "all off in these flights, so the error depends on the path flown only"
    )
    return (
        "the emulator's error depends on how the vehicle is flown through its motion-dependent "
        f"parts (blur, drift with motion, feature loss; {on}); the controllers' motion in "
        "degraded perception: " + "; ".join(parts)
    )


def finding3_bound(
    checks: pd.DataFrame, flights: pd.DataFrame, ref_name: str | None
) -> dict | None:
    """Finding 3 (module docstring): the perception error stays below the bound."""
    if checks.empty:
        return None
    seed_of = dict(zip(flights["flight"], flights["seed"], strict=True))
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
        f"{c} {_g(v)}" for c, v in by.items()
    )

    def why() -> str:
        worst = frame.loc[frame["ratio"].idxmax()]
        cond = f", {worst['condition']}" if "condition" in frame else ""
        text = (
            f"the worst flight ({worst['by']}{cond}, seed {int(worst['seed'])}) reaches "
            f"{_g(float(worst['ratio']))} x gamma; the bound holds only under its premise "
            "||e|| <= eps_e + S d (the certificate's eps_e and S)"
        )
        if "frac_premise_holds" in frame and "max_premise_ratio" in frame:
            text += (
                f", which holds on {100 * float(frame['frac_premise_holds'].mean()):.1f}% of "
                f"the samples of these flights, the error reaching "
                f"{_g(float(frame['max_premise_ratio'].max()))} x (eps_e + S d)"
            )
        return text

    return _item(
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
    """Finding 3 on the certified controllers' own flights, read through every assumption of
    the guarantee (:mod:`qsls.pipeline.evaluate.assumptions`): ``contradicted`` if any flight
    breaks an assumption or the bound, with the share of such flights and its Clopper-Pearson
    95% interval; ``reproduced`` only when none does."""
    from qsls.pipeline.errormodel.honest import clopper_pearson

    if assumptions is None or not len(assumptions):
        return None
    ok = assumptions["assumptions_hold"].astype(bool) & assumptions["bound_held"].astype(bool)
    bad = assumptions[~ok]
    n, k = len(assumptions), len(bad)
    lo, hi = clopper_pearson(k, n)
    listed = ", ".join(
        f"{r.flight} ({r.first_failed or 'bound'})" for r in bad.head(6).itertuples()
    )
    detail = (
        f"{k} of {n} flights of certified controllers break an assumption or the bound "
        f"(share {k / n:.3g}, 95% Clopper-Pearson {lo:.3g} to {hi:.3g})"
        + (f": {listed}" + (" ..." if k > 6 else "") if k else "")
    )
    item = {
        "id": 3,
        "claim": "every controller's perception error stays below the bound",
        "effect": k / n,
        "ci": [lo, hi],
        "verdict": "contradicted" if k else "reproduced",
        "n_flights": n,
        "n_violating": k,
        "level": 0.95,
        "effect_definition": "share of the certified controllers' own flights on which an "
        "assumption of the guarantee, or the bound itself, fails (the paper: 0)",
        "paper_direction": "= 0",
        "detail": detail,
        "bound": "every assumption (docs/guarantee.md)",
    }
    if k:
        item["mechanism"] = detail
    return item


def finding4_softness(flights: pd.DataFrame) -> dict | None:
    """Finding 4 (module docstring): the robust controllers react more softly than PD."""
    rob = flights[flights["controller"].isin(ROBUST)]
    if rob.empty or "reaction_vs_pd" not in rob:
        return None
    logs = np.log(rob["reaction_vs_pd"].astype(float).where(rob["reaction_vs_pd"] > 0))
    per_seed = np.exp(logs.groupby(rob["seed"]).mean())
    groups = {
        f"{c} ({cond})": ratio_interval(g["reaction_vs_pd"].to_numpy(float))
        for (c, cond), g in rob.groupby(["controller", "condition"], sort=False)
    }
    g = rob.groupby(["controller", "condition"], sort=False)
    rough = g["smoothness_vs_pd"].mean()
    err = g["error_reaction_vs_pd"].mean() if "error_reaction_vs_pd" in rob else None
    detail = "feedback attitude command RMS / PD's on the same estimate (< 1: softer): " + (
        ", ".join(f"{k} {_iv_text(iv)}" for k, iv in groups.items())
    )

    def why() -> str:
        text = (
            "RMS step change of the attitude command / PD's on the same estimate (roughness, "
            "what drives blur): "
            + ", ".join(f"{c} ({cond}) {v:.3g}" for (c, cond), v in rough.items())
        )
        if err is not None:
            text += (
                "; the reaction to the estimation error alone (the controller's filter on "
                "e = y - x against K_PD e): "
                + ", ".join(f"{c} ({cond}) {v:.3g}" for (c, cond), v in err.items())
            )
        return text

    return _item(
        4,
        "(qualitative) the robust controllers react more softly than PD would on the same estimate",
        "per seed, the geometric mean over the robust controllers and conditions of "
        "RMS(u_att - u_ff) / RMS(K_PD (y - r))_att (< 1: softer)",
        per_seed,
        "less",
        detail,
        why,
        by_controller={k: {"effect": iv.mean, "ci": iv.ci} for k, iv in groups.items()},
        roughness_vs_pd={f"{c} ({cond})": float(v) for (c, cond), v in rough.items()},
        error_reaction_vs_pd=(
            {f"{c} ({cond})": float(v) for (c, cond), v in err.items()} if err is not None else {}
        ),
    )


def degraded_rms(flights: pd.DataFrame, names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Per controller, the mean over seeds of the degraded-perception ``||e||`` RMS and its
    95% t-interval."""
    deg = flights[flights["condition"] == "degraded"]
    out: dict[str, dict[str, Any]] = {}
    for c in names:
        iv = t_interval(deg.loc[deg["controller"] == c, "perception_error_rms"].to_numpy(float))
        if iv.n:
            out[c] = {"mean": iv.mean, "ci": iv.ci, "n": iv.n}
    return out


def paired_findings(
    flights: pd.DataFrame,
    checks: pd.DataFrame,
    ref_name: str | None,
    paper4: Sequence[str],
    threshold: float,
    motion_parts: Sequence[str] = (),
    assumptions: pd.DataFrame | None = None,
) -> dict[str, Any]:
    """``findings.json``: ``{n_seeds, findings: [{id, claim, effect, ci, verdict, ...}],
    degraded_perception_rms: {controller: {mean, ci}}}`` (issue 13's schema plus details).
    ``motion_parts``: the emulator's motion-dependent parts switched on (for the mechanism)."""
    found = (
        finding1_tracking(flights, paper4, threshold),
        finding2_degraded(flights, paper4, motion_parts),
        finding3_assumptions(assumptions)
        if assumptions is not None and len(assumptions)
        else finding3_bound(checks, flights, ref_name),
        finding4_softness(flights),
    )
    names = list(dict.fromkeys(flights["controller"])) if len(flights) else []
    return {
        "n_seeds": int(flights["seed"].nunique()) if len(flights) else 0,
        "level": 0.95,
        "method": "Student t-interval of the per-seed log ratios, reported as "
        "a geometric mean ratio (no effect: 1); findings 1 and 2 test every pair with "
        "simultaneous 95% intervals (Bonferroni), the deciding pair shown",
        "findings": [f for f in found if f is not None],
        "degraded_perception_rms": degraded_rms(flights, names),
    }


def findings_markdown(doc: dict[str, Any], comparison: Sequence[dict[str, Any]] = ()) -> list[str]:
    """The findings as a Markdown table (``| 1. claim | effect [CI] | verdict | qsls | ... |``),
    with the point comparison (means over seeds, ``agrees``) of the same finding beside."""

    def cell(v: Any) -> str:
        return str(v).replace("|", "\\|")

    point = {str(c["finding"]).partition(".")[0]: c for c in comparison}
    lines = [
        f"Paired by seed ({doc.get('n_seeds', 0)} seeds): {doc.get('method', '')}.",
        "",
        "| finding (paper) | effect [95% CI] | verdict | qsls | means over seeds (agrees) |",
        "|---|---|---|---|---|",
    ]
    for f in doc.get("findings", []):
        lo, hi = f["ci"]
        eff = "n/a" if f["effect"] is None else f"{f['effect']:.3g}"
        ci = f" [{lo:.3g}, {hi:.3g}]" if lo is not None and hi is not None else ""
        c = point.get(str(f["id"]))
        means = f"{c['qsls']} ({c['agrees']})" if c else "-"
        lines.append(
            f"| {f['id']}. {cell(f['claim'])} | {eff}{ci} (paper: {cell(f['paper_direction'])}) "
            f"| {f['verdict']} | {cell(f.get('mechanism', f['detail']))} | {cell(means)} |"
        )
    rms = doc.get("degraded_perception_rms") or {}
    if rms:
        lines += ["", "Degraded perception, ||e||_inf RMS per controller (mean [95% CI]):", ""]
        for name, v in rms.items():
            lo, hi = v["ci"]
            ci = f" [{lo:.4g}, {hi:.4g}]" if lo is not None and hi is not None else ""
            lines.append(f"- {name}: {v['mean']:.4g}{ci}")
    return lines


__all__ = ["FINDINGS_FILE", "findings_markdown", "paired_findings"]
