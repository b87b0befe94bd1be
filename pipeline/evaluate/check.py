"""One held-out flight against one controller's certificate: the table row and the per-sample
frame (docs/evaluation.md#the-bound-check; paper, Bounded Perception Error Guarantee). Pure:
the certificate's numbers (:class:`~qsls.pipeline.evaluate.certified.ControllerBound`), the
training states and the flight's table in; the row and the samples out.

For a controller certified with an S-slope ``S``, error bound ``eps_e`` (and ``R0``), process
noise ``eps_w`` and responses ``Phi``, the certificate states (docs/guarantee.md)::

    ||e|| <= gamma        = (eps_e + S a) / (1 - S ||Phi_xy||),  a = eps_w ||Phi_xx H|| + Delta
    ||e|| <= gamma_strict = R0 / (1 - S ||Phi_xy||)              (the paper's comparison)

Each row (one flight, one controller) holds three things:

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.evaluate.certified import ControllerBound
from qsls.pipeline.evaluate.theorem import (
    TheoremNumbers,
    premise_only,
    theorem_check,
    theorem_verdict,
    uniform_grid,
)
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE
from qsls.pipeline.ingest.flight import errors, states
from qsls.pipeline.premise import honest


def finite_samples(name: str, x: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Flight ``name``'s samples with finite states ``x`` and errors ``e`` (a flight without
    one is refused)."""
    ok = np.isfinite(x).all(axis=1) & np.isfinite(e).all(axis=1)
    if not ok.any():
        raise InputError(f"flight {name}: no samples with finite states and errors")
    return ok


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
    theorem is checked only when it is ``bound`` itself (module docstring). ``nearest``: the
    training states nearest to the flight's finite samples, ``(d_k, i(k))``, where known."""
    x_all, e_all, t_all = states(flight), errors(flight), flight["t"].to_numpy(float)
    ok = finite_samples(name, x_all, e_all)
    d, idx = nearest if nearest is not None else training.nearest(x_all[ok])
    p = premise_on_flight(bound, x_all[ok], e_all[ok], t_all[ok], d, idx, training)
    problems = list(p.problems)
    why_not = _why_theorem_not(bound, flown_by, t_all)
    d_hat = np.full(len(p.t), np.nan)
    if why_not is None:
        assert bound.phi_xy is not None
        certified = TheoremNumbers(bound.numbers, bound.a_certificate, bound.phi_xy_tail)
        theorem, d_hat_all = theorem_check(
            x_all, e_all, t_all, bound.phi_xy, certified, training.scale, training.distance
        )
        d_hat = d_hat_all[ok]
        head = theorem_verdict(theorem, float(p.e_norm[p.k_err]), certified)
        if not theorem["bound_holds"] and p.holds and p.within_radius:
            problems.append("although the premise holds on this flight")
    else:
        theorem = premise_only(bound.a_certificate)
        head = f"premise only ({why_not}: the theorem does not apply)"
    row = {
        "flight": name,
        "controller": bound.name,
        "flown_by": flown_by or "",
        **_certificate_columns(bound),
        **theorem,
        **p.columns(int((~ok).sum())),
        "verdict": "; ".join([head, *problems]),
    }
    samples = pd.DataFrame(
        {
            "flight": name,
            "controller": bound.name,
            "t": p.t,
            "error_norm": p.e_norm,
            "distance": d,
            "nominal_distance": d_hat,
            "gamma": p.gamma_k,
            "gamma_strict": np.full(len(p.t), bound.gamma_strict),
            "gamma_nominal": np.full(len(p.t), theorem["gamma_nominal"]),
            "premise": p.premise_k,
        }
    )
    return row, samples


def _certificate_columns(bound: ControllerBound) -> dict[str, Any]:
    """The row's columns that restate the certificate (its norms recomputed from the taps)."""
    return {
        "status": bound.status,
        "robust": bound.robust,
        "S": bound.numbers.S,
        "eps_e": bound.numbers.eps,
        "R0": bound.r0,
        "norm_phi_xy": bound.norm_phi_xy,
        "norm_phi_xx_h": bound.norm_phi_xx_h,
        "has_guarantee": bound.has_guarantee,
    }


@dataclass(frozen=True)
class PremiseOnFlight:
    """The premise ``||e_k|| <= eps_e + S d_k`` and the per-sample curve ``gamma_k`` on one
    flight's finite samples (``x``, ``e``, ``t``; ``d`` and ``idx`` their nearest training
    states): what the row says whether or not the theorem applies."""

    bound: ControllerBound
    x: np.ndarray
    t: np.ndarray
    d: np.ndarray
    e_norm: np.ndarray
    """``||e_k||``, or the dense part ``|d_k|_e`` under the generalized premise."""
    gamma_k: np.ndarray
    premise_k: np.ndarray
    ratio: np.ndarray
    ratio_strict: np.ndarray
    premise_ratio: np.ndarray
    windows: OutlierWindows
    max_slope: float
    problems: tuple[str, ...]
    """What the verdict says besides its head (:func:`_premise_problems`, the outlier count)."""

    @property
    def inside(self) -> np.ndarray:
        return self.d < self.bound.numbers.radius

    @property
    def within_radius(self) -> bool:
        return bool(np.all(self.inside))

    @property
    def dense_holds(self) -> bool:
        return bool(np.all(self.premise_ratio <= 1.0))

    @property
    def holds(self) -> bool:
        return self.dense_holds and self.windows.holds

    @property
    def k_err(self) -> int:
        return int(np.argmax(self.e_norm))

    def columns(self, n_dropped: int) -> dict[str, Any]:
        """The row's columns after the theorem's, in the table's order."""
        b, e_norm, gamma_k, t, x, d = self.bound, self.e_norm, self.gamma_k, self.t, self.x, self.d
        k_ratio, k_err, k_dist = int(np.argmax(self.ratio)), self.k_err, int(np.argmax(d))
        k_prem = int(np.argmax(self.premise_ratio))
        return {
            "gamma": float(gamma_k.max()),
            "gamma_min": float(gamma_k.min()),
            "gamma_certificate": b.gamma_certificate,
            "gamma_strict": b.gamma_strict,
            "max_error_norm": float(e_norm[k_err]),
            "max_error_norm_t": float(t[k_err]),
            "rms_error_norm": float(np.sqrt(np.mean(e_norm**2))),
            "n_samples": len(t),
            "n_nonfinite_dropped": n_dropped,
            "frac_under_gamma": float(np.mean(e_norm <= gamma_k)),
            "frac_under_gamma_strict": float(np.mean(e_norm <= b.gamma_strict)),
            "max_ratio": float(self.ratio[k_ratio]),
            "max_ratio_t": float(t[k_ratio]),
            "max_ratio_px": float(x[k_ratio, 0]),
            "max_ratio_py": float(x[k_ratio, 1]),
            "max_ratio_pz": float(x[k_ratio, 2]),
            "max_ratio_strict": float(np.max(self.ratio_strict)),
            "max_distance_to_training": float(d[k_dist]),
            "max_distance_t": float(t[k_dist]),
            "mean_distance_to_training": float(d.mean()),
            "radius": b.numbers.radius,
            "frac_within_radius": float(np.mean(self.inside)),
            "frac_premise_holds": float(np.mean(self.premise_ratio <= 1.0)),
            "max_premise_ratio": float(self.premise_ratio[k_prem]),
            "max_premise_ratio_t": float(t[k_prem]),
            "max_slope_to_training": self.max_slope,
            "max_outliers_in_window": self.windows.largest,
            "frac_windows_over_m": self.windows.share_over,
            "local_bound_holds": bool(np.all(e_norm <= gamma_k)) if b.finite else False,
            "strict_bound_holds": bool(np.all(e_norm <= b.gamma_strict)),
            "assumption_holds": self.holds and self.within_radius,
            "premise_holds": self.holds,
        }


def premise_on_flight(
    bound: ControllerBound,
    x: np.ndarray,
    e: np.ndarray,
    t: np.ndarray,
    d: np.ndarray,
    idx: np.ndarray,
    training: TrainingData,
) -> PremiseOnFlight:
    """:class:`PremiseOnFlight` of the finite samples ``x``, ``e`` at ``t`` whose nearest
    training states are ``idx`` at distances ``d``."""
    # the premise bounds the dense part |d_k|_e (the whole ||e_k|| in the special case)
    e_norm = bound.dense(e) if bound.generalized else np.abs(e).max(axis=1)
    gamma_k = bound.gamma_at(d)
    premise_k = bound.premise_at(d)
    inside = d < bound.numbers.radius
    ratio, ratio_strict, premise_ratio = _ratios(e_norm, gamma_k, bound.gamma_strict, premise_k)
    k_prem = int(np.argmax(premise_ratio))
    windows = outlier_windows(bound, e)
    max_slope = _max_slope_to_training(e, d, idx, inside, training)
    problems = _premise_problems(
        bound, bool(np.all(premise_ratio <= 1.0)), bool(np.all(inside)),
        float(premise_ratio[k_prem]), float(t[k_prem]), max_slope,
        float(np.mean(premise_ratio <= 1.0)),
    )  # fmt: skip
    if not windows.holds:
        problems.append(windows.text())
    return PremiseOnFlight(
        bound, x, t, d, e_norm, gamma_k, premise_k, ratio, ratio_strict, premise_ratio,
        windows, max_slope, tuple(problems),
    )  # fmt: skip


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
