"""The guarantee on held-out flights: ``||e_k||`` against the certified bounds (docs/evaluation.md; paper, Bounded Perception Error Guarantee).

For a controller certified with an S-slope ``S``, error bound ``eps_e`` (and ``R0``), process
noise ``eps_w`` and responses ``Phi``, the certificate states (docs/guarantee.md)::

    ||e|| <= gamma        = (eps_e + S a) / (1 - S ||Phi_xy||),  a = eps_w ||Phi_xx H|| + Delta
    ||e|| <= gamma_strict = R0 / (1 - S ||Phi_xy||)              (the paper's comparison)

Each row of the check (one flight, one controller) holds three things:

- **The theorem** (:mod:`.theorem`), only on a flight the controller flew itself: ``x_hat``,
  ``a_nominal``, ``gamma_nominal = (eps_e + S a_nominal) / (1 - S ||Phi_xy||)`` and the verdict
  ``bound_holds = max_k ||e_k|| <= gamma_nominal``. On a recorded log or another controller's
  flight the theorem does not apply: those columns are empty and the verdict says so.
- **The premise** ``||e_k|| <= eps_e + S d_k`` with ``d_k = min_i ||W (x_k - x_i)||`` the
  flown state's distance to the nearest training state (KD-tree, infinity norm, ``W`` the
  error model's ``state_scale``), within the radius ``r``: the share of samples where it holds,
  the worst ratio and when. This tests the error model (how it generalizes), not the
  controller.
- **The per-sample curve** ``gamma_k = (eps_e + S (eps_w ||Phi_xx H|| + d_k)) / (...)``, kept for
  the figures (columns ``gamma``, ``max_ratio``, ``frac_under_gamma``, ``local_bound_holds``).
  It is *not* the theorem's bound: it holds wherever the premise holds (``gamma_k >= eps_e +
  S d_k``), and ``d_k`` does not bound the theorem's distance (on the quickstart's
  ``l1_robust`` flight ``max d_k`` = 0.122 while ``a_nominal`` = 0.152).

When the theorem's bound fails the verdict says whether the premise failed on the flight
(the certified S or eps_e is too small for where the vehicle went) or whether it failed
although its premise held (which the theory rules out on the linear plant; look for model
mismatch or a flight outside the radius).

Outputs (``evaluate``): ``evaluation.parquet`` (one row per flight and controller),
``evaluation.json`` (the same rows, per-controller totals, warnings), ``samples.parquet``
(per-sample ``||e_k||``, ``d_k``, ``gamma_k``, ``d(x_hat_k)`` for the report) and figures.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control import guarantee
from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.nominal import static_gain_responses
from qsls.pipeline.core.artifacts import StageWriter, read_manifest, require_stage
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import (
    ErrorModel,
    load_error_model,
    resolve_model,
)
from qsls.pipeline.evaluate import figures as plots
from qsls.pipeline.evaluate.assumptions import check_assumptions
from qsls.pipeline.evaluate.certified import (
    ControllerBound,
    calibration_of,
    certificate_for,
    certified_premise,
    check_model_hash,
    expand_controllers,
    load_bounds,
    load_conditioned,
    load_controller_bound,
    outside_calibration,
)
from qsls.pipeline.evaluate.conditions import flight_conditions
from qsls.pipeline.evaluate.flownby import flown_by
from qsls.pipeline.evaluate.mismatch import flight_mismatches, skipped_controller_folders
from qsls.pipeline.evaluate.nees import Nees, flight_nees
from qsls.pipeline.evaluate.options import CheckOptions, EvaluateOptions
from qsls.pipeline.evaluate.table import Evaluation
from qsls.pipeline.evaluate.theorem import (
    TheoremNumbers,
    premise_only,
    theorem_check,
    theorem_verdict,
    uniform_grid,
)
from qsls.pipeline.evaluate.training import TrainingData, load_training
from qsls.pipeline.evaluate.twins import twin_warnings
from qsls.pipeline.evaluate.verdict import (
    ASSUMPTIONS_FILE,
    AssumptionVerdict,
    Verdict,
    combined,
    controller_promises,
    with_promises,
)
from qsls.pipeline.ingest.flight import errors, read_flight, states
from qsls.pipeline.premise import honest
from qsls.pipeline.sim.simulate import TRUTH_FILE
from qsls.pipeline.sim.ticks import TICKS_FILE, TickLog

__all__ = [
    "ControllerBound",
    "EvaluateOptions",
    "EvaluateResult",
    "TrainingData",
    "bound_check",
    "check_flight",
    "check_model_hash",
    "evaluate",
    "expand_controllers",
    "load_bounds",
    "load_controller_bound",
    "load_flights",
    "load_training",
    "resolve_model",
    "weighted_bounds",
    "write_tables",
]


# --------------------------------------------------------------------------- the check
def check_flight(
    name: str,
    flight: pd.DataFrame,
    bound: ControllerBound,
    training: TrainingData,
    nearest: tuple[np.ndarray, np.ndarray] | None = None,
    flown_by: str | None = None,
) -> tuple[dict[str, Any], pd.DataFrame]:
    """One flight against one controller: the table row and the per-sample frame.

    ``flown_by`` names the controller that flew the flight (``None``: a recorded log); the
    theorem is checked only when it is ``bound`` itself (module docstring)."""
    x_all = states(flight)
    e_all = errors(flight)
    t_all = flight["t"].to_numpy(float)
    ok = np.isfinite(x_all).all(axis=1) & np.isfinite(e_all).all(axis=1)
    if not ok.any():
        raise InputError(f"flight {name}: no samples with finite states and errors")
    d, idx = nearest if nearest is not None else training.nearest(x_all[ok])
    x, e, t, n_dropped = x_all[ok], e_all[ok], t_all[ok], int((~ok).sum())
    # the premise bounds the dense part |d_k|_e (the whole ||e_k|| in the special case)
    e_norm = bound.dense(e) if bound.generalized else np.abs(e).max(axis=1)
    gamma_k = bound.gamma_at(d)
    gamma_strict = bound.gamma_strict
    premise_k = bound.premise_at(d)
    inside = d < bound.numbers.radius
    ratio, ratio_strict, premise_ratio = _ratios(e_norm, gamma_k, gamma_strict, premise_k)
    k_ratio, k_err, k_dist = int(np.argmax(ratio)), int(np.argmax(e_norm)), int(np.argmax(d))
    k_prem = int(np.argmax(premise_ratio))
    dense_holds = bool(np.all(premise_ratio <= 1.0))
    frac_premise = float(np.mean(premise_ratio <= 1.0))
    windows = outlier_windows(bound, e)
    premise_holds = dense_holds and windows.holds
    within_radius = bool(np.all(inside))
    max_slope = _max_slope_to_training(e, d, idx, inside, training)
    problems = _premise_problems(
        bound, dense_holds, within_radius, float(premise_ratio[k_prem]), float(t[k_prem]),
        max_slope, frac_premise,
    )  # fmt: skip
    if not windows.holds:
        problems.append(windows.text())
    why_not = _why_theorem_not(bound, flown_by, t_all)
    d_hat = np.full(len(t), np.nan)
    if why_not is None:
        assert bound.phi_xy is not None
        certified = TheoremNumbers(bound.numbers, bound.a_certificate, bound.phi_xy_tail)
        theorem, d_hat_all = theorem_check(
            x_all, e_all, t_all, bound.phi_xy, certified, training.scale, training.distance
        )
        d_hat = d_hat_all[ok]
        head = theorem_verdict(theorem, float(e_norm[k_err]), certified)
        if not theorem["bound_holds"] and premise_holds and within_radius:
            problems.append("although the premise holds on this flight")
    else:
        theorem = premise_only(bound.a_certificate)
        head = f"premise only ({why_not}: the theorem does not apply)"
    row = {
        "flight": name,
        "controller": bound.name,
        "flown_by": flown_by or "",
        "status": bound.status,
        "robust": bound.robust,
        "S": bound.numbers.S,
        "eps_e": bound.numbers.eps,
        "R0": bound.r0,
        "norm_phi_xy": bound.norm_phi_xy,
        "norm_phi_xx_h": bound.norm_phi_xx_h,
        "has_guarantee": bound.has_guarantee,
        **theorem,
        "gamma": float(gamma_k.max()),
        "gamma_min": float(gamma_k.min()),
        "gamma_certificate": bound.gamma_certificate,
        "gamma_strict": gamma_strict,
        "max_error_norm": float(e_norm[k_err]),
        "max_error_norm_t": float(t[k_err]),
        "rms_error_norm": float(np.sqrt(np.mean(e_norm**2))),
        "n_samples": len(t),
        "n_nonfinite_dropped": n_dropped,
        "frac_under_gamma": float(np.mean(e_norm <= gamma_k)),
        "frac_under_gamma_strict": float(np.mean(e_norm <= gamma_strict)),
        "max_ratio": float(ratio[k_ratio]),
        "max_ratio_t": float(t[k_ratio]),
        "max_ratio_px": float(x[k_ratio, 0]),
        "max_ratio_py": float(x[k_ratio, 1]),
        "max_ratio_pz": float(x[k_ratio, 2]),
        "max_ratio_strict": float(np.max(ratio_strict)),
        "max_distance_to_training": float(d[k_dist]),
        "max_distance_t": float(t[k_dist]),
        "mean_distance_to_training": float(d.mean()),
        "radius": bound.numbers.radius,
        "frac_within_radius": float(np.mean(inside)),
        "frac_premise_holds": frac_premise,
        "max_premise_ratio": float(premise_ratio[k_prem]),
        "max_premise_ratio_t": float(t[k_prem]),
        "max_slope_to_training": max_slope,
        "max_outliers_in_window": windows.largest,
        "frac_windows_over_m": windows.share_over,
        "local_bound_holds": bool(np.all(e_norm <= gamma_k)) if bound.finite else False,
        "strict_bound_holds": bool(np.all(e_norm <= gamma_strict)),
        "assumption_holds": premise_holds and within_radius,
        "premise_holds": premise_holds,
        "verdict": "; ".join([head, *problems]),
    }
    samples = pd.DataFrame(
        {
            "flight": name,
            "controller": bound.name,
            "t": t,
            "error_norm": e_norm,
            "distance": d,
            "nominal_distance": d_hat,
            "gamma": gamma_k,
            "gamma_strict": np.full(len(t), gamma_strict),
            "gamma_nominal": np.full(len(t), theorem["gamma_nominal"]),
            "premise": premise_k,
        }
    )
    return row, samples


@dataclass(frozen=True)
class OutlierWindows:
    """The sparse part of the premise on a flight: outliers (velocity errors beyond ``beta``)
    counted in every window of ``T`` samples against ``m``; it does not depend on the
    controller, so it is checked on every flight, recorded ones included."""

    m: int
    window: int
    largest: int
    share_over: float

    @property
    def holds(self) -> bool:
        return self.largest <= self.m

    def text(self) -> str:
        return (
            f"outlier count broken: up to {self.largest} outliers in a window of {self.window} "
            f"samples > m = {self.m} ({100 * self.share_over:.1f}% of windows)"
        )


def outlier_windows(bound: ControllerBound, e: np.ndarray) -> OutlierWindows:
    """:class:`OutlierWindows` of the errors ``e`` under ``bound``'s premise (none to count
    without a ``beta``: the premise then has no sparse part and ``m = 0``)."""
    window = int(bound.certificate.get("T") or 0)
    m = int(bound.certificate.get("m") or 0)
    if not math.isfinite(bound.beta) or window <= 0:
        return OutlierWindows(m, window, 0, 0.0)
    _, o = honest.split_errors(e, bound.beta, bound.measure)
    counts = honest.window_counts(np.abs(o).max(axis=1) > 0, np.zeros(len(e), int), window)
    full = counts[window - 1 :] if len(counts) >= window else counts
    return OutlierWindows(m, window, int(counts.max()), float(np.mean(full > m)))


def _why_theorem_not(bound: ControllerBound, flown_by: str | None, t: np.ndarray) -> str | None:
    """Why the theorem cannot be checked on this flight against ``bound`` (``None``: it can)."""
    if not flown_by:
        return "a recorded flight"
    if bound.generalized:
        return f"its guarantee is checked on the controller's own log: {ASSUMPTIONS_FILE}"
    if flown_by != bound.name:
        return f"flown by {flown_by}"
    if bound.phi_xy is None or not math.isfinite(bound.dt):
        return "controller without responses"
    if not uniform_grid(t, bound.dt):
        return f"flight not sampled at the controller's dt = {bound.dt:g} s"
    return None


def _ratios(
    e_norm: np.ndarray, gamma_k: np.ndarray, gamma_strict: float, premise_k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``||e_k||`` over ``gamma_k``, over ``gamma_strict`` and over the premise ``eps_e + S d_k``
    (0 where a bound is infinite)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(gamma_k), e_norm / gamma_k, 0.0)
        strict = e_norm / gamma_strict if math.isfinite(gamma_strict) else np.zeros_like(e_norm)
        return ratio, strict, e_norm / premise_k


def _max_slope_to_training(
    e: np.ndarray, d: np.ndarray, idx: np.ndarray, inside: np.ndarray, training: TrainingData
) -> float:
    """``max_k ||e_k - e_i(k)|| / d_k`` to the nearest training state ``i(k)`` within the
    radius and beyond the model's minimum separation (NaN without training errors)."""
    if training.e is None:
        return math.nan
    use = (d > max(training.min_separation, 1e-9)) & inside
    if not np.any(use):
        return math.nan
    return float((np.abs(e - training.e[idx]).max(axis=1)[use] / d[use]).max())


def _premise_problems(
    bound: ControllerBound,
    premise_holds: bool,
    within_radius: bool,
    premise_ratio: float,
    premise_t: float,
    max_slope: float,
    frac_premise: float,
) -> list[str]:
    """What the verdict says besides its head: a missing guarantee, the premise failing on
    the flight, the flight leaving the radius."""
    problems = []
    if not bound.has_guarantee:
        problems.append(
            f"no guarantee: {bound.no_guarantee_reason}, the formula's value is shown for comparison"
        )
    if not premise_holds:
        slope = (
            f", held-out slope to training {max_slope:.3g} > S"
            if max_slope > bound.numbers.S
            else ""
        )
        problems.append(
            f"premise violated at {100 * (1 - frac_premise):.1f}% of samples: ||e|| reaches "
            f"{premise_ratio:.3g}x eps_e + S*d at t={premise_t:.2f}s (certified S={bound.numbers.S:.3g}, "
            f"eps_e={bound.numbers.eps:.3g} are too small for this flight{slope})"
        )
    else:
        problems.append("premise holds at every sample")
    if not within_radius:
        problems.append(
            f"flight leaves the radius r={bound.numbers.radius:.3g} around the training states"
        )
    return problems


# --------------------------------------------------------------------------- stage
@dataclass(frozen=True)
class EvaluateResult:
    out: Path
    table: pd.DataFrame
    warnings: tuple[str, ...]
    assumptions: pd.DataFrame | None = None
    """Every assumption on the flights a controller flew itself (``--flown-by``, from their
    tick logs); None when there are none."""
    nees: tuple[Nees, ...] = ()
    """The position NEES of each flight whose VIO recorded covariances (:mod:`.nees`)."""
    promises: Mapping[str, str] = field(default_factory=dict)
    """Each controller's promise, the sentence its verdict leads with (:mod:`.verdict`)."""

    def verdicts(self) -> list[Verdict | AssumptionVerdict]:
        """Each controller's verdict, led by its promise (:func:`.verdict.combined`)."""
        return with_promises(combined(self.table, self.assumptions), self.promises)

    def summary(self) -> dict[str, Any]:
        t = self.table
        out: dict[str, Any] = {
            "output": self.out.as_posix(),
            "flights": int(t["flight"].nunique()),
            "controllers": int(t["controller"].nunique()),
        }
        for c, g in t.groupby("controller", sort=False):
            # the per-sample curve gamma(d_k) checks the premise, not the controller: the
            # theorem's verdict is printed after the summary (verdict.py)
            out[f"{c}"] = (
                f"max ||e|| {g['max_error_norm'].max():.4g}; premise curve gamma(d_k): under "
                f"{100 * g['frac_under_gamma'].mean():.1f}%, max ratio {g['max_ratio'].max():.3g}; "
                f"gamma_strict {g['gamma_strict'].iloc[0]:.4g} (under "
                f"{100 * g['frac_under_gamma_strict'].mean():.1f}%)"
            )
        for n in self.nees:  # the estimator's own uncertainty, beside the bound
            out[f"VIO position NEES, {n.flight}"] = n.text()
        if self.warnings:
            out["warnings"] = len(self.warnings)
        return out


def load_flights(folders: Sequence[Path]) -> list[tuple[str, pd.DataFrame]]:
    """Read held-out flights (flight folders or ``flight.parquet`` files), unique names."""
    if not folders:
        raise InputError("no flights given; pass at least one --flights folder from 'qsls ingest'")
    out: list[tuple[str, pd.DataFrame]] = []
    seen: dict[str, int] = {}
    for f in folders:
        f = Path(f)
        df = read_flight(f)
        base = f.name if f.is_dir() else f.parent.name
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}_{seen[base]}"
        out.append((name, df))
    return out


def bound_check(
    flights: Sequence[tuple[str, pd.DataFrame]],
    bounds: Sequence[ControllerBound],
    training: TrainingData,
    *,
    pairs: Sequence[tuple[int, int]] | None = None,
    flown_by: Sequence[str | None] | None = None,
    progress: Progress = NULL_PROGRESS,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every flight against every controller (or the given ``(flight, controller)`` index
    pairs): ``(rows, samples)``. ``flown_by[i]`` names the controller that flew flight ``i``
    (``None``: recorded). Nearest distances are computed once per flight."""
    if pairs is None:
        pairs = [(i, j) for i in range(len(flights)) for j in range(len(bounds))]
    progress.start("bound check", total=len(pairs))
    nearest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    rows, samples = [], []
    for i, j in pairs:
        name, df = flights[i]
        if i not in nearest:
            x = states(df)
            ok = np.isfinite(x).all(axis=1) & np.isfinite(errors(df)).all(axis=1)
            if not ok.any():
                raise InputError(f"flight {name}: no samples with finite states and errors")
            nearest[i] = training.nearest(x[ok])
        by = flown_by[i] if flown_by is not None else None
        row, s = check_flight(name, df, bounds[j], training, nearest[i], by)
        rows.append(row)
        s.insert(1, "flown_by", by or "")
        samples.append(s)
        progress.advance()
    progress.finish()
    return pd.DataFrame(rows), pd.concat(samples, ignore_index=True)


def with_conditions(
    table: pd.DataFrame,
    flights: Sequence[tuple[str, pd.DataFrame]],
    conditions: Sequence[str],
    pairs: Sequence[tuple[int, int]],
    bounds: Sequence[ControllerBound],
    estimators: Sequence[str] | None = None,
) -> pd.DataFrame:
    """The table with each row's flight ``condition`` and ``outside_calibration`` (why the
    certificate it was checked against was calibrated under other conditions, ``''`` when
    not: :func:`qsls.pipeline.evaluate.certified.outside_calibration`; ``estimators[i]``:
    flight ``i``'s estimator, ``''`` where not known)."""
    est = list(estimators) if estimators is not None else [""] * len(flights)
    span = [float(df["t"].iloc[-1] - df["t"].iloc[0]) if len(df) else 0.0 for _, df in flights]
    out = table.copy()
    out.insert(3, "condition", [conditions[i] for i, _ in pairs])
    cal = {j: calibration_of(bounds[j].folder) for j in dict.fromkeys(j for _, j in pairs)}
    out["outside_calibration"] = [
        outside_calibration(cal[j], conditions[i], span[i], est[i]) for i, j in pairs
    ]
    return out


def controller_totals(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per controller over all its flights: the worst case and the fractions."""
    out = []
    for c, g in table.groupby("controller", sort=False):
        out.append(
            {
                "controller": c,
                "flights": len(g),
                "gamma_strict": float(g["gamma_strict"].iloc[0]),
                "gamma_max": float(g["gamma"].max()),
                "max_error_norm": float(g["max_error_norm"].max()),
                "frac_under_gamma": float(g["frac_under_gamma"].mean()),
                "frac_under_gamma_strict": float(g["frac_under_gamma_strict"].mean()),
                "max_ratio": float(g["max_ratio"].max()),
                **_theorem_totals(g),
                "frac_premise_holds": float(g["frac_premise_holds"].mean()),
                "assumption_holds_all": bool(g["assumption_holds"].all()),
            }
        )
    return out


def _theorem_totals(g: pd.DataFrame) -> dict[str, Any]:
    """Over one controller's rows where the theorem applies (its own flights): how many, did
    the bound hold on all, the worst ``max ||e|| / gamma_nominal`` (None without such rows)."""
    own = g[g["theorem_applies"].astype(bool)] if "theorem_applies" in g else g.iloc[:0]
    if not len(own):
        return {"theorem_flights": 0, "bound_holds_all": None, "max_nominal_ratio": None}
    ratio = pd.to_numeric(own["nominal_ratio"], errors="coerce")
    return {
        "theorem_flights": len(own),
        "bound_holds_all": bool(own["bound_holds"].astype(bool).all()),
        "max_nominal_ratio": float(ratio.max()) if ratio.notna().any() else None,
        "max_a_nominal": float(own["a_nominal"].max()),
    }


def weighted_bounds(
    bounds: Iterable[ControllerBound], state_scale: Sequence[float]
) -> list[ControllerBound]:
    """The bounds in the error model's norms (docs/guarantee.md#weighted-norms): with
    ``W_x = diag(state_scale)`` and the certificate's ``W_e``, the S-slope is a slope in the
    weighted distance, so the bound reads ``N = ||W_x Phi_xy W_e^-1||`` and
    ``N_w = ||W_x Phi_xx H||`` in place of ``||Phi_xy||`` and ``||Phi_xx H||`` (a static gain's
    tail beyond its taps weighted by the largest weight). Unchanged for an unweighted model;
    a certificate stating its premise in other state weights than the model's is refused."""
    scale = tuple(float(v) for v in state_scale)
    out = []
    for b in bounds:
        premise = b.certificate.get("premise") or {}
        stated = tuple(float(v) for v in premise.get("state_scale") or (1.0,) * len(scale))
        if stated != scale:
            raise InputError(
                f"{b.name}: its certificate states the premise in state_scale {list(stated)}, "
                f"the error model in {list(scale)}; check it against the error model it was "
                "synthesized from"
            )
        if all(v == 1.0 for v in scale):
            out.append(b)
            continue
        ctrl = load_controller_dir(b.folder).controller
        taps, model = ctrl.taps, ctrl.model
        tails = {"phi_xy": 0.0, "phi_xx_h": 0.0}
        if ctrl.kind == "static_gain" and ctrl.K is not None:
            true = ctrl.norms()
            tails = {k: true[k].tail_bound for k in tails}
            taps = static_gain_responses(model, ctrl.K, true["phi_xy"].horizon)
        extra = model.nx - len(scale)  # the attitude plant's states: unweighted, error-free
        sx = (*scale, *(0.0,) * extra)
        se = (*b.error_scale, *(1.0,) * (taps.Phi_xy.shape[2] - len(b.error_scale)))
        # every error channel, read or not, as the unweighted ||Phi_xy|| (a FIR controller's
        # unread columns vanish; a PD reads them all)
        channels = tuple(range(len(se)))
        norms = guarantee.system_norms(
            taps.Phi_xy, taps.Phi_xx @ model.H, state_scale=sx, error_scale=se, measured=channels
        )
        inv_e = guarantee.error_weights(se, channels)
        w = max(scale)
        out.append(
            replace(
                b,
                norm_phi_xy=norms.N + w * float(inv_e.max()) * tails["phi_xy"],
                norm_phi_xx_h=norms.N_w + w * tails["phi_xx_h"],
            )
        )
    return out


def evaluate(
    flights: Sequence[Path],
    error_model: Path,
    controllers: Sequence[Path],
    options: EvaluateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
    conditions: Sequence[str] | None = None,
    by_condition: Mapping[str, Sequence[Path]] | None = None,
    estimators: Sequence[str] | None = None,
) -> EvaluateResult:
    """The bound check of every held-out flight against every controller's certificate.

    ``conditions[i]``: flight ``i``'s perception condition (``''`` where not known, as for a
    recorded log); ``estimators[i]``: the estimator that made flight ``i``'s estimate
    (``camera``, ``emulator``; ``''`` where not known); ``by_condition``: per condition, the
    certificates a calibration wrote for it (``calibrate/<condition>/``). A flight is checked
    against its condition's certificate where there is one, else the controller's own, and the
    table's ``outside_calibration``
    says when that certificate was calibrated under other conditions (docs/calibration.md,
    "One certificate per condition")."""
    model_file, fit_dir = resolve_model(error_model)
    model = load_error_model(model_file)
    folders = expand_controllers(controllers)
    if not folders:
        raise InputError("no controllers given; pass at least one --controller folder")
    bounds = weighted_bounds(load_bounds(folders), model.state_scale)
    if options.flown_by is not None and options.flown_by not in {b.name for b in bounds}:
        raise InputError(
            f"--flown-by {options.flown_by}: not among the controllers "
            f"({', '.join(b.name for b in bounds)})"
        )
    warnings = [w for b in bounds if (w := check_model_hash(b, model_file, force=force))]
    training = load_training(fit_dir, model, options.state_scale)
    held_out = load_flights(flights)
    warnings += skipped_controller_folders(controllers)
    warnings += flight_mismatches(held_out, bounds, training)
    warnings += twin_warnings(flights, held_out, fit_dir)
    for f in flights:
        try:
            require_stage(Path(f) if Path(f).is_dir() else Path(f).parent, "ingest")
        except InputError as exc:
            warnings.append(str(exc))
    conds = list(conditions) if conditions is not None else [""] * len(held_out)
    if len(conds) != len(held_out):
        raise InputError(f"{len(conds)} conditions given for {len(held_out)} flights")
    ests = list(estimators) if estimators is not None else [""] * len(held_out)
    if len(ests) != len(held_out):
        raise InputError(f"{len(ests)} estimators given for {len(held_out)} flights")
    conditioned = load_conditioned(by_condition, [b.name for b in bounds], sorted(set(conds)))
    weighted = weighted_bounds(conditioned.values(), model.state_scale)
    conditioned = dict(zip(conditioned, weighted, strict=True))
    warnings += [
        m for b in conditioned.values() if (m := check_model_hash(b, model_file, force=force))
    ]
    every = [*bounds, *conditioned.values()]
    at = {id(b): j for j, b in enumerate(every)}
    named = {b.name: b for b in bounds}
    pairs = [
        (i, at[id(b)])
        for i, cond in enumerate(conds)
        for j in range(len(bounds))
        if (b := certificate_for(bounds[j].name, cond, named, conditioned)) is not None
    ]
    table, samples = bound_check(
        held_out, every, training, pairs=pairs, flown_by=[options.flown_by] * len(held_out),
        progress=progress,
    )  # fmt: skip
    table = with_conditions(table, held_out, conds, pairs, every, ests)
    assumptions = None
    if options.flown_by is not None:
        own = [certificate_for(options.flown_by, c, named, conditioned) for c in conds]
        assumptions, missing = own_log_assumptions(flights, own, training, conds, ests)
        warnings += missing
    nees = vio_nees(flights, held_out)
    cond_folders = [b.folder for b in conditioned.values()]
    used = list(dict.fromkeys([model_file, *folders, *cond_folders, *map(Path, flights)]))
    return write_evaluation(
        out,
        table,
        samples,
        warnings,
        options=options,
        inputs=used,
        model=model,
        force=force,
        assumptions=assumptions,
        nees=nees,
        promises=controller_promises((b.name, b.certificate) for b in every),
    )


def vio_nees(
    folders: Sequence[Path], flights: Sequence[tuple[str, pd.DataFrame]]
) -> tuple[Nees, ...]:
    """The position NEES (:mod:`.nees`) of every flight whose VIO recorded covariances, with
    the alignment its ingest manifest keeps."""
    out = []
    for f, (name, frame) in zip(folders, flights, strict=True):
        folder = Path(f) if Path(f).is_dir() else Path(f).parent
        if "var_px" not in frame.columns:
            continue
        try:
            results = dict(read_manifest(folder).get("results") or {})
        except InputError:
            continue
        if (n := flight_nees(name, frame, results)) is not None:
            out.append(n)
    return tuple(out)


def own_log_of(folder: Path) -> tuple[Path | None, str]:
    """Where flight ``folder``'s tick log is, and the controller that flew it (``''`` when not
    recorded): the folder's own ``ticks.parquet`` (the fly stage's and the calibration's
    flights), else the one beside the bag its ingest read (``qsls simulate``), whose
    ``truth.json`` names the controller."""
    if (folder / TICKS_FILE).is_file():
        return folder / TICKS_FILE, ""
    try:
        inputs = read_manifest(folder).get("inputs") or []
    except InputError:
        return None, ""
    for i in inputs:
        src = Path(str(i.get("path", ""))).parent if isinstance(i, dict) else None
        if src is not None and (src / TICKS_FILE).is_file():
            try:
                who = json.loads((src / TRUTH_FILE).read_text()).get("controller", "")
            except (OSError, ValueError, AttributeError):
                who = ""  # no readable truth.json: who flew it is not recorded
            return src / TICKS_FILE, str(who or "")
    return None, ""


def simulated_conditions(ticks: Path) -> dict[str, Any] | None:
    """The recorded conditions of the simulated flight whose tick log is ``ticks`` (vehicle,
    reference, VIO emulator: :func:`qsls.pipeline.evaluate.conditions.flight_conditions`),
    read from the simulate folder's manifest beside it; None where the log is not a
    simulation's (a recorded flight states its conditions in its ingest manifest)."""
    try:
        opts = read_manifest(ticks.parent).get("options")
    except InputError:
        return None
    if not isinstance(opts, dict) or not isinstance(opts.get("vehicle"), dict):
        return None
    return flight_conditions(opts)


def own_log(
    folder: Path, ticks: Path, who: str, bound: ControllerBound
) -> tuple[TickLog | None, str]:
    """Flight ``folder``'s tick log if ``bound``'s controller flew it, else why not: the
    controller ``truth.json`` names (``who``), the one the log names (name and sha256), its
    ticks at the controller's ``dt``, and for a vehicle's log the replay
    (:func:`~qsls.pipeline.evaluate.flownby.flown_by`). A log that cannot be read is named."""
    if who and who != bound.name:
        return None, f"flown by {who}, not {bound.name} ({ticks.parent / TRUTH_FILE})"
    try:
        log = TickLog.read(ticks)
    except InputError as exc:
        return None, str(exc)
    sha = str(bound.certificate.get("controller_sha256", ""))
    if log.controller_sha256 and log.controller_sha256 != sha:
        return None, f"flown by {log.controller or 'another controller'} (its log's sha256)"
    if log.controller and log.controller != bound.name and not log.controller_sha256:
        return None, f"flown by {log.controller}, not {bound.name} (its log)"
    if math.isfinite(bound.dt) and (why := log.off_rate(bound.dt)):
        return None, f"not {bound.name}'s ticks: {why}"
    if recorded := recorded_ticks_facts(folder):  # a vehicle's log: prove who flew it
        proof = flown_by(log, bound.folder, float(recorded["mass_kg"]),
                         dict(recorded.get("stamps") or {}))  # fmt: skip
        if not proof.flown:
            return None, f"not flown by {bound.name} ({proof.reason})"
    return log, ""


def recorded_ticks_facts(folder: Path) -> dict[str, Any]:
    """What the ingest of a vehicle's log recorded of its tick log (``results.ticks``:
    ``qsls ingest LOG --mass``, docs/vehicle.md); empty for any other folder."""
    try:
        m = read_manifest(folder)
    except InputError:
        return {}
    facts = (m.get("results") or {}).get("ticks") if m.get("stage") == "ingest" else None
    return dict(facts) if isinstance(facts, dict) and "mass_kg" in facts else {}


def own_log_assumptions(
    flights: Sequence[Path],
    bounds: Sequence[ControllerBound | None],
    training: TrainingData,
    conditions: Sequence[str] | None = None,
    estimators: Sequence[str] | None = None,
) -> tuple[pd.DataFrame | None, list[str]]:
    """Every assumption of ``bounds[i]``'s guarantee (:mod:`qsls.pipeline.evaluate.assumptions`)
    on each flight ``flights[i]`` that keeps the controller's own tick log (``ticks.parquet``
    beside ``flight.parquet``: ``qsls fly`` and ``qsls calibrate`` write it); a flight
    without one is named, with the log it needs. ``bounds[i]`` is the certificate of the
    controller that flew flight ``i`` (its perception condition's, where calibrated per
    condition, ``conditions[i]``, and estimator, ``estimators[i]``: ``''`` where not known);
    ``outside_calibration`` says when that certificate was calibrated under other conditions."""
    rows, missing = [], []
    conds = list(conditions) if conditions is not None else [""] * len(flights)
    ests = list(estimators) if estimators is not None else [""] * len(flights)
    read = {  # each certificate once: its premise and its calibration record
        b.folder: (certified_premise(b.folder), calibration_of(b.folder))
        for b in bounds
        if b is not None
    }
    for f, bound, condition, estimator in zip(flights, bounds, conds, ests, strict=True):
        if bound is None:
            continue
        premise, calibration = read[bound.folder]
        if premise is None:
            missing.append(f"--flown-by {bound.name}: its certificate states no premise to check")
            continue
        folder = Path(f) if Path(f).is_dir() else Path(f).parent
        ticks, who = own_log_of(folder)
        if ticks is None:
            missing.append(
                f"{folder}: no {TICKS_FILE} (the controller's own log at its ticks: t, x_*, y_*, "
                f"u_*, r_*, uff_*), so the assumptions of {bound.name}'s guarantee cannot be "
                "checked on it; its premise is checked on the ingested flight"
            )
            continue
        log, why = own_log(folder, ticks, who, bound)
        if log is None:
            missing.append(
                f"{folder}: {why}: the assumptions of {bound.name}'s guarantee are checked on "
                "its own flights only"
            )
            continue
        row = check_assumptions(log, premise, training.distance)
        span = float(log.t[-1] - log.t[0]) if len(log.t) else 0.0
        row["outside_calibration"] = outside_calibration(
            calibration, condition, span, estimator, simulated_conditions(ticks)
        )
        rows.append({"flight": folder.name, "controller": bound.name, "status": bound.status,
                     "crashed": False, **row})  # fmt: skip
    return (pd.DataFrame(rows) if rows else None), list(dict.fromkeys(missing))


def write_evaluation(
    out: Path,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    *,
    options: EvaluateOptions,
    inputs: Sequence[Path],
    model: ErrorModel,
    force: bool,
    assumptions: pd.DataFrame | None = None,
    nees: tuple[Nees, ...] = (),
    promises: Mapping[str, str] | None = None,
) -> EvaluateResult:
    """Write the stage folder: ``evaluation.parquet``, ``evaluation.json`` (with each
    controller's ``promises``: :func:`~qsls.pipeline.evaluate.verdict.promise`),
    ``samples.parquet``, figures and, with ``assumptions``, ``assumptions.parquet``."""
    promised = dict(promises or {})
    with StageWriter(out, "evaluate", options=options, inputs=inputs, force=force) as w:
        if assumptions is not None:
            w.write_parquet(ASSUMPTIONS_FILE, assumptions)
        totals = write_tables(w, table, samples, warnings, model, options, {"promises": promised})
        w.results.update(
            {
                "flights": int(table["flight"].nunique()),
                "controllers": totals,
                "warnings": len(warnings),
            }
        )
        if nees:
            w.results["vio_position_nees"] = [n.as_dict() for n in nees]
    return EvaluateResult(
        out=Path(out), table=table, warnings=tuple(warnings), assumptions=assumptions, nees=nees,
        promises=promised,
    )  # fmt: skip


def write_tables(
    w: StageWriter,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    model: ErrorModel,
    options: CheckOptions,
    extra_json: dict[str, Any] | None = None,
    *,
    own_only: bool = False,
) -> list[dict[str, Any]]:
    """The bound check's files inside an open writer; returns the per-controller totals.
    ``own_only``: figures show each flight against the controller that flew it only."""
    totals = controller_totals(table) if len(table) else []
    w.write_parquet("samples.parquet", samples)
    doc = {
        "error_model": {
            "eps_e": model.eps_e,
            "R0": model.R0,
            "S_max": model.s_slope.max,
            "radius": model.radius,
            "state_scale": list(model.state_scale),
        },
        "controllers": totals,
        "rows": table.to_dict(orient="records"),
        "warnings": list(warnings),
        **(extra_json or {}),
    }
    Evaluation(table, doc).save(w)
    if options.figures and len(samples):
        sub = samples
        if own_only and "flown_by" in samples.columns:
            sub = samples[samples["controller"] == samples["flown_by"]]
        names = list(dict.fromkeys(sub["flight"]))[: options.max_figure_flights]
        sub = sub[sub["flight"].isin(names)]
        if not own_only:
            w.write_figure(
                "perception_error.png", plots.perception_error_figure(sub, options.smooth_s)
            )
        w.write_figure("distance_to_training.png", plots.distance_figure(sub, model.radius))
    return totals
