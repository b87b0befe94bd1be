"""The premise a certificate rests on: its numbers, how each was chosen, and how much of the
training data violates it (docs/guarantee.md, Premise).

The premise is measured (:mod:`qsls.pipeline.premise.measure`) on the
training states the error model was fitted on (``training_states.parquet`` beside
``error_model.yaml``):

- ``eps_e``: the bound on the dense error ``|d_k|_e``; violated by the training samples above it;
- ``S``: tested leave-one-flight-out, violated by the left-out samples with
  ``|d_k|_e > min(eps, eps_{-f}) + S dist_{-f}(x_k)`` within ``r`` of the other flights;
- ``m``: violated by the windows of ``T`` steps with more than ``m`` outliers;
- ``eps_o``: violated by the outliers with ``||o_k||_inf > eps_o``;
- ``eps_w``: violated by the steps with ``||w_k||_inf > eps_w`` (realized disturbance);
- samples the fit excluded count as violations too.

A certificate is ``certified`` only when every share is zero, nothing was excluded and ``S`` was
tested on left-out flights (:attr:`Premise.holds`); otherwise it is ``relaxed``. A premise
that no training sample satisfies is refused.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.disturbance import RESIDUAL as RESIDUAL  # eps_w_source's lower bound
from qsls.pipeline.errormodel.model import ErrorModel
from qsls.pipeline.premise import honest
from qsls.pipeline.premise.measure import ONES, Measured, Spec
from qsls.pipeline.premise.numbers import PremiseNumbers


class PremiseEntry(BaseModel):
    """One number of the premise: its value, how it was chosen and the share of the training
    data violating it (``None``: not known)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    value: float
    chosen: str
    """``number`` (given), ``max``, ``lofo`` (leave-one-flight-out), ``pXX`` / ``local_pXX``,
    ``binomial`` (m), ``gate`` / ``given`` (eps_o), ``error model`` or ``default``."""
    violated: float | None = None
    n_violating: int | None = None
    n_total: int | None = None
    """Samples, left-out samples, windows, outliers or steps checked."""


class Premise(BaseModel):
    """``certificate.yaml``'s ``premise``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    eps_e: PremiseEntry
    """The bound on the dense error ``|d|_e`` (``||e||`` in the special case)."""
    S: PremiseEntry
    r: PremiseEntry
    Delta: PremiseEntry
    eps_w: PremiseEntry
    m: PremiseEntry | None = None
    eps_o: PremiseEntry | None = None
    measure: str = "full"
    beta: float | None = None
    state_scale: list[float] = list(ONES)
    error_scale: list[float] = list(ONES)
    gate: float | None = None
    """Velocity gate ``V``: the controller reads ``clip(y_v, v_ref +/- V)``; ``eps_o = 2 V - beta``."""
    eps_w_source: str | None = None
    """``inputs`` or ``input_free_residual`` (a lower bound: inputs were not logged)."""
    tested_range: float | None = None
    """Largest distance at which ``S`` was tested (left-out samples within ``r``)."""
    outliers: dict[str, Any] | None = None
    """The sparse part on the training data: outliers, rate, its one-sided 95 % upper bound, the
    largest count in a window, and the risk that a flight of N steps holds a window of more
    than ``m`` outliers at that bound (union bound), for a few flight lengths."""
    n_excluded: int = 0
    """Training samples the fit left out (each one counts against the premise)."""
    training_data: str | None = None
    """Where the shares were computed, why they could not be, or None without an error model."""
    groups: dict[str, dict[str, float]] | None = None
    """Per channel group (``position``, ``velocity``) on the training data: ``eps`` (its largest
    dense error ``|d_g|_e`` in the user's ``W_e``) and ``S`` (its leave-one-flight-out slope, NaN
    when nothing was left out); the premise's training ``eps_e`` and ``S = lofo`` are their
    maxima. With a vector of bounds (``eps_groups``) each group's ``bound`` ``eps_g``: the
    premise's ``eps_e``, ``S`` and ``error_scale`` are then those of
    :func:`qsls.pipeline.premise.numbers.grouped_premise`."""

    def entries(self) -> dict[str, PremiseEntry]:
        out = {"eps_e": self.eps_e, "S": self.S, "eps_w": self.eps_w}
        if self.m is not None:
            out["m"] = self.m
        if self.eps_o is not None:
            out["eps_o"] = self.eps_o
        return out

    @property
    def holds(self) -> bool:
        """Every training sample, window and left-out sample satisfies every premise quantity,
        nothing excluded. Without an error model the numbers are the user's assumption, and no
        training data contradicts them."""
        if self.training_data is None:
            return True
        return self.n_excluded == 0 and all(e.violated == 0.0 for e in self.entries().values())

    def shares(self) -> str:
        """``premise violated: eps_e by 5% of samples, S by 2% of left-out samples`` (one line)."""
        what = {
            "eps_e": "samples", "S": "left-out samples", "eps_w": "steps", "m": "windows",
            "eps_o": "outliers",
        }  # fmt: skip
        parts = [
            f"{k} by {_pct(e.violated)} of {what[k]} ({e.chosen})"
            for k, e in self.entries().items()
            if e.violated != 0.0
        ]
        if self.n_excluded:
            parts.append(f"{self.n_excluded} training samples excluded by the fit")
        return "premise violated: " + ("; ".join(parts) if parts else "nowhere")


def _pct(v: float | None) -> str:
    return "an unknown share" if v is None else f"{100 * v:.3g}%"


def _count(bad: np.ndarray, total: np.ndarray | None = None) -> tuple[int, int]:
    n = int(len(bad) if total is None else int(total.sum()))
    return int(np.count_nonzero(bad)), n


def _entry(value: float, chosen: str, counted: tuple[int, int] | None) -> PremiseEntry:
    if counted is None:
        return PremiseEntry(value=value, chosen=chosen)
    bad, n = counted
    return PremiseEntry(
        value=value, chosen=chosen, violated=bad / n if n else 0.0, n_violating=bad, n_total=n
    )


def premise_record(chosen: PremiseNumbers, how: dict[str, str], spec: Spec,
                   meas: Measured | None, em: ErrorModel | None, where: str | None,
                   groups: dict[str, dict[str, float]] | None = None) -> Premise:  # fmt: skip
    """The certificate's :class:`Premise`: the numbers synthesis uses (``chosen``) in the norms
    of ``spec``, how each was chosen (``how``: ``eps_e``, ``S``, ``eps_w``, ``m``, ``eps_o``,
    ``r``, ``Delta``) and the share of the training data violating each (counted on ``meas``,
    measured under ``spec``); ``groups``: the channel groups' record (default: that of ``meas``,
    :func:`group_record`)."""
    h = how
    if meas is None:
        # without the training states a share is known only where the number is at least
        # the error model's maximum over them (then nothing violates it)
        eps = _bounded(chosen.eps, h["eps_e"], em.eps_e if em is not None else None)
        S = _bounded(chosen.S, h["S"], em.s_slope.max if em is not None else None)
        top_w = em.disturbance.max if em is not None and em.disturbance is not None else None
        eps_w = _bounded(chosen.eps_w, h["eps_w"], top_w)
        m = eps_o = None
        tested = None
    else:
        eps = _entry(chosen.eps, h["eps_e"], _count(meas.dense > chosen.eps))
        within = meas.dist_other <= chosen.radius
        if math.isnan(meas.slope.S):
            S = _entry(chosen.S, h["S"], None)  # one flight: nothing to leave out
        else:
            others = {int(f): _others_max(meas, int(f)) for f in np.unique(meas.flight)}
            cap = np.minimum(chosen.eps, np.array([others[int(f)] for f in meas.flight]))
            bad = within & (meas.dense > cap + chosen.S * meas.dist_other)
            S = _entry(chosen.S, h["S"], (int(bad.sum()), int(within.sum())))
        if meas.w_norm is not None:
            w = meas.w_norm[np.isfinite(meas.w_norm)]
            eps_w = _entry(chosen.eps_w, h["eps_w"], _count(w > chosen.eps_w))
        else:
            top_w = em.disturbance.max if em is not None and em.disturbance is not None else None
            eps_w = _bounded(chosen.eps_w, h["eps_w"], top_w)
        has_out = bool(honest.outlier_channels(spec.measure, spec.beta))
        if has_out:
            counts = honest.window_counts(meas.outlier > 0, meas.flight, spec.window)
            m = _entry(chosen.m, h["m"], _count(counts > chosen.m))
            out = meas.outlier[meas.outlier > 0]
            if (
                chosen.gate is not None
            ):  # eps_o = 2V - beta: a guarantee of the gate, not a measurement
                eps_o = _entry(chosen.eps_o, h["eps_o"], (0, len(out)))
            else:
                eps_o = _entry(chosen.eps_o, h["eps_o"], _count(out > chosen.eps_o))
        else:
            m = eps_o = None
        tested = meas.slope.tested_range
    return Premise(
        eps_e=eps, S=S,
        r=PremiseEntry(value=chosen.radius, chosen=h["r"]),
        Delta=PremiseEntry(value=chosen.delta, chosen=h["Delta"]),
        eps_w=eps_w, m=m, eps_o=eps_o,
        measure=spec.measure,
        beta=spec.beta if math.isfinite(spec.beta) else None,
        state_scale=list(spec.state_scale), error_scale=list(spec.error_scale),
        gate=chosen.gate,
        outliers=_outlier_record(meas, chosen.m) if m is not None else None,
        eps_w_source=em.disturbance.source if em is not None and em.disturbance else None,
        tested_range=tested,
        n_excluded=em.n_excluded if em is not None else 0,
        training_data=where,
        groups=groups if groups is not None else group_record(meas),
    )  # fmt: skip


def group_record(
    meas: Measured | None, bounds: dict[str, float] | None = None
) -> dict[str, dict[str, float]] | None:
    """Per channel group: the training maximum ``eps`` of ``|d_g|_e`` and the leave-one-flight-out
    ``S`` (in the user's ``W_e``), and with a vector of bounds the group's ``bound`` ``eps_g``."""
    if meas is None or not meas.groups:
        if not bounds:
            return None
        return {g: {"bound": b} for g, b in bounds.items()}
    out = {}
    for g, v in meas.groups.items():
        fit = meas.group_slopes[g]
        out[g] = {"eps": float(v.max()), "S": float(fit.S)}
        if bounds and g in bounds:
            out[g]["bound"] = bounds[g]
    return out


FLIGHT_STEPS = (100, 300, 1000, 3000)
"""Flight lengths (steps) at which a certificate states the outlier count's risk."""


def _outlier_record(meas: Measured | None, m: int) -> dict[str, Any] | None:
    if meas is None:
        return None
    o, T = meas.outliers, meas.spec.window
    return {
        "n_outliers": o.n_outliers, "n_samples": o.n_samples, "rate": o.rate,
        "rate_upper_95": o.rate_upper, "max_in_window": o.max_in_window, "window": T,
        "risk_per_window": honest.window_exceed_prob(m, T, o.rate_upper),
        "risk_per_flight": {str(n): honest.flight_risk(m, T, o.rate_upper, n) for n in FLIGHT_STEPS},
    }  # fmt: skip


def _bounded(value: float, chosen: str, top: float | None) -> PremiseEntry:
    if top is not None and value >= top:
        return PremiseEntry(value=value, chosen=chosen, violated=0.0)
    return PremiseEntry(value=value, chosen=chosen)


def _others_max(meas: Measured, f: int) -> float:
    other = meas.flight != f
    return float(meas.dense[other].max()) if other.any() else math.inf


def refuse_empty(p: Premise) -> None:
    """A premise that no training sample satisfies is no premise: refused."""
    e = p.eps_e
    if e.violated is not None and e.n_total and e.violated >= 1.0:
        raise InputError(
            f"eps_e = {e.value:g} is exceeded by every one of the {e.n_total} training samples: "
            "a premise no sample satisfies certifies nothing; use eps_e max (the training "
            "maximum) or a larger number"
        )


PREMISE_COLUMNS = ("premise_holds", "eps_e_violated", "S_violated", "tested_range", "m", "eps_o")
"""The premise's columns of a sweep table (one row per grid point)."""


def premise_columns(p: Premise, chosen: PremiseNumbers) -> dict[str, Any]:
    nan = math.nan
    return {
        "premise_holds": p.holds,
        "eps_e_violated": nan if p.eps_e.violated is None else p.eps_e.violated,
        "S_violated": nan if p.S.violated is None else p.S.violated,
        "tested_range": nan if p.tested_range is None else p.tested_range,
        "m": chosen.m,
        "eps_o": chosen.eps_o,
    }
