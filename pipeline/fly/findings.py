"""The paper's findings (paper, Experiments), one function each, and the comparison table:
the point comparison (means over seeds), numbered in the paper's order like
:mod:`qsls.pipeline.fly.paired` (1 tracking, 2 softness, 3 bound, 4 degraded).

Each ``finding_*`` returns ``{"finding", "qsls", "agrees"}`` (what the paper claims, what qsls
measured, whether it agrees) or ``None`` when the flights needed for it were not flown.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control import guarantee
from qsls.pipeline.evaluate.certified import ControllerBound
from qsls.pipeline.fly.stats import paired_ratio, ratio_interval

PAPER_CONTROLLERS = ("pd", "l1_nominal", "l1_robust", "l1_robust_imitation")
ROBUST_QR = "l1_robust"


def finding_tracking(per: pd.DataFrame, threshold: float, tie_rel: float) -> dict[str, Any] | None:
    """Finding 1, regular perception: every controller tracks (no crash, RMS below ``threshold``), PD tracks best (within ``tie_rel`` of the best)."""
    paper4 = [c for c in PAPER_CONTROLLERS if c in set(per["controller"])]
    reg = per[(per["condition"] == "regular") & per["controller"].isin(paper4)]
    if len(reg):
        tracks = {
            r.controller: bool(r.crashed == 0 and r.tracking_rms_m < threshold)
            for r in reg.itertuples()
        }
        order = reg.sort_values("tracking_rms_m")
        best, lo = order.iloc[0]["controller"], float(order.iloc[0]["tracking_rms_m"])
        nums = ", ".join(
            f"{r.controller} {r.tracking_rms_m:.3f} m"
            + (f" ({int(r.crashed)} crashed)" if r.crashed else "")
            for r in order.itertuples()
        )
        all_track = all(tracks.values())
        if "pd" not in tracks:
            pd_best, rank = False, "PD not flown"
        else:
            pd_rms = float(reg.loc[reg["controller"] == "pd", "tracking_rms_m"].iloc[0])
            pd_best = pd_rms <= lo * (1 + tie_rel)
            rank = (
                "PD best" if best == "pd" else
                f"PD within {100 * tie_rel:g}% of the best ({best})" if pd_best else
                f"best: {best}, PD {100 * (pd_rms / lo - 1):.0f}% worse"
            )  # fmt: skip
        not_tracking = [c for c, ok in tracks.items() if not ok]
        detail = (
            f"tracking RMS, mean over seeds: {nums}; "
            + ("all track" if all_track else
               f"not tracking (crash or RMS >= {threshold:g} m): {', '.join(not_tracking)}")
            + f"; {rank}"
        )  # fmt: skip
        agrees = "yes" if all_track and pd_best else "partly" if all_track or pd_best else "no"
        return {
            "finding": "1. regular perception: all controllers track, PD tracks best",
            "qsls": detail,
            "agrees": agrees,
        }
    return None


def finding_degraded_perception(per: pd.DataFrame, tie_rel: float) -> dict[str, Any] | None:
    """Finding 4, degraded perception: the robust qr-cost controller has the lowest perception error (a spread below ``tie_rel`` is a tie)."""
    paper4 = [c for c in PAPER_CONTROLLERS if c in set(per["controller"])]
    deg = per[(per["condition"] == "degraded") & per["controller"].isin(paper4)]
    if len(deg):
        order = deg.sort_values("perception_error_rms")
        best = order.iloc[0]["controller"]
        lo, hi = (
            float(order.iloc[0]["perception_error_rms"]),
            float(order.iloc[-1]["perception_error_rms"]),
        )
        spread = hi / lo - 1 if lo > 0 else math.inf
        nums = ", ".join(f"{r.controller} {r.perception_error_rms:.4f}" for r in order.itertuples())
        if ROBUST_QR not in set(deg["controller"]):
            agrees = "n/a (l1_robust not flown)"
        elif spread < tie_rel:
            agrees = "no (tie)"
        elif best == ROBUST_QR:
            agrees = "yes"
        else:
            agrees = "no"
        detail = (
            f"||e||_inf RMS, mean over seeds: {nums}; lowest: {best}; "
            f"spread {100 * spread:.2f}% (a tie below {100 * tie_rel:g}%)"
        )
        return {
            "finding": "4. degraded perception: the robust qr-cost controller has the "
            "lowest perception error",
            "qsls": detail,
            "agrees": agrees,
        }
    return None


def _names(items: list[str], most: int = 6) -> str:
    """The first ``most`` names and how many more."""
    more = f" and {len(items) - most} more" if len(items) > most else ""
    return ", ".join(items[:most]) + more


def finding_bound(
    checks: pd.DataFrame, ref_bound: ControllerBound | None, true_lipschitz: dict[str, float] | None
) -> dict[str, Any] | None:
    """Finding 3: every controller's perception error stays below the bound (``ref_bound``'s ``gamma_strict``, the paper's comparison, and each certified controller's own check)."""
    if not checks.empty and ref_bound is not None:
        ref = checks[checks["controller"] == ref_bound.name]
        worst = ref.groupby("flown_by", sort=False)["max_ratio_strict"].max()
        all_under = bool((ref["frac_under_gamma_strict"] >= 1.0).all())
        nums = ", ".join(f"{c} {worst[c]:.3g}" for c in worst.index)
        own = checks[(checks["controller"] == checks["flown_by"]) & checks["has_guarantee"]]
        own = own[own["bound_holds"].notna()]  # None: no theorem on this pair
        own_fail = own[~own["bound_holds"].astype(bool)]
        own_txt = (
            f"the theorem on each certified controller's own flights (max ||e|| <= "
            f"gamma_nominal): holds on {len(own) - len(own_fail)} of {len(own)} flights"
        )
        if own.empty:  # generalized certificates: checked assumption by assumption instead
            own_txt = (
                "the certified controllers' own flights are checked assumption by assumption "
                "(the verdict and the assumptions table)"
            )
        elif len(own_fail):
            n_ass = int((~own_fail["assumption_holds"].astype(bool)).sum())
            own_txt += (
                f"; fails on {_names(list(own_fail['flight']))} "
                f"({n_ass} of them with the S-slope/eps_e premise violated: "
                f"||e|| above eps_e + S d)"
            )
        detail = (
            f"max ||e|| / gamma_strict of {ref_bound.name} ({ref_bound.gamma_strict:.4g}, the "
            f"paper's comparison) per controller flown: {nums}; {own_txt}"
        )
        if true_lipschitz and "condition" in ref.columns:
            # the paper computed its bound (1.602) with the true S-slope; the emulator's is known
            parts = []
            for cond, lip in true_lipschitz.items():
                g = guarantee.gamma_strict_of(ref_bound.r0, lip, ref_bound.norm_phi_xy)
                m = float(ref.loc[ref["condition"] == cond, "max_error_norm"].max())
                parts.append(
                    f"{cond}: L = {lip:.3g}, bound {g:.4g}"
                    + (
                        f", max ||e|| / bound {m / g:.3g}"
                        if math.isfinite(g)
                        else " (none: L ||Phi_xy|| >= 1)"
                    )
                )
            detail += (
                "; with the emulator's true Lipschitz constant as S (the paper's choice): "
                + ", ".join(parts)
            )
        if not ref_bound.has_guarantee:
            detail = f"{ref_bound.name} has no guarantee; " + detail
        agrees = "yes" if all_under and own_fail.empty else (
            "partly (strict bound yes, gamma_nominal no)" if all_under else "no"
        )  # fmt: skip
        return {
            "finding": "3. every controller's perception error stays below the bound",
            "qsls": detail,
            "agrees": agrees,
        }
    return None


def finding_softness(per: pd.DataFrame) -> dict[str, Any] | None:
    """Finding 2 (qualitative, the paper's input figure): the robust controllers react more softly than PD would on the same estimate (RMS of the feedback attitude command against PD's, ``reaction_vs_pd``; the step change's ratio ``smoothness_vs_pd`` beside it)."""
    rob = per[per["controller"].isin(["l1_robust", "l1_robust_imitation"])]
    col = "reaction_vs_pd" if "reaction_vs_pd" in rob.columns else "smoothness_vs_pd"
    if len(rob) and col in rob.columns:
        ratios = rob[col].to_numpy(float)
        rough = "smoothness_vs_pd" in rob.columns and col != "smoothness_vs_pd"
        nums = ", ".join(
            f"{r.controller} ({r.condition}) {getattr(r, col):.2f}"
            + (f" (step change {r.smoothness_vs_pd:.2f})" if rough else "")
            for r in rob.itertuples()
        )
        what = (
            "RMS of the feedback attitude command (u - hover - u_ff)"
            if col == "reaction_vs_pd"
            else "RMS step change of the attitude command"
        )
        agrees = "yes" if np.all(ratios < 1) else "no" if np.all(ratios >= 1) else "partly"
        return {
            "finding": "2. (qualitative) the robust controllers react more softly than PD "
            "would on the same estimate",
            "qsls": f"{what} relative to PD's on the same estimate, mean over seeds "
            f"(< 1: softer): {nums}",
            "agrees": agrees,
        }
    return None


def compare_with_paper(
    per: pd.DataFrame,
    checks: pd.DataFrame,
    threshold: float,
    ref_bound: ControllerBound | None,
    tie_rel: float = 0.02,
    true_lipschitz: dict[str, float] | None = None,
) -> list[dict[str, Any]]:
    """The paper's findings, each with what qsls measured and whether it agrees.

    Differences between controllers smaller than ``tie_rel`` (relative to the lowest value)
    count as a tie: qsls then does not reproduce a claimed ranking."""
    found = (
        finding_tracking(per, threshold, tie_rel),
        finding_softness(per),
        finding_bound(checks, ref_bound, true_lipschitz),
        finding_degraded_perception(per, tie_rel),
    )
    return [f for f in found if f is not None]


def state_dependence(
    flights: pd.DataFrame, reference: str = "pd", window: str = "circle"
) -> dict[str, Any] | None:
    """Does a controller that stays closer to the path see better estimates (the paper's
    mechanism; docs/paper.md)? Per condition: Spearman's rank correlation between the
    tracking RMS and the estimator error RMS over every flight (``rho > 0``: who strays errs);
    and per controller against ``reference``, paired by seed, the ratios of tracking RMS and
    of error RMS (geometric means with the 95 % t-interval of their logs)."""
    from scipy.stats import spearmanr

    tr, er = f"tracking_rms_m_{window}", f"perception_error_rms_{window}"
    if flights.empty or tr not in flights or er not in flights:
        return None
    out: dict[str, Any] = {"metric": [tr, er], "reference": reference, "conditions": {}}
    for cond, g in flights.groupby("condition", sort=False):
        g = g[np.isfinite(g[tr]) & np.isfinite(g[er])]
        if len(g) < 3:
            continue
        rho, p = spearmanr(g[tr], g[er])
        pairs = {}
        ref = g[g["controller"] == reference].set_index("seed")
        for c, gc in g.groupby("controller", sort=False):
            if c == reference or ref.empty:
                continue
            both = gc.set_index("seed")[[tr, er]].join(
                ref[[tr, er]].rename(columns=lambda k: k + "_ref"), how="inner"
            )
            t_iv = paired_ratio(both[tr], both[tr + "_ref"])
            e_iv = paired_ratio(both[er], both[er + "_ref"])
            pairs[str(c)] = {
                "tracking_ratio": t_iv.mean, "tracking_ci": t_iv.ci,
                "error_ratio": e_iv.mean, "error_ci": e_iv.ci, "n_seeds": t_iv.n,
            }  # fmt: skip
        out["conditions"][str(cond)] = {
            "spearman_rho": float(rho), "p_value": float(p), "flights": len(g),
            "vs_reference": pairs,
        }  # fmt: skip
    return out


PAPER_SUFFIX = "_paper"
"""The paper mode's controllers (:mod:`qsls.pipeline.control.papermode`) end with it."""


def paper_mode_reaction(flights: pd.DataFrame, window: str = "circle") -> dict[str, Any] | None:
    """Finding 2's measure for the paper mode's controllers (docs/paper.md): per controller
    and condition, the feedback attitude command RMS over PD's on the same estimate
    (geometric mean over seeds with the 95 % t-interval of the logs; < 1: softer)."""
    col = f"reaction_vs_pd_{window}"
    col = col if col in flights else "reaction_vs_pd"
    if flights.empty or col not in flights:
        return None
    mine = flights[flights["controller"].astype(str).str.endswith(PAPER_SUFFIX)]
    out: dict[str, Any] = {}
    for (c, cond), g in mine.groupby(["controller", "condition"], sort=False):
        iv = ratio_interval(g[col].to_numpy(float))
        out.setdefault(str(c), {})[str(cond)] = {"effect": iv.mean, "ci": iv.ci, "n_seeds": iv.n}
    return {"metric": col, "controllers": out} if out else None


def state_dependence_markdown(sd: dict[str, Any] | None) -> list[str]:
    """The state-dependence table (:func:`state_dependence`) as Markdown lines."""
    if not sd or not sd["conditions"]:
        return []
    ref = sd["reference"]
    lines = [
        "",
        f"## State-dependent perception: who strays errs? (circle, paired with {ref} by seed)",
        "",
        "| condition | controller | tracking / "
        + ref
        + " | error / "
        + ref
        + " | Spearman rho (all flights) |",
        "|---|---|---|---|---|",
    ]

    def iv(m: float, ci: list[float | None]) -> str:
        lo, hi = (f"{v:.3g}" if v is not None else "?" for v in ci)
        return f"{m:.3g} [{lo}, {hi}]"

    for cond, d in sd["conditions"].items():
        rho = f"{d['spearman_rho']:.2f} (p {d['p_value']:.2g}, {d['flights']} flights)"
        for c, r in d["vs_reference"].items():
            lines.append(
                f"| {cond} | {c} | {iv(r['tracking_ratio'], r['tracking_ci'])} | "
                f"{iv(r['error_ratio'], r['error_ci'])} | {rho} |"
            )
    return lines


# --------------------------------------------------------------------------- stage
