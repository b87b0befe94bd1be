"""The paper's four findings as the paper states them, paired by seed, with 95% intervals
(``fly/findings.json``), in the paper's order (paper, Experiments):

1. regular perception: all controllers track, PD tracks best;
2. the robust controllers react more conservatively to estimation errors than PD (the
   paper's input figure), **per robust controller**;
3. every controller's perception error stays below the theoretical bound, both as qsls's
   certificate (every assumption of the guarantee on the robust controllers' own flights,
   every estimator's) and as the paper's strict bound ``R0 / (1 - S ||Phi_xe||)`` (undefined
   when ``S ||Phi_xe|| >= 1``; :mod:`qsls.pipeline.fly.paper`), in
   :mod:`qsls.pipeline.fly.bound_finding`;
4. degraded perception: the quadratic-cost robust and nominal controllers err significantly
   less than PD and the imitation controller (the **two-group contrast**), ``l1_robust`` the
   least (reported beside it).

The same seed gives every controller the same randomness, so each finding is one effect per
seed, compared between controllers flown with that seed in the same condition;
:mod:`qsls.pipeline.fly.stats` turns the per-seed effects into a mean, a 95% interval
and a verdict (``reproduced`` / ``contradicted`` / ``inconclusive``). Ratios are tested on
their logarithm and reported as geometric means (no effect: 1):

1. ``r_i(c) = rms_track(c, i) / rms_track(pd, i)`` for each other controller ``c`` (the paper:
   ``> 1`` for every ``c``); whether every controller tracks is reported beside it.
2. ``r_i(c) = RMS(u_att - u_ff)(c, i) / RMS(K_PD (y - r))_att(i)`` in regular perception, per
   robust controller ``c`` (its feedback attitude command against PD's on the estimate it
   flew on; the paper: ``< 1``); degraded perception reported beside it.
3. ``contradicted`` if any certified controller's own flight breaks an assumption or the
   bound (a counterexample to "every flight", so no replication is needed for it; reproduced
   only when both halves of the seeds have flights and none breaks), with the share and its
   Clopper-Pearson interval, each failing flight named; without the assumption table
   ``r_i = max_flights max_k ||e_k|| / gamma`` per seed.
4. ``r_i`` = geometric mean of PD's and the imitation controller's ``||e||`` RMS over that of
   ``l1_robust`` and ``l1_nominal`` (> 1: the quadratic-cost group errs less).

"Every controller" claims (1, 2, and ``l1_robust`` lowest beside 4) test each controller with
simultaneous 95% intervals (Bonferroni: each at ``1 - 0.05 / m`` for ``m`` tests):
``reproduced`` when every one reproduces, ``contradicted`` when any contradicts,
``inconclusive`` otherwise; the finding's effect and interval are those of the one that
decides (among those with the finding's verdict, the one least in the paper's favour). The
per-seed minimum over the others would not do: the minimum of ``m`` noisy ratios lies below 1
when all controllers tie.

Metrics are read over the circle with the paper's 1 s smoothing where the flights have them
(``*_circle`` columns), the whole flight's reported beside (``whole_flight``). Every verdict
is replicated: it reads ``reproduced`` or ``contradicted`` only when both halves of the seeds
say so on their own (``halves``; the verdict on all seeds is ``verdict_all_seeds``;
:func:`qsls.pipeline.fly.items.replicate`). ``comparison.md``'s text:
:mod:`qsls.pipeline.fly.markdown`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.fly.bound_finding import finding3
from qsls.pipeline.fly.findings import (
    paper_mode_reaction,
    state_dependence,
)
from qsls.pipeline.fly.items import finding_item, interval_text, replicate
from qsls.pipeline.fly.paper import (
    QUADRATIC,
    TUNED_FOR_IDEAL,
    halves,
    two_group_contrast,
)
from qsls.pipeline.fly.stats import (
    LEVEL,
    Direction,
    Interval,
    ratio_interval,
    t_interval,
    verdict,
)

ROBUST = ("l1_robust", "l1_robust_imitation")


def _pivot(flights: pd.DataFrame, condition: str, col: str) -> pd.DataFrame:
    """``col`` as (seed x controller) for one condition (seeds flown by every column)."""
    sub = flights[flights["condition"] == condition]
    if sub.empty or col not in sub:
        return pd.DataFrame()
    return sub.pivot_table(index="seed", columns="controller", values=col, aggfunc="first")


def _col(flights: pd.DataFrame, base: str, window: str) -> str:
    """The circle's smoothed column of ``base`` when asked for and present, else ``base``."""
    circle = f"{base}_circle"
    if window == "circle" and circle in flights and flights[circle].notna().any():
        return circle
    return base


def _window_name(col: str) -> str:
    return "circle, 1 s smoothing" if col.endswith("_circle") else "whole flight"


def _decide(
    per_seed: dict[str, pd.Series], direction: Direction, level: float | None = None
) -> tuple[dict[str, Interval], dict[str, str], str, str, float]:
    """Simultaneous intervals of every entry's per-seed ratios (Bonferroni), each entry's
    verdict, the overall verdict (module docstring) and the entry that decides it."""
    level = level if level is not None else 1.0 - (1.0 - LEVEL) / max(len(per_seed), 1)
    ivs = {c: ratio_interval(r.to_numpy(float), level) for c, r in per_seed.items()}
    says: dict[str, str] = {c: verdict(iv, 1.0, direction) for c, iv in ivs.items()}
    overall = (
        "contradicted"
        if "contradicted" in says.values()
        else "reproduced"
        if all(v == "reproduced" for v in says.values())
        else "inconclusive"
    )
    sign = 1.0 if direction == "greater" else -1.0
    decider = min(
        (c for c in per_seed if says[c] == overall),
        key=lambda c: sign * (ivs[c].mean if math.isfinite(ivs[c].mean) else math.inf),
    )
    return ivs, says, overall, decider, level


@dataclass(frozen=True)
class Pairs:
    """Every other controller against one (module docstring, finding 1 and finding 4's
    ``l1_robust`` lowest)."""

    per_seed: dict[str, pd.Series]  # c -> piv[c] / piv[who], per seed
    intervals: dict[str, Interval]  # simultaneous, each at ``level``
    level: float
    decider: str  # the pair whose interval gives the finding's verdict
    verdict: str = "inconclusive"


def _against_each(piv: pd.DataFrame, who: str, direction: Direction) -> Pairs:
    """``piv[c] / piv[who]`` per seed for every ``c != who`` (seeds where all flew), with
    Bonferroni-simultaneous 95% intervals, and the pair that decides the verdict."""
    piv = piv.dropna()
    others = [c for c in piv.columns if c != who]
    per_seed = {c: piv[c] / piv[who] for c in others}
    ivs, _, overall, decider, level = _decide(per_seed, direction)
    return Pairs(per_seed, ivs, level, decider, overall)


def _pairs_text(p: Pairs) -> str:
    return ", ".join(f"{c} {interval_text(iv)}" for c, iv in p.intervals.items())


def finding1_tracking(
    flights: pd.DataFrame, paper4: Sequence[str], threshold: float, window: str = "circle"
) -> dict | None:
    """Finding 1 (module docstring): PD tracks best in regular perception."""
    col = _col(flights, "tracking_rms_m", window)
    piv = _pivot(flights, "regular", col)
    cols = [c for c in paper4 if c in piv.columns]
    if "pd" not in cols or len(cols) < 2:
        return None
    piv = piv[cols]
    reg = flights[(flights["condition"] == "regular") & flights["controller"].isin(cols)]
    bad = sorted(set(reg.loc[reg["crashed"] | (reg["tracking_rms_m"] >= threshold), "controller"]))
    means = piv.mean().sort_values()
    detail = (
        f"tracking RMS (m, {_window_name(col)}), mean over seeds: "
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
    return finding_item(
        1,
        "regular perception: all controllers track, PD tracks best",
        f"per seed, {pairs.decider}'s tracking RMS / PD's ({_window_name(col)}; > 1: PD "
        "better); every other controller is tested against PD and this pair decides the verdict",
        pairs.per_seed[pairs.decider],
        "greater",
        detail,
        why,
        level=pairs.level,
        all_track=not bad,
        metric=col,
        pairwise={c: {"effect": iv.mean, "ci": iv.ci} for c, iv in pairs.intervals.items()},
    )


def finding2_softness(flights: pd.DataFrame, window: str = "circle") -> dict | None:
    """Finding 2 (module docstring): each robust controller reacts more softly than PD on the
    same estimate, in regular perception (degraded beside it)."""
    col = _col(flights, "reaction_vs_pd", window)
    if col not in flights:
        return None
    rob = flights[flights["controller"].isin(ROBUST)]
    reg = rob[rob["condition"] == "regular"]
    if reg.empty:
        return None
    per_seed = {
        str(c): g.set_index("seed")[col].astype(float)
        for c, g in reg.groupby("controller", sort=False)
    }
    ivs, says, _, decider, level = _decide(per_seed, "less")
    deg = {
        str(c): ratio_interval(g[col].to_numpy(float))
        for c, g in rob[rob["condition"] == "degraded"].groupby("controller", sort=False)
    }
    detail = (
        f"feedback attitude command RMS / PD's on the same estimate ({_window_name(col)}; < 1: "
        f"softer), regular perception, each robust controller (simultaneous "
        f"{100 * level:.4g}% intervals): "
        + ", ".join(f"{c} {interval_text(iv)} {says[c]}" for c, iv in ivs.items())
    )
    if deg:
        detail += "; degraded perception: " + ", ".join(
            f"{c} {interval_text(iv)}" for c, iv in deg.items()
        )
    g = flights[flights["controller"].isin(ROBUST)].groupby(["controller", "condition"], sort=False)
    rough = g["smoothness_vs_pd"].mean() if "smoothness_vs_pd" in flights else pd.Series()
    err = g["error_reaction_vs_pd"].mean() if "error_reaction_vs_pd" in flights else None

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

    return finding_item(
        2,
        "the robust controllers react more conservatively to estimation errors than PD "
        "(each robust controller)",
        f"per seed, {decider}'s feedback attitude command RMS / PD's on the same estimate "
        "(regular perception; < 1: softer); every robust controller is tested and this one "
        "decides the verdict",
        per_seed[decider],
        "less",
        detail,
        why,
        level=level,
        metric=col,
        by_controller={
            c: {"effect": iv.mean, "ci": iv.ci, "verdict": says[c]} for c, iv in ivs.items()
        },
        degraded={c: {"effect": iv.mean, "ci": iv.ci} for c, iv in deg.items()},
        roughness_vs_pd={f"{c} ({cond})": float(v) for (c, cond), v in rough.items()},
        error_reaction_vs_pd=(
            {f"{c} ({cond})": float(v) for (c, cond), v in err.items()} if err is not None else {}
        ),
    )


def _motion_mechanism(
    flights: pd.DataFrame,
    cols: Sequence[str],
    motion_parts: Sequence[str],
    estimator: str = "emulator",
) -> str:
    """Which controller flies roughest, and how much blur (and error) that makes, with the
    blur and features of the estimator that flew (the camera's own exposure model for camera
    flights)."""
    deg = flights[(flights["condition"] == "degraded") & flights["controller"].isin(cols)]
    have = [
        c
        for c in ("attitude_smoothness", "angular_rate_rms", "blur_px_mean", "features_per_frame")
        if c in deg and deg[c].notna().any()
    ]
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
        if "features_per_frame" in have:
            bits.append(f"{r['features_per_frame']:.3g} features per frame")
        parts.append(f"{c}: " + ", ".join([*bits, f"||e|| RMS {r['perception_error_rms']:.4g}"]))
    if estimator == "camera":
        how = (
            "the camera loop's error depends on how the vehicle is flown through the rendered "
            "images (blur over the camera's own exposure, features tracked per frame)"
        )
    else:
        on = (
            f"on in these flights: {', '.join(motion_parts)}"
            if motion_parts
            else "all off in these flights, so the error depends on the path flown only"
        )
        how = (
            "the emulator's error depends on how the vehicle is flown through its "
            f"motion-dependent parts (blur, drift with motion, feature loss; {on})"
        )
    return how + "; the controllers' motion in degraded perception: " + "; ".join(parts)


def finding4_degraded(
    flights: pd.DataFrame,
    paper4: Sequence[str],
    motion_parts: Sequence[str] = (),
    estimator: str = "emulator",
    window: str = "circle",
) -> dict | None:
    """Finding 4 (module docstring): in degraded perception the quadratic-cost controllers
    (``l1_robust``, ``l1_nominal``) err less than PD and the imitation controller."""
    col = _col(flights, "perception_error_rms", window)
    piv = _pivot(flights, "degraded", col)
    cols = [c for c in paper4 if c in piv.columns]
    if not any(c in cols for c in QUADRATIC) or not any(c in cols for c in TUNED_FOR_IDEAL):
        return None
    piv = piv[cols].dropna()
    per_seed = two_group_contrast(piv, QUADRATIC, TUNED_FOR_IDEAL)
    a = [c for c in QUADRATIC if c in cols]
    b = [c for c in TUNED_FOR_IDEAL if c in cols]
    detail = (
        f"||e||_inf RMS ({_window_name(col)}), geometric mean of {' and '.join(b)} over that "
        f"of {' and '.join(a)} (> 1: the quadratic-cost group errs less)"
    )
    lowest: dict[str, Any] = {}
    if "l1_robust" in cols and len(cols) > 1:
        pairs = _against_each(piv, "l1_robust", "greater")
        lowest = {
            "verdict": pairs.verdict,
            "level": pairs.level,
            "pairwise": {c: {"effect": iv.mean, "ci": iv.ci} for c, iv in pairs.intervals.items()},
        }
        detail += (
            f"; beside it, l1_robust the lowest (each controller's ||e|| RMS / l1_robust's, "
            f"simultaneous {100 * pairs.level:.4g}% intervals): {_pairs_text(pairs)}: "
            f"{pairs.verdict}"
        )

    def why() -> str:
        return _motion_mechanism(flights, cols, motion_parts, estimator)

    return finding_item(
        4,
        "degraded perception: the quadratic-cost robust and nominal controllers err less than "
        "PD and the imitation controller (l1_robust the least)",
        f"per seed, the geometric mean ||e|| RMS of {' and '.join(b)} / that of "
        f"{' and '.join(a)} (> 1: the quadratic-cost group lower)",
        per_seed,
        "greater",
        detail,
        why,
        metric=col,
        groups={"quadratic": a, "others": b},
        l1_robust_lowest=lowest,
    )


def mechanism_table(
    flights: pd.DataFrame, norms: dict[str, dict[str, float]] | None = None
) -> list[dict[str, Any]]:
    """Per controller and condition, what drives the findings: the gains from perception
    error to state and input (``||Phi_xe||``, ``||Phi_ue||`` of its taps, from ``norms``), the
    feedback command against PD's, the body rate, the blur and features per frame of the
    estimator that flew, and the perception error (means over seeds)."""
    if flights.empty:
        return []
    norms = norms or {}
    cols = [
        c
        for c in (
            "reaction_vs_pd_circle", "reaction_vs_pd", "angular_rate_rms", "blur_px_mean",
            "features_per_frame",
            "perception_error_rms_circle", "perception_error_rms", "tracking_rms_m_circle",
        )
        if c in flights
    ]  # fmt: skip
    m = flights.groupby(["controller", "condition"], sort=False)[cols].mean()
    out = []
    for (c, cond), r in m.iterrows():
        n = norms.get(str(c), {})
        out.append(
            {
                "controller": c,
                "condition": cond,
                "norm_phi_xe": n.get("phi_xe"),
                "norm_phi_ue": n.get("phi_ue"),
                **{k: (float(v) if pd.notna(v) else None) for k, v in r.items()},
            }
        )
    return out


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


def degradation_check(
    flights: pd.DataFrame, controller: str = "pd", factor: float = 2.0
) -> dict[str, Any] | None:
    """Does the degraded condition degrade? Per seed, ``controller``'s estimator error RMS
    (over the circle with 1 s smoothing where flown) in degraded over regular perception;
    the geometric mean with the 95% t-interval of the logs. ``doubles`` (``factor`` 2) when
    the interval lies above ``factor``, also checked on each half of the seeds. Without the
    named controller, the first flown in both conditions is used."""
    if flights.empty or "condition" not in flights:
        return None
    both = [
        c
        for c in dict.fromkeys(flights["controller"])
        if {"regular", "degraded"} <= set(flights.loc[flights["controller"] == c, "condition"])
    ]
    if not both:
        return None
    who = controller if controller in both else both[0]
    col = _col(flights, "perception_error_rms", "circle")
    mine = flights[flights["controller"] == who]
    piv = mine.pivot_table(index="seed", columns="condition", values=col, aggfunc="first")
    piv = piv.dropna()
    r = (piv["degraded"] / piv["regular"]).astype(float)
    iv = ratio_interval(r.to_numpy(float))
    hs = []
    for half in halves(r.index):
        h = ratio_interval(r.loc[half].to_numpy(float)) if half else None
        hs.append(
            {
                "seeds": half,
                "effect": h.mean if h else None,
                "ci": h.ci if h else [None, None],
                "doubles": bool(h is not None and np.isfinite(h.lo) and h.lo > factor),
            }
        )
    doubles = bool(np.isfinite(iv.lo) and iv.lo > factor)
    return {
        "controller": who,
        "metric": col,
        "factor": factor,
        "effect": iv.mean,
        "ci": iv.ci,
        "n_seeds": iv.n,
        "doubles": doubles,
        "halves": hs,
        "per_seed": {str(int(s)): float(v) for s, v in r.items()},
        "text": (
            f"degraded over regular estimator error ({who}'s flights, {_window_name(col)}, "
            f"paired by seed): {interval_text(iv)} over {iv.n} seeds; "
            + (
                f"the interval lies above {factor:g}: the degraded condition degrades"
                if doubles
                else f"the interval does not lie above {factor:g}: the degraded condition does not "
                "degrade enough for finding 4 to be read as the paper's"
            )
        ),
    }


def paired_findings(
    flights: pd.DataFrame,
    checks: pd.DataFrame,
    ref_name: str | None,
    paper4: Sequence[str],
    threshold: float,
    motion_parts: Sequence[str] = (),
    assumptions: pd.DataFrame | None = None,
    *,
    estimator: str = "emulator",
    strict: Sequence[dict[str, Any]] = (),
    norms: dict[str, dict[str, float]] | None = None,
) -> dict[str, Any]:
    """``findings.json``: ``{n_seeds, findings: [{id, claim, effect, ci, verdict, halves,
    ...}], mechanism: [...], degraded_perception_rms: {controller: {mean, ci}}}``, the four
    findings in the paper's order (module docstring). ``motion_parts``: the emulator's
    motion-dependent parts switched on; ``estimator``: the estimator that flew (for the
    mechanism's text); ``strict``: the controllers' premises for the paper's strict bound
    (:func:`strict_bounds`); ``norms``: ``{controller: {phi_xe, phi_ue}}``."""
    found = (
        replicate(lambda fl, w: finding1_tracking(fl, paper4, threshold, w), flights),
        replicate(finding2_softness, flights),
        finding3(checks, flights, ref_name, assumptions, strict),
        replicate(lambda fl, w: finding4_degraded(fl, paper4, motion_parts, estimator, w), flights),
    )
    names = list(dict.fromkeys(flights["controller"])) if len(flights) else []
    return {
        "n_seeds": int(flights["seed"].nunique()) if len(flights) else 0,
        "level": 0.95,
        "estimator_flown": estimator,
        "method": "Student t-interval of the per-seed log ratios, reported as a geometric mean "
        "ratio (no effect: 1); every-controller claims test each with simultaneous 95% "
        "intervals (Bonferroni), the deciding one shown; metrics over the circle with 1 s "
        "smoothing; a verdict reads reproduced or contradicted only when both halves of the "
        "seeds say so",
        "findings": [f for f in found if f is not None],
        "perception_check": degradation_check(flights),
        "mechanism": mechanism_table(flights, norms),
        "degraded_perception_rms": degraded_rms(flights, names),
        "state_dependence": state_dependence(flights),
        "paper_mode": paper_mode_reaction(flights),
    }


def replace_finding(doc: dict[str, Any], item: dict[str, Any] | None) -> dict[str, Any]:
    """``doc`` with its finding of ``item``'s id replaced by ``item`` (kept when ``None``)."""
    if item is None:
        return doc
    found = [item if f["id"] == item["id"] else f for f in doc.get("findings", [])]
    return {**doc, "findings": found}


__all__ = [
    "degradation_check",
    "mechanism_table",
    "paired_findings",
    "replace_finding",
]
