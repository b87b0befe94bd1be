"""The onboard premise monitor of a controller folder (docs/monitor.md): its constants from the
certificate and the taps, and the rule applied to a logged flight; the innovation monitor's
own arithmetic is :mod:`qsls.pipeline.control.innovation`.

The thresholds' arithmetic is :func:`monitor_spec` (the envelope of the guarantee's split); the
exported step applies the same rule on the vehicle (:mod:`qsls.pipeline.export.c`,
:mod:`qsls.pipeline.export.python`); :func:`monitor_flags` applies it to deviations logged in
flight, for the checks of ``qsls fly`` and the tests' cross-check of the exported
code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import ControllerDir
from qsls.pipeline.control.guarantee import (
    MONITOR_RTOL,
    ONES,
    VELOCITY,
    bias_rows,
    error_bounds,
    error_weights,
    measured_channels,
    outlier_channels,
)
from qsls.pipeline.control.innovation import (
    CHANNEL_NAMES,
    MAX_WINDOWS,
    NO_INNOVATION,
    TRIP_INNOVATION_OUTLIERS,
    TRIP_SUM_CHANNEL,
    TRIP_SUM_WINDOW,
    InnovationMonitor,
    InnovationSpec,
    PremiseBox,
    calibrated_innovation,
    innovation_flags,
    innovation_spec,
    premise_box,
)
from qsls.pipeline.control.status import CERTIFIED, RELAXED
from qsls.pipeline.core.plant import GRAVITY, NX
from qsls.pipeline.premise.numbers import PremiseNumbers


# --------------------------------------------------------------------------- the envelope
def deviation_envelope(
    phi_xy: np.ndarray,
    phi_xx_h: np.ndarray,
    *,
    eps_w: float,
    dense: float,
    error_scale: Sequence[float] = ONES,
    measured: Sequence[int] = tuple(range(6)),
    outlier_channels: Sequence[int] = (),
    m: int = 0,
    eps_o: float = 0.0,
    beta: float = math.inf,
    eps_b: float = 0.0,
    bias_dirs: np.ndarray | None = None,
) -> np.ndarray:
    """``env`` (one entry per state channel, unweighted): under the premise
    ``|x_k,i - r_k,i| <= env_i`` at every tick (docs/monitor.md, The envelope).

    In deviation from the reference ``x - r = Phi_xx H * w + Phi_xy * (d + o)`` (the flight
    starts on the reference), ``w = D_w beta + w'`` with ``||beta|| <= eps_b`` (adding
    ``eps_b g_b,i``, :func:`bias_rows`) and ``||w'|| <= eps_w``, ``|d_j|_e <= dense = eps + S rho*`` (so
    ``|d_j| <= dense / w_e,j``, and ``<= beta`` on an outlier channel, where ``d = clip_beta(e)``)
    and at most ``m`` of the last ``T`` ticks carry an outlier ``||o|| <= eps_o``::

        env_i = eps_w sum_t sum_j |(Phi_xx H)(t)_ij|
              + sum_t sum_j |Phi_xy(t)_ij| db_j                 db_j = dense / w_e,j (min beta)
              + eps_o (sum of the m largest over t of sum_{j in O} |Phi_xy(t)_ij|)

    ``max_i w_x,i env_i <= eps_w N_w + eps_b G_b + N dense + eps_o G_m = rho* - Delta``."""
    db = error_bounds(dense, error_scale, measured, beta)
    env = eps_w * np.abs(phi_xx_h).sum(axis=(0, 2)) + (np.abs(phi_xy) * db[None, None, :]).sum(
        axis=(0, 2)
    )
    if eps_b > 0:
        env = env + eps_b * bias_rows(phi_xx_h, bias_dirs)
    if m > 0 and len(outlier_channels):
        per_tap = np.abs(phi_xy[:, :, list(outlier_channels)]).sum(axis=2)  # (taps, nx)
        env = env + eps_o * (-np.sort(-per_tap, axis=0))[:m].sum(axis=0)
    return np.asarray(env, dtype=float)


OFF, TRIP, COUNT = 0, 1, 2
"""A monitored channel's kind: not checked; beyond its threshold the premise is broken; beyond
its threshold the tick carries an outlier (more than ``m`` in ``T`` ticks break the premise)."""


@dataclass(frozen=True)
class MonitorSpec:
    """The onboard premise monitor's constants (docs/monitor.md): a measured deviation
    ``|y_k,i - r_k,i|`` (velocity through the gate) beyond ``threshold_i = env_i + db_i``."""

    threshold: tuple[float, ...]
    kind: tuple[int, ...]
    m: int
    window: int
    envelope: tuple[float, ...]
    error_bound: tuple[float, ...]

    @property
    def active(self) -> bool:
        return any(k != OFF for k in self.kind)


def monitor_spec(
    phi_xy: np.ndarray,
    phi_xx_h: np.ndarray,
    numbers: PremiseNumbers,
    *,
    dense: float,
    error_scale: Sequence[float] = ONES,
    measure: str = "full",
    beta: float = math.inf,
    realization_error: float = 0.0,
    bias_dirs: np.ndarray | None = None,
) -> MonitorSpec:
    """The thresholds ``env_i + db_i`` of :func:`deviation_envelope` plus the bound ``db_i`` on
    the error of the tick itself, per measured channel, under the premise ``numbers``
    (``eps_w``, ``m``, ``eps_o``, the gate ``V``, ``eps_b``) with the dense bound ``dense``
    (``gamma = eps + S rho*``); velocity channels with ``beta`` and
    ``m > 0`` count outliers (``kind`` :data:`COUNT`), the others trip (:data:`TRIP`). A channel
    whose threshold is at least the gate can never be exceeded through the gate: it is
    :data:`OFF`. A velocity channel counts only where an outlier can meet the dense bound
    (``beta <= dense / w_e,j``); where ``dense / w_e,j < beta``, an error beyond ``dense / w_e,j``
    breaks the dense premise whether or not it is an outlier (its clipped part is then
    ``beta``), so the channel trips. Thresholds are widened by :data:`MONITOR_RTOL`."""
    m, gate = numbers.m, numbers.gate
    measured = measured_channels(measure)
    sparse = outlier_channels(measure, m) if math.isfinite(beta) else ()
    env = deviation_envelope(
        phi_xy, phi_xx_h, eps_w=numbers.eps_w, dense=dense, error_scale=error_scale,
        measured=measured, outlier_channels=sparse, m=m, eps_o=numbers.eps_o, beta=beta,
        eps_b=numbers.eps_b, bias_dirs=bias_dirs,
    )  # fmt: skip
    db = error_bounds(dense, error_scale, measured, beta)
    T = phi_xy.shape[0] - 1
    widen = 1.0 + MONITOR_RTOL + 10.0 * (T + 1) * max(realization_error, 0.0)
    thr = (env + db) * widen
    kind = []
    for i in range(len(thr)):
        if i not in measured or not math.isfinite(thr[i]):
            kind.append(OFF)
        elif i in VELOCITY and gate is not None and thr[i] >= gate:
            kind.append(OFF)  # the gated deviation never exceeds V
        elif i in sparse and dense * error_weights(error_scale, measured)[i] >= beta:
            kind.append(COUNT)  # beyond: |e_i| > beta, an outlier the premise allows m of
        else:
            kind.append(TRIP)  # beyond: the dense bound is broken (with o != 0, |d_i| = beta too)
    return MonitorSpec(
        threshold=tuple(float(v) if k != OFF else 0.0 for v, k in zip(thr, kind, strict=True)),
        kind=tuple(kind),
        m=int(m) if sparse else 0,
        window=T,
        envelope=tuple(float(v) for v in env),
        error_bound=tuple(float(v) for v in db),
    )


NO_MONITOR = MonitorSpec((0.0,) * 6, (OFF,) * 6, 0, 1, (0.0,) * 6, (0.0,) * 6)
"""The monitor of a controller without a guarantee: every channel off."""
TRIP_ENVELOPE, TRIP_OUTLIERS = 1, 2
"""The bits of a tick: a deviation beyond its channel's envelope plus error bound; more than
``m`` outlier ticks in the last ``T``."""


def monitor_of(cdir: ControllerDir) -> MonitorSpec:
    """The monitor of a controller whose certificate states a premise and ``rho*`` (certified
    or relaxed, robust): :func:`monitor_spec` on its taps, with
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
        taps.Phi_xy[:, :NX, :NX], phi_xx_h, cert.numbers(), dense=cert.gamma,
        error_scale=p.error_scale if p is not None else (1.0,) * 6,
        measure=cert.measure,
        beta=p.beta if p is not None and p.beta is not None else np.inf,
        realization_error=cert.realization_error or 0.0, bias_dirs=c.model.bias_dirs,
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

    def __init__(
        self, spec: MonitorSpec, gate: float | None = None, innovation: InnovationSpec | None = None
    ) -> None:
        self.spec, self.gate = spec, gate
        self.innovation = InnovationMonitor(innovation) if innovation is not None else None
        self._thr = np.asarray(spec.threshold, dtype=float)
        kind = np.asarray(spec.kind)
        self._trip, self._count = kind == TRIP, kind == COUNT
        self.reset()

    def reset(self) -> None:
        self._window = np.zeros(self.spec.window, dtype=int)
        if self.innovation is not None:
            self.innovation.reset()
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
        if self.innovation is not None:
            bits |= self.innovation.step(d.tolist() if np.all(np.isfinite(d)) else None)
        if int(self._window.sum()) > self.spec.m:
            bits |= TRIP_OUTLIERS
        if bits:
            self.trips += 1
            if self.first_trip is None:
                self.first_trip = self.tick
        self.tick += 1
        return bits

    def command(self, du: np.ndarray) -> None:
        """The deviation command flown at this tick (the innovation's ``du_k``)."""
        if self.innovation is not None:
            self.innovation.command(np.asarray(du, dtype=float).reshape(3).tolist())


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


def innovation_of(cdir: ControllerDir) -> InnovationSpec:
    """The innovation monitor of a controller folder (its certificate's numbers, its model's
    ``A``, ``B``, ``H``); off where :func:`monitor_of` is off. Calibrated where the
    certificate's calibration record says so (:func:`calibrated_innovation`)."""
    spec = sound_innovation_of(cdir)
    cal = cdir.certificate.calibration
    if cal is not None and cal.monitor is not None and spec.active:
        return calibrated_innovation(spec, cal.monitor)
    return spec


def sound_innovation_of(cdir: ControllerDir) -> InnovationSpec:
    """:func:`innovation_of` in sound mode, whatever the record says: the premise's bounds
    (the scale of a calibration's statistics)."""
    if monitor_of(cdir) is NO_MONITOR:
        return NO_INNOVATION
    model = cdir.controller.model
    return innovation_spec(model.A, model.B, model.H, **_premise_of(cdir))


def premise_box_of(cdir: ControllerDir) -> PremiseBox | None:
    """The premise per tick of a controller folder's certificate, as its innovation monitor
    reads it (:func:`qsls.pipeline.control.innovation.premise_box`); None where the monitor is
    off."""
    if monitor_of(cdir) is NO_MONITOR:
        return None
    model = cdir.controller.model
    return premise_box(model.A, model.H, **_premise_of(cdir))


def _premise_of(cdir: ControllerDir) -> dict[str, Any]:
    """The certificate's premise as :func:`premise_box` and :func:`innovation_spec` take it."""
    cert, p = cdir.certificate, cdir.certificate.premise
    return dict(
        numbers=cert.numbers(), dense=cert.gamma,
        error_scale=p.error_scale if p is not None else (1.0,) * 6, measure=cert.measure,
        beta=p.beta if p is not None and p.beta is not None else np.inf, T=cdir.controller.T,
        bias_dirs=cdir.controller.model.bias_dirs,
    )  # fmt: skip


def hover_input(cdir: ControllerDir) -> np.ndarray:
    """``u_hover = [0, 0, m g]`` of the controller's model (the deviation command's origin)."""
    return np.array([0.0, 0.0, cdir.controller.model.mass * GRAVITY])


def describe_bits(bits: int, spec: InnovationSpec | None = None) -> list[str]:
    """What a tick's bits say, one phrase per test (docs/monitor.md, The bits)."""
    out = [text for bit, _, text in _tests() if bits & bit]
    if spec is not None:
        ws = [spec.windows[w] for w in range(len(spec.windows)) if bits & (TRIP_SUM_WINDOW << w)]
        if ws:
            out.append("window " + ", ".join(f"{K} ticks" for K in ws))
    return out


def _tests() -> list[tuple[int, str, str]]:
    """Each test's bit, its short name (a table cell) and its phrase (docs/monitor.md, The bits)."""
    tests = [
        (TRIP_ENVELOPE, "envelope", "deviation beyond its envelope"),
        (TRIP_OUTLIERS, "outlier count", "more than m outliers in T ticks (envelope count)"),
        (TRIP_INNOVATION_OUTLIERS, "innovation outlier count",
         "more than m outliers in T ticks (innovation count)"),
    ]  # fmt: skip
    tests += [(TRIP_SUM_CHANNEL << c, f"disturbance on {CHANNEL_NAMES[c]}",
               f"disturbance above eps_w on {CHANNEL_NAMES[c]}") for c in range(NX)]  # fmt: skip
    return tests


PREMISE_BITS = (
    TRIP_ENVELOPE | TRIP_OUTLIERS | TRIP_INNOVATION_OUTLIERS
    | ((1 << NX) - 1) * TRIP_SUM_CHANNEL | ((1 << MAX_WINDOWS) - 1) * TRIP_SUM_WINDOW
)  # fmt: skip
"""Every bit that proves the premise broken (``INPUT_REFUSED``, 4, is the step's refusal)."""


def first_test(bits: int) -> str:
    """The short name of the test a tick's bits name first, in the order of :data:`_tests`
    (``envelope``, ``outlier count``, ``innovation outlier count``, ``disturbance on vz``);
    empty when no premise bit is set."""
    return next((name for bit, name, _ in _tests() if bits & bit), "")


def trip_summary(bits: np.ndarray, dt: float, t: np.ndarray | None = None) -> list[str]:
    """A flight's trips by test and channel with how long each held, first trip first:
    ``disturbance above eps_w on vz for 2.3 s (from 1.7 s)`` (``len(hit) dt`` seconds; the
    start at ``t`` of the first tripped tick, ``k dt`` without ``t``)."""
    b = np.asarray(bits, dtype=int)
    found = []
    for bit, _, text in _tests():
        hit = np.flatnonzero(b & bit)
        if len(hit):
            start = float(t[hit[0]]) if t is not None else hit[0] * dt
            found.append((int(hit[0]), f"{text} for {len(hit) * dt:.1f} s (from {start:.1f} s)"))
    return [s for _, s in sorted(found)]


def onboard_flags(
    spec: MonitorSpec, innovation: InnovationSpec, dev: np.ndarray, du: np.ndarray,
    gate: float | None = None,
) -> np.ndarray:  # fmt: skip
    """The onboard monitor's bits (the exported step's and :class:`RuntimeMonitor`'s) at every
    tick of a logged flight from a reset: :func:`monitor_flags` (the envelope and its outlier
    count) or-ed with :func:`innovation_flags` (the window sums and the innovation outlier
    count) on the raw deviations ``dev`` (n, 6) and the deviation commands ``du`` (n, 3)
    flown, ``du_k = u_k - u_hover - uff_k``."""
    flags = monitor_flags(spec, dev, gate)
    if innovation.active:
        flags = flags | innovation_flags(innovation, dev, du, gate)
    return flags
