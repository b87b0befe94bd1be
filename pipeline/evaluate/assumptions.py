"""Every assumption of the guarantee, checked on a flight the certified controller flew, with
what the controller saw (docs/guarantee.md, Checks on a flight).

The data are the controller's own log at its own ticks: the truth ``x_k``, what it read
``y_k``, what it commanded ``u_k`` and the reference ``r_k`` (never a re-ingested flight). With
the velocity gate the controller read ``y'_v = clip(y_v - v_ref, -V, V) + v_ref``; the error it
acted on is ``e'_k = y'_k - x_k``, split into dense and sparse parts as the premise says. The
assumptions, in the order the proof uses them:

1. ``disturbance``: the disturbance in the proof's deviation coordinates,
   ``delta_k = dx_{k+1} - A dx_k - B du_k`` (``dx = x - r``, ``du = u - u_hover - uff``), has
   ``||H^-1 delta_k||_inf <= eps_w`` (docs/guarantee.md, Disturbance in deviation coordinates);
   with a bias term, some constant acceleration ``||beta||_inf <= eps_b`` leaves
   ``||H^-1 delta_k - D_w beta||_inf <= eps_w`` (docs/guarantee.md#the-bias-term);
2. ``reference``: ``dist(x_ref,k) <= Delta``, the reference inside the region the premise
   covers (``a = eps_w N_w + Delta`` counts on it);
3. ``nominal``: ``dist(x_hat_k) <= a`` with ``x_hat = x - Phi_xy * e'``;
4. ``invariance``: ``dist(x_k) <= rho* <= r``;
5. ``dense``: ``|d_k|_e <= eps + S dist(x_k)`` at every sample;
6. ``outliers``: at most ``m`` nonzero ``o_k`` in any ``T`` consecutive steps, each
   ``||o_k||_inf <= eps_o``.

The verdict names the assumption that failed first in time (at the same tick, the first in the
proof's order above); ``|d_k|_e <= eps + S rho*`` ("the bound held") is reported as a
consequence only. ``max ||e|| <= gamma`` alone would follow from the
premise at the worst sample whatever ``Phi_xy`` is: it checks the error model, not the controller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control import guarantee
from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.control.guarantee import measured_channels
from qsls.pipeline.errormodel.disturbance import BiasSplit, deviation_disturbance, split_bias
from qsls.pipeline.evaluate.theorem import nominal_states
from qsls.pipeline.premise import honest
from qsls.pipeline.premise.numbers import PremiseNumbers
from qsls.pipeline.sim.ticks import FlownLog as FlownLog

ASSUMPTIONS = ("disturbance", "reference", "nominal", "invariance", "dense", "outliers")


@dataclass(frozen=True)
class CertifiedPremise:
    """What a certificate promises and the premise it rests on, as the checks need it: the
    certificate's premise numbers (:meth:`qsls.pipeline.control.artifacts.Certificate.numbers`),
    its ``a`` and ``rho*``, how the error is split and weighted, and the taps and plant."""

    numbers: PremiseNumbers
    a: float
    rho_star: float
    beta: float
    measure: str
    error_scale: tuple[float, ...]
    phi_xy: np.ndarray
    A: np.ndarray
    B: np.ndarray
    H: np.ndarray
    u_hover: np.ndarray
    bias_dirs: np.ndarray | None = None
    """``D_w`` on the physical states ((6, 3),
    :attr:`qsls.pipeline.core.plant.LinearModel.bias_dirs`); read only when the premise has a
    bias term (``numbers.eps_b > 0``)."""

    @property
    def window(self) -> int:
        return self.phi_xy.shape[0] - 1


def gated_reading(log: FlownLog, gate: float | None) -> np.ndarray:
    """``y'``: what the controller acted on, ``y`` with its velocity through the gate
    (``clip(y_v - v_ref, -V, V) + v_ref``), if any."""
    y = np.array(log.y, dtype=float)
    if gate is not None:  # without one, y itself (not y - r + r, which rounds)
        y[:, 3:] = gated_deviation(y - log.ref, gate)[:, 3:] + log.ref[:, 3:]
    return y


def gated_errors(log: FlownLog, gate: float | None) -> np.ndarray:
    """``e' = y' - x``: the error the controller acted on (:func:`gated_reading`)."""
    return gated_reading(log, gate) - log.x


@dataclass(frozen=True)
class Signals:
    """What a flight shows of each premise quantity, per tick: the error acted on (``e_read``,
    through the gate, the measured channels), ``|d_k|_e``, ``||o_k||_inf``, ``dist(x_k)``,
    ``||H^-1 w_k - D_w beta||_inf`` (``beta = 0`` without a bias term), the outlier count of
    the ``T`` ticks ending at ``k``, and the disturbance's split (its ratio and ``beta``)."""

    e_read: np.ndarray
    dense: np.ndarray
    mag: np.ndarray
    dist: np.ndarray
    w: np.ndarray
    counts: np.ndarray
    split: BiasSplit


def signals(
    log: FlownLog, c: CertifiedPremise, distance: Callable[[np.ndarray], np.ndarray]
) -> Signals:
    """:class:`Signals` of a flight under premise ``c`` (the checks here and the calibration's
    scores read the same ones)."""
    e = gated_errors(log, c.numbers.gate)
    ch = list(measured_channels(c.measure))
    e_read = np.zeros_like(e)
    e_read[:, ch] = e[:, ch]
    d, o = honest.split_errors(e_read, c.beta, c.measure)
    mag = np.abs(o).max(axis=1)
    delta = deviation_disturbance(log.x, log.u, log.ref, log.uff, c.A, c.B, c.u_hover)
    w = np.linalg.solve(np.asarray(c.H, float), delta.T).T
    dirs = c.bias_dirs if c.bias_dirs is not None else np.zeros((w.shape[1], 3))
    split = split_bias(w, dirs, c.numbers.eps_w, c.numbers.eps_b)
    return Signals(
        e_read=e_read,
        dense=honest.weighted_norm(d, c.error_scale),
        mag=mag,
        dist=distance(log.x),
        w=split.residual,
        counts=honest.window_counts(mag > 0, np.zeros(len(mag), int), c.window),
        split=split,
    )


def check_assumptions(
    log: FlownLog, c: CertifiedPremise, distance: Callable[[np.ndarray], np.ndarray]
) -> dict[str, Any]:
    """The table row of one flight (module docstring); ``distance(q)`` is ``dist`` to the
    training states in the certificate's ``W_x`` norm."""
    sig = signals(log, c, distance)
    dense, mag, dist, w, counts = sig.dense, sig.mag, sig.dist, sig.w, sig.counts
    d_hat = distance(nominal_states(log.x, sig.e_read, c.phi_xy))
    d_ref = distance(np.asarray(log.ref, float))
    allowed = guarantee.premise_bound(c.numbers.eps, c.numbers.S, dist)
    inside = dist <= c.numbers.radius
    t_w = _first(w > c.numbers.eps_w, log.t)
    if math.isnan(t_w) and sig.split.ratio > 1.0 and len(log.t):  # only the bias is beyond eps_b
        t_w = float(log.t[0])
    values = {
        "disturbance": (float(w.max()) if len(w) else 0.0, c.numbers.eps_w, t_w),
        "reference": (float(d_ref.max()), c.numbers.delta, _first(d_ref > c.numbers.delta, log.t)),
        "nominal": (float(d_hat.max()), c.a, _first(d_hat > c.a, log.t)),
        "invariance": (float(dist.max()), min(c.rho_star, c.numbers.radius),
                       _first(dist > min(c.rho_star, c.numbers.radius), log.t)),
        "dense": (float(np.max(dense - allowed)), 0.0, _first(inside & (dense > allowed), log.t)),
        "outliers": (float(counts.max()), float(c.numbers.m), _first((counts > c.numbers.m) | (mag > c.numbers.eps_o), log.t)),
    }  # fmt: skip
    row: dict[str, Any] = {}
    for name in ASSUMPTIONS:
        value, limit, t_fail = values[name]
        row[f"{name}_value"] = value
        row[f"{name}_limit"] = limit
        row[f"{name}_holds"] = math.isnan(t_fail)
        row[f"{name}_t"] = t_fail
    broken = [
        (values[n][2], i, n) for i, n in enumerate(ASSUMPTIONS) if not math.isnan(values[n][2])
    ]
    failed = min(broken)[2] if broken else None
    bound = float(guarantee.premise_bound(c.numbers.eps, c.numbers.S, c.rho_star))
    row |= {
        "bias": float(np.abs(sig.split.beta).max()),
        "eps_b": c.numbers.eps_b,
        "max_outlier": float(mag.max()),
        "eps_o": c.numbers.eps_o,
        "max_dense": float(dense.max()),
        "dense_bound": bound,
        "bound_held": bool(dense.max() <= bound),
        "assumptions_hold": failed is None,
        "first_failed": failed or "",
        "verdict": _verdict(failed, values, float(dense.max()), bound),
    }
    return row


def crashed(row: dict[str, Any], when: Any, reason: Any) -> dict[str, Any]:
    """A row of a flight that crashed: checked on the ticks it flew, and never reported as
    held (a crash is outside every guarantee, whatever held before it)."""
    if not row["assumptions_hold"]:
        return row
    return row | {
        "assumptions_hold": False,
        "first_failed": "crashed",
        "verdict": f"the flight crashed at t={when}s ({reason}); every assumption held before",
    }


def _first(bad: np.ndarray, t: np.ndarray) -> float:
    idx = np.flatnonzero(bad)
    return float(t[idx[0]]) if len(idx) else math.nan


WHAT = {
    "disturbance": "||H^-1 delta|| {v:.3g} > eps_w {lim:.3g} (deviation coordinates)",
    "reference": "dist(x_ref) {v:.3g} > Delta {lim:.3g}",
    "nominal": "dist(x_hat) {v:.3g} > a {lim:.3g}",
    "invariance": "dist(x) {v:.3g} > rho* {lim:.3g}",
    "dense": "dense error above eps + S dist by {v:.3g}",
    "outliers": "{v:.0f} outliers in a window > m {lim:.0f} (or one above eps_o)",
}


def _verdict(failed: str | None, values: dict, max_dense: float, bound: float) -> str:
    if failed is None:
        held = "held" if max_dense <= bound else "FAILED"
        return (
            f"every assumption holds; as a consequence the bound {held}: max |d|_e "
            f"{max_dense:.3g} <= eps + S rho* {bound:.3g}"
        )
    v, lim, t = values[failed]
    return f"assumption '{failed}' fails first at t={t:.2f}s: " + WHAT[failed].format(v=v, lim=lim)
