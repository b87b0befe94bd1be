"""The onboard premise monitor of a controller folder (docs/monitor.md): its constants from the
certificate and the taps, and the rule applied to a logged flight.

The thresholds' arithmetic is :func:`qsls.pipeline.control.guarantee.monitor_spec`; the
exported step applies the same rule on the vehicle (:mod:`qsls.pipeline.export.c`,
:mod:`qsls.pipeline.export.python`); :func:`monitor_flags` applies it to deviations logged in
flight, for the checks of ``qsls fly`` and the tests' cross-check of the exported
code.
"""

from __future__ import annotations

import numpy as np

from qsls.pipeline.control.artifacts import ControllerDir
from qsls.pipeline.control.guarantee import COUNT, OFF, TRIP, MonitorSpec, monitor_spec
from qsls.pipeline.control.status import CERTIFIED, RELAXED
from qsls.pipeline.core.plant import NX

NO_MONITOR = MonitorSpec((0.0,) * 6, (OFF,) * 6, 0, 1, (0.0,) * 6, (0.0,) * 6)
"""The monitor of a controller without a guarantee: every channel off."""
TRIP_ENVELOPE, TRIP_OUTLIERS = 1, 2
"""The bits of a tick: a deviation beyond its channel's envelope plus error bound; more than
``m`` outlier ticks in the last ``T``."""


def monitor_of(cdir: ControllerDir) -> MonitorSpec:
    """The monitor of a controller whose certificate states a premise and ``rho*`` (certified
    or relaxed, robust): :func:`qsls.pipeline.control.guarantee.monitor_spec` on its taps, with
    the dense bound ``gamma = eps + S rho*``; otherwise the monitor is off."""
    cert, c = cdir.certificate, cdir.controller
    if (
        cert.status not in (CERTIFIED, RELAXED)
        or not cert.robust
        or cert.rho_star is None
        or not np.isfinite(cert.rho_star)
        or c.kind != "filter_bank"
    ):
        return NO_MONITOR
    p = cert.premise
    taps = c.taps
    # the physical rows and measured columns (the attitude plant's extra states are neither
    # measured nor disturbed: docs/model.md)
    phi_xx_h = np.einsum("tij,jk->tik", taps.Phi_xx, c.model.H)[:, :NX, :]
    return monitor_spec(
        taps.Phi_xy[:, :NX, :NX], phi_xx_h, eps_w=cert.eps_w, dense=cert.gamma,
        error_scale=p.error_scale if p is not None else (1.0,) * 6,
        measure=cert.measure, m=cert.m, eps_o=cert.eps_o,
        beta=p.beta if p is not None and p.beta is not None else np.inf,
        gate=cert.gate, realization_error=cert.realization_error or 0.0,
    )  # fmt: skip


def monitor_flags(spec: MonitorSpec, dev: np.ndarray, gate: float | None = None) -> np.ndarray:
    """The monitor's bits at every tick of the raw deviations ``dev`` (n, 6) from a reset:
    the velocity through the gate ``V``; bit 1 where a :data:`TRIP` channel's ``|dev|``
    exceeds its threshold (or is NaN), bit 2 where more than ``m`` of the last ``T`` ticks (this
    one included) had a :data:`COUNT` channel beyond its threshold."""
    d = np.array(dev, dtype=float).reshape(-1, 6)
    if gate is not None:
        d[:, 3:] = np.clip(d[:, 3:], -gate, gate)
    thr = np.asarray(spec.threshold, dtype=float)
    kind = np.asarray(spec.kind)
    beyond = ~((d <= thr) & (d >= -thr))
    envelope = (beyond & (kind == TRIP)).any(axis=1)
    outlier = (beyond & (kind == COUNT)).any(axis=1).astype(int)
    in_window = np.convolve(outlier, np.ones(spec.window, dtype=int))[: len(outlier)]
    return envelope * TRIP_ENVELOPE | (in_window > spec.m) * TRIP_OUTLIERS


class RuntimeMonitor:
    """:func:`monitor_flags` one tick at a time, as the exported step applies it on the
    vehicle (docs/monitor.md, The rule): from :meth:`reset`, :meth:`step` takes the raw
    deviation ``y_k - r_k`` and returns the tick's bits; the trip count and the first trip's
    tick are never cleared before a reset. Tick for tick the bits equal
    ``monitor_flags(spec, dev, gate)`` on the whole log."""

    def __init__(self, spec: MonitorSpec, gate: float | None = None) -> None:
        self.spec, self.gate = spec, gate
        self._thr = np.asarray(spec.threshold, dtype=float)
        kind = np.asarray(spec.kind)
        self._trip, self._count = kind == TRIP, kind == COUNT
        self.reset()

    def reset(self) -> None:
        self._window = np.zeros(self.spec.window, dtype=int)
        self.tick = 0
        self.trips = 0
        self.first_trip: int | None = None

    def step(self, dev: np.ndarray) -> int:
        d = np.array(dev, dtype=float).reshape(6)
        if self.gate is not None:
            d[3:] = np.clip(d[3:], -self.gate, self.gate)
        beyond = ~((d <= self._thr) & (d >= -self._thr))
        self._window[self.tick % self.spec.window] = int((beyond & self._count).any())
        bits = int((beyond & self._trip).any()) * TRIP_ENVELOPE
        if int(self._window.sum()) > self.spec.m:
            bits |= TRIP_OUTLIERS
        if bits:
            self.trips += 1
            if self.first_trip is None:
                self.first_trip = self.tick
        self.tick += 1
        return bits


def envelope_peak(spec: MonitorSpec, dev: np.ndarray, gate: float | None = None) -> float:
    """How close a logged flight came to an envelope trip: the largest ``|dev_i| /
    threshold_i`` over its ticks and :data:`TRIP` channels (velocity through the gate; above
    1 where bit 1 was set; NaN without such a channel)."""
    d = np.array(dev, dtype=float).reshape(-1, 6)
    if gate is not None:
        d[:, 3:] = np.clip(d[:, 3:], -gate, gate)
    live = np.asarray(spec.kind) == TRIP
    if not live.any() or not len(d):
        return float("nan")
    return float(np.max(np.abs(d[:, live]) / np.asarray(spec.threshold, dtype=float)[live]))
