"""The innovation monitor's arithmetic (docs/monitor.md, The innovation monitor): the
innovation ``nu_k = y'_{k+1} - A y'_k - B du_k`` summed over windows, each window's bound under
the premise (sound) or at a conformal quantile of calibration flights' statistics
(calibrated), and the monitor run tick by tick in the exported step's order of operations
(:class:`InnovationMonitor`; the C and Python of :mod:`qsls.pipeline.export.innovation` do
exactly its roundings). Pure: numbers and arrays in, a spec or bits out;
:mod:`qsls.pipeline.control.monitor` reads a controller folder into them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.control.guarantee import (
    MONITOR_RTOL,
    error_bounds,
    measured_channels,
    outlier_channels,
)
from qsls.pipeline.control.monitor_record import (
    CALIBRATED,
    MonitorCalibration,
    MonitorMode,
    conformal_quantile,
)
from qsls.pipeline.core.plant import NX
from qsls.pipeline.core.ticks import FlownLog
from qsls.pipeline.premise.numbers import PremiseNumbers

# --------------------------------------------------------------------------- the innovation
TRIP_INNOVATION_OUTLIERS = 8
"""More than ``m`` outlier ticks in the last ``T - 1``, counted from the innovations."""
TRIP_SUM_CHANNEL = 16
"""A window sum beyond its bound on channel ``c`` sets ``TRIP_SUM_CHANNEL << c`` (16 .. 512)."""
TRIP_SUM_WINDOW = 1024
"""... and ``TRIP_SUM_WINDOW << w`` for the window ``w`` (its index in the spec's windows)."""
MAX_WINDOWS = 4
WINDOW_BREAKS = (1.0, 0.5, 0.2, 0.1)
"""The windows are chosen so that each is the shortest that catches a constant break of
``eps_w (1 + f)`` per tick for these ``f``, whatever the errors within the premise do."""
LIVE_BREAK = 1.0
"""A channel's window is checked only if it catches a break of at most ``(1 + LIVE_BREAK)``
``eps_w``: the position channels, whose window sums hold ``dt`` times the velocity errors, never
do on this plant, and cost nothing when off."""
MAX_WINDOW = 600
"""The longest window (ticks: 60 s at the paper's 10 Hz); a break the errors hide longer is
not looked for."""
DOUBLE_EPS = 2.0**-53
CHANNEL_NAMES = ("px", "py", "pz", "vx", "vy", "vz")


@dataclass(frozen=True)
class InnovationSpec:
    """The innovation monitor's constants (docs/monitor.md, The innovation monitor).

    ``nu_k = y'_{k+1} - A_xx y'_k - A_xa a_k - B_x du_k`` (``y'`` the gated deviation, ``a`` the
    attitude plant's loop states from the controller's own commands ``du``); per channel ``c``
    and window ``K = windows[w]`` the statistic is the median over ``shifts[c]`` consecutive
    end ticks of the window sums of ``nu``, tripping beyond ``threshold[w][c]`` (0: not
    checked); a tick whose innovation exceeds ``outlier_threshold[c]`` on an outlier channel
    places an outlier (more than ``m`` placed in ``count_window`` ticks trip)."""

    a_xx: tuple[tuple[float, ...], ...]
    a_xa: tuple[tuple[float, ...], ...]
    b_x: tuple[tuple[float, ...], ...]
    a_aa: tuple[tuple[float, ...], ...]
    b_a: tuple[tuple[float, ...], ...]
    windows: tuple[int, ...]
    threshold: tuple[tuple[float, ...], ...]
    shifts: tuple[int, ...]
    outlier_threshold: tuple[float, ...]
    m: int
    count_window: int
    breaks: tuple[float, ...] = ()
    """The break (share above ``eps_w``) each window catches at the errors' worst."""
    per_tick: tuple[float, ...] = ()
    """``eps_w sum_j |H_cj|`` (plus the bias term's ``eps_b sum_a |(H D_w)_ca|``): the
    premise's disturbance bound per tick and channel."""
    error_part: tuple[tuple[float, ...], ...] = ()
    """``E_K,c``: the window bound's error terms (the threshold is ``K per_tick + E``)."""
    mode: str = "sound"
    """``sound`` (the premise's bound) or ``calibrated`` (a conformal quantile: docs/monitor.md)."""
    false_trip_rate: float = 0.0
    """Calibrated mode: the stated probability of a false trip per flight (0 when sound)."""
    scale: float = 1.0
    """Calibrated mode: the window thresholds' share of the sound ones (1 when sound)."""

    @property
    def active(self) -> bool:
        return any(v > 0 for row in self.threshold for v in row) or any(
            v > 0 for v in self.outlier_threshold
        )

    @property
    def ring(self) -> int:
        """Innovations kept per checked channel: the longest window plus its shifts."""
        live = [
            self.windows[w] + self.shifts[c] - 1
            for w in range(len(self.windows))
            for c in range(NX)
            if self.threshold[w][c] > 0
        ]
        return max(live, default=0)

    def live_channels(self) -> list[int]:
        return [c for c in range(NX) if any(row[c] > 0 for row in self.threshold)]


NO_INNOVATION = InnovationSpec(
    a_xx=((0.0,) * NX,) * NX, a_xa=((),) * NX, b_x=((0.0,) * 3,) * NX, a_aa=(), b_a=(),
    windows=(), threshold=(), shifts=(1,) * NX, outlier_threshold=(0.0,) * NX, m=0,
    count_window=1,
)  # fmt: skip
"""The innovation monitor of a controller without a guarantee (or without a measured velocity)."""


def max_outliers(length: int, m: int, T: int) -> int:
    """The most outlier ticks among ``length`` consecutive ticks: at most ``m`` in any ``T``."""
    if m <= 0 or length <= 0:
        return 0
    return min(length, m * -(-length // T))


def window_bound(
    K: int, c: int, *, per_tick: np.ndarray, db: np.ndarray, a_minus_i: np.ndarray,
    outlier: np.ndarray, eps_o: float, m: int, T: int, robust: bool,
) -> tuple[float, float]:  # fmt: skip
    """``(K per_tick_c, E_K,c)``: the premise's bound on ``|sum_{k=j}^{j+K-1} nu_k,c|`` is their
    sum (docs/monitor.md, The window bound). With ``nu_k = delta_k + e_{k+1} - A e_k``::

        sum nu = sum delta + e_{j+K} - e_j - (A - I) sum_{k=j}^{j+K-1} e_k

    ``|delta_c| <= per_tick_c``; ``|e_k,i| <= db_i`` plus ``eps_o`` on an outlier tick of an
    outlier channel; at most ``max_outliers`` outlier ticks. ``robust``: the two end errors are
    known to carry no outlier (the median over shifts sees to it)."""
    inner = float(np.abs(a_minus_i[c]) @ db) * K
    n_in = max_outliers(K, m, T)
    inner += eps_o * float(np.abs(a_minus_i[c]) @ outlier) * n_in
    ends = 2.0 * db[c]
    if outlier[c] and not robust:
        ends += eps_o * min(2, max_outliers(K + 1, m, T))
    return K * float(per_tick[c]), ends + inner


def per_tick_bound(
    H: np.ndarray, eps_w: float, eps_b: float = 0.0, bias_dirs: np.ndarray | None = None
) -> np.ndarray:
    """``|delta_k,c| <= eps_w sum_j |H_cj| + eps_b sum_a |(H D_w)_ca|`` per physical channel:
    ``delta = H (D_w beta + w')`` with the bias term's constant ``||beta|| <= eps_b``
    (docs/guarantee.md#the-bias-term) and ``||w'|| <= eps_w``."""
    out = eps_w * np.abs(H[:NX, :NX]).sum(axis=1)
    if eps_b > 0 and bias_dirs is not None:
        out = out + eps_b * np.abs(H[:NX] @ np.asarray(bias_dirs, float)).sum(axis=1)
    return np.asarray(out, dtype=float)


@dataclass(frozen=True)
class PremiseBox:
    """The premise per tick and physical channel, as a monitor of what the controller reads
    and commands sees it (docs/monitor.md, The window bound): ``nu_k = delta_k + e_{k+1} -
    A_xx e_k`` with ``|delta_k,c| <= per_tick_c``, ``|e_k,c| <= db_c`` plus ``eps_o`` on an
    outlier tick of an outlier channel (``outlier_c`` 1), at most ``m`` outlier ticks in any
    ``T`` consecutive ones. Exactly the premise's sets where ``H`` is diagonal, there is no
    bias term and ``S`` is 0 (its norms are ``inf`` norms, and its dense bound does not depend on
    the state); a box around them otherwise."""

    a_xx: np.ndarray
    per_tick: np.ndarray
    db: np.ndarray
    outlier: np.ndarray
    eps_o: float
    m: int
    T: int
    exact: bool
    """The box is the premise's own set (diagonal ``H``, no bias term, ``S`` 0), not a box
    around it."""


def premise_box(
    A: np.ndarray, H: np.ndarray, numbers: PremiseNumbers, *, dense: float,
    error_scale: Sequence[float], measure: str, beta: float, T: int,
    bias_dirs: np.ndarray | None = None) -> PremiseBox | None:  # fmt: skip
    """:class:`PremiseBox` of a certificate's premise ``numbers`` (``eps_w``, ``m``, ``eps_o``,
    ``eps_b``) with the dense bound ``dense``: per-tick disturbance bound
    (:func:`per_tick_bound`), dense bounds ``db`` (:func:`error_bounds`), outlier channels
    (velocities that can hold an outlier: ``m > 0`` and ``db = beta``). None without a
    measured velocity or where the loop states depend on the physical ones."""
    A, H = np.asarray(A, dtype=float), np.asarray(H, dtype=float)
    na = A.shape[0] - NX
    if measure != "full" or (na and np.any(A[NX:, :NX] != 0)) or not math.isfinite(dense):
        return None
    db = error_bounds(dense, error_scale, measured_channels(measure), beta)
    per_tick = per_tick_bound(H, numbers.eps_w, numbers.eps_b, bias_dirs)
    sparse = outlier_channels(measure, numbers.m) if math.isfinite(beta) else ()
    outlier = np.zeros(NX)
    for j in sparse:
        if db[j] >= beta:  # else an outlier there breaks the dense bound: none can occur
            outlier[j] = 1.0
    h = H[:NX, :NX]
    diagonal = bool(np.all(h == np.diag(np.diag(h))))
    return PremiseBox(
        a_xx=A[:NX, :NX].copy(), per_tick=per_tick, db=db, outlier=outlier,
        eps_o=float(numbers.eps_o), m=int(numbers.m) if outlier.any() else 0, T=int(T),
        exact=diagonal and not numbers.eps_b > 0 and numbers.S == 0,
    )  # fmt: skip


def innovation_spec(
    A: np.ndarray, B: np.ndarray, H: np.ndarray, numbers: PremiseNumbers, *, dense: float,
    error_scale: Sequence[float], measure: str, beta: float, T: int,
    bias_dirs: np.ndarray | None = None) -> InnovationSpec:  # fmt: skip
    """The innovation monitor of a certificate's premise ``numbers`` with the dense bound
    ``dense`` (docs/monitor.md): the premise per tick (:func:`premise_box`), the windows of
    :data:`WINDOW_BREAKS` and their thresholds (:func:`window_bound`). Off without a measured
    velocity or where the loop states depend on the physical ones."""
    box = premise_box(
        A, H, numbers, dense=dense, error_scale=error_scale, measure=measure, beta=beta, T=T,
        bias_dirs=bias_dirs,
    )  # fmt: skip
    if box is None:
        return NO_INNOVATION
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    eps_o, measured = box.eps_o, measured_channels(measure)
    db, per_tick, outlier, m_eff = box.db, box.per_tick, box.outlier, box.m
    amI = box.a_xx - np.eye(NX)
    ns = 4 * m_eff + 1
    shifts, robust = [], []
    for c in range(NX):
        ok = bool(outlier[c]) and ns <= T and float(np.abs(amI[c]) @ outlier) == 0.0
        robust.append(ok)
        shifts.append(ns if ok else 1)
    kw: dict[str, Any] = dict(per_tick=per_tick, db=db, a_minus_i=amI, outlier=outlier, eps_o=eps_o, m=m_eff, T=T)  # fmt: skip

    def caught(K: int, c: int) -> float:
        """The smallest break share the window catches on channel c at the errors' worst."""
        dist, err = window_bound(K, c, robust=robust[c], **kw)
        return 2.0 * err / dist if dist > 0 else math.inf

    windows, breaks = _windows(lambda K: min(caught(K, c) for c in range(NX)))
    threshold, error_part = [], []
    L = max((K + max(shifts) - 1 for K in windows), default=0)
    for K in windows:
        row, erow = [], []
        for c in range(NX):
            dist, err = window_bound(K, c, robust=robust[c], **kw)
            erow.append(err)
            if c in measured and caught(K, c) <= LIVE_BREAK:
                row.append(dist + err)
            else:
                row.append(0.0)
        threshold.append(row)
        error_part.append(erow)
    # the per-tick innovation beyond which the tick or the next carries an outlier
    othr = [
        float(per_tick[c] + 2 * db[c] + np.abs(amI[c]) @ db) if outlier[c] and m_eff else 0.0
        for c in range(NX)
    ]
    c_max = max(
        float(per_tick[c] + 2 * (db[c] + eps_o * outlier[c]) + np.abs(amI[c]) @ (db + eps_o * outlier))
        for c in range(NX)
    )  # fmt: skip
    tol = innovation_tolerance(L, c_max, DOUBLE_EPS)
    widen = 1.0 + MONITOR_RTOL
    return InnovationSpec(
        a_xx=_rows(A[:NX, :NX]), a_xa=_rows(A[:NX, NX:]), b_x=_rows(B[:NX]),
        a_aa=_rows(A[NX:, NX:]), b_a=_rows(B[NX:]), windows=tuple(windows),
        threshold=tuple(tuple(float(v * widen + tol) if v > 0 else 0.0 for v in r) for r in threshold),
        shifts=tuple(shifts),
        outlier_threshold=tuple(float(v * widen + tol) if v > 0 else 0.0 for v in othr),
        m=m_eff, count_window=max(T - 1, 1), breaks=tuple(breaks),
        per_tick=tuple(float(v) for v in per_tick),
        error_part=tuple(tuple(float(v) for v in r) for r in error_part),
    )  # fmt: skip


def _windows(caught: Callable[[int], float]) -> tuple[list[int], list[float]]:
    """For each break share ``f`` of :data:`WINDOW_BREAKS`, the shortest window ``K`` (at most
    :data:`MAX_WINDOW`) that ``caught(K)`` (the smallest break share a window of ``K`` catches
    on some channel at the errors' worst) says catches ``f``; each window once, with its ``f``."""
    windows: list[int] = []
    breaks: list[float] = []
    for f in WINDOW_BREAKS:
        for K in range(1, MAX_WINDOW + 1):
            if caught(K) < f:
                if K not in windows:
                    windows.append(K)
                    breaks.append(f)
                break
    return windows, breaks


def innovation_tolerance(L: int, c_max: float, unit: float) -> float:
    """The rounding of a window sum of up to ``L`` innovations, each at most ``c_max`` under
    the premise, accumulated newest first and differenced: ``4 L^2 u c_max`` (``u`` the unit
    roundoff), with room for the innovation's own few roundings."""
    return 4.0 * max(L, 1) ** 2 * unit * c_max


QUANTUM_SCALE = 2.0**30
"""The window sums are exact sums of integers: each innovation is truncated to a multiple of
``2^-30`` (m or m/s) before it is summed (:func:`quantize`), so a running sum (add the newest,
subtract the one leaving) carries no rounding, however long the flight, and the C and the
Python steps hold the same integers."""
QUANTUM_MAX = 2.0**40
"""Innovations are clamped to ``+/- 2^40`` quanta (1024 m/s) before truncation: a window of
``K <= 600`` holds sums below ``2^50``, exact in a double. Under the premise an innovation is
a few m/s, so the clamp never acts on a flight whose premise held."""


def quantize(v: float) -> float:
    """``trunc(v 2^30)`` clamped to ``+/- 2^40``, as a double (an integer): ``|q - v 2^30| < 1``
    (:data:`QUANTUM_SCALE`; NaN maps to the upper clamp)."""
    x = v * QUANTUM_SCALE
    if not (-QUANTUM_MAX <= x <= QUANTUM_MAX):
        x = -QUANTUM_MAX if x < 0 else QUANTUM_MAX
    return float(math.trunc(x))


def sum_limit(threshold: float, K: int) -> float:
    """The bound on a window sum of ``K`` quantized innovations: ``floor(threshold 2^30) + K``.
    Each truncation moves a term by less than one quantum, so a window sum within
    ``threshold`` quantizes to within ``threshold 2^30 + K`` quanta, an integer, hence within
    this bound (docs/monitor.md, Rounding)."""
    return float(math.floor(threshold * QUANTUM_SCALE) + K)


def majority_side(sums: Sequence[float], h: int) -> float | None:
    """The statistic of the shifted window sums held so far (at most ``ns = 2h - 1``): the
    ``h``-th largest where it is positive, else the ``h``-th smallest where that is negative,
    else 0; None while fewer than ``h`` are held. It lies beyond a bound exactly when at least
    ``h`` of the sums lie beyond it on one side, and with all ``ns`` sums held it is their
    median. At most ``h - 1 = 2m`` of any ``ns`` consecutive shifted sums have an outlier at an
    end, so ``h`` beyond the bound prove the premise broken as soon as ``h`` are held, without
    waiting for all ``ns`` (docs/monitor.md, The median over shifts)."""
    if len(sums) < h:
        return None
    srt = sorted(sums)
    hi, lo = srt[len(srt) - h], srt[h - 1]
    return hi if hi > 0 else (lo if lo < 0 else 0.0)


def _rows(a: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in r) for r in np.asarray(a, dtype=float))


# --------------------------------------------------------------------------- calibrated mode
def calibrated_innovation(spec: InnovationSpec, record: MonitorCalibration) -> InnovationSpec:
    """``spec`` (sound) with the window thresholds the record states: ``scale`` times the
    sound ones (``scale = min(q (1 + 1e-9), 1)``, ``q`` the conformal quantile of the
    calibration flights' :func:`flight_statistic`: docs/monitor.md#the-calibrated-mode). A flight
    whose statistic is at most ``q`` never trips them; the outlier count stays sound. In sound
    mode (or ``q`` 0 or inf) the thresholds are the sound ones, the mode and rate stated."""
    if record.mode != CALIBRATED:
        return spec
    f = record.scale
    thr = tuple(tuple(v * f if v > 0 else 0.0 for v in row) for row in spec.threshold)
    return replace(
        spec, threshold=thr, mode=CALIBRATED, false_trip_rate=record.false_trip_rate, scale=f
    )


def monitor_reading(
    log: FlownLog, u_hover: np.ndarray | Sequence[float], gate: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """What the monitor reads of a flight: the gated deviation ``y' - r``
    (:func:`qsls.pipeline.control.gate.gated_deviation`) and the deviation command
    ``du = u - u_hover - uff`` (0 where not logged)."""
    d = gated_deviation(np.asarray(log.y, float) - np.asarray(log.ref, float), gate)
    du = np.asarray(log.u, float) - np.asarray(log.uff, float) - np.asarray(u_hover, float)
    return d, np.nan_to_num(du)


def flight_statistic(
    spec: InnovationSpec, log: FlownLog, u_hover: np.ndarray | Sequence[float], gate: float | None
) -> float:
    """A flight's statistic ``s_f = max_{k, w, c} |med_k,w,c| / threshold_w,c`` under the sound
    ``spec``: the largest median window sum of innovations (:class:`InnovationMonitor`, the
    onboard arithmetic) over the flight's ticks, windows and checked channels, each over its
    sound threshold (docs/monitor.md#the-calibrated-mode). 1 or more: the sound monitor tripped
    (the premise is broken); 0 where no window filled. From the flight's ``y - r`` (velocity
    through the gate) and the deviation command ``u - u_hover - uff`` flown, from the reset at
    take-off; a row that is not finite is refused (it restarts the windows), as onboard."""
    d, du = monitor_reading(log, u_hover, gate)
    mon = InnovationMonitor(spec)
    live = [
        (w, c, thr) for w, row in enumerate(spec.threshold) for c, thr in enumerate(row) if thr > 0
    ]
    worst = 0.0
    for k in range(len(d)):
        ok = bool(np.all(np.isfinite(d[k])))
        mon.step(d[k].tolist() if ok else None)
        mon.command(du[k].tolist())
        for w, c, thr in live:
            worst = max(worst, abs(mon.statistic[w][c]) / thr)
    return worst


def monitor_calibration(
    spec: InnovationSpec, logs: Sequence[FlownLog], u_hover: np.ndarray | Sequence[float],
    gate: float | None, mode: MonitorMode, rate: float,
) -> MonitorCalibration:  # fmt: skip
    """The calibration record of the innovation monitor: each calibration flight's
    :func:`flight_statistic` under the sound ``spec`` and their conformal quantile at ``rate``
    (:func:`qsls.pipeline.control.monitor_record.conformal_quantile`)."""
    stats = [flight_statistic(spec, log, u_hover, gate) for log in logs]
    rank, q = conformal_quantile(stats, rate)
    return MonitorCalibration(
        mode=mode, false_trip_rate=rate, statistics=stats, rank=rank, quantile=q
    )


class InnovationMonitor:
    """The innovation monitor, one tick at a time, in the order of operations of the exported
    step (the generated C and Python do exactly these roundings: docs/monitor.md).

    At each tick :meth:`step` takes the gated deviation ``y'_k`` (None: a refused measurement)
    and returns the tick's bits; then :meth:`command` takes the deviation command ``du_k``
    actually flown at that tick.

    Per checked channel and window ``K`` the window sum is a running sum of the quantized
    innovations (:func:`quantize`: exact integers, no drift); a sum is ``above`` its bound
    (:func:`sum_limit`) or ``below`` its negative; the median of the last ``ns`` sums is beyond
    the bound exactly when more than ``ns // 2`` of them are on the same side, which is what
    the exported code counts (one comparison per tick, not a sort); while fewer than ``ns``
    are held, ``ns // 2 + 1`` of them on one side decide (:func:`majority_side`)."""

    def __init__(self, spec: InnovationSpec) -> None:
        self.spec = spec
        self._live = spec.live_channels()
        self._R = max(spec.windows, default=0) + 1
        self._cap = max(spec.windows, default=0) + max(spec.shifts, default=1)
        self._terms = [
            [(j, v) for j, v in enumerate(spec.a_xx[c]) if v != 0.0]
            + [(NX + j, v) for j, v in enumerate(spec.a_xa[c]) if v != 0.0]
            + [(-1 - j, v) for j, v in enumerate(spec.b_x[c]) if v != 0.0]
            for c in range(NX)
        ]
        self._count_c = [c for c in range(NX) if spec.outlier_threshold[c] > 0]
        self._limit = [
            [sum_limit(t, K) if (t := spec.threshold[w][c]) > 0 else 0.0 for c in range(NX)]
            for w, K in enumerate(spec.windows)
        ]
        self.reset()

    def reset(self) -> None:
        self._yp: list[float] | None = None
        self._a = [0.0] * len(self.spec.a_aa)
        self._du = [0.0, 0.0, 0.0]
        self._head = 0
        self._placed = [0] * self.spec.count_window
        self._phead = 0
        self._pcount = 0
        self._last = -2
        self.tick = 0
        self._restart()
        self.statistic = [[0.0] * NX for _ in self.spec.windows]
        """The last tick's statistic per window and channel (0 before the window is full): the
        median of the last ``ns`` window sums, in m or m/s (a multiple of the quantum)."""

    def _restart(self) -> None:
        """Empty windows (after a reset or a refused tick)."""
        nw = len(self.spec.windows)
        self._q = {c: [0.0] * self._R for c in self._live}
        self._sum = {c: [0.0] * nw for c in self._live}
        self._recent: dict[int, list[list[float]]] = {
            c: [[] for _ in range(nw)] for c in self._live
        }
        self._valid = 0

    def _innovation(self, yg: list[float]) -> list[float]:
        yp, a, du = self._yp, self._a, self._du
        assert yp is not None
        out = []
        for c in range(NX):
            acc = yg[c]
            for j, v in self._terms[c]:
                if j >= NX:
                    acc = acc - v * a[j - NX]
                elif j >= 0:
                    acc = acc - v * yp[j]
                else:
                    acc = acc - v * du[-1 - j]
            out.append(acc)
        return out

    def step(self, yg: Sequence[float] | None) -> int:
        s = self.spec
        bits = 0
        placed = 0
        fresh = False
        if self.tick > 0:
            if self._yp is not None and yg is not None:
                y = [float(v) for v in yg]
                nu = self._innovation(y)
                if self._live and s.windows:
                    fresh = True
                    self._head = self._head - 1 if self._head > 0 else self._R - 1
                    self._valid = min(self._valid + 1, self._cap)
                    for c in self._live:
                        q = quantize(nu[c])
                        self._q[c][self._head] = q
                        for w, K in enumerate(s.windows):
                            acc = self._sum[c][w] + q
                            if self._valid > K:
                                acc = acc - self._q[c][(self._head + K) % self._R]
                            self._sum[c][w] = acc
                hit = any(
                    not (-s.outlier_threshold[c] <= nu[c] <= s.outlier_threshold[c])
                    for c in self._count_c
                )
                if hit and self._last != self.tick - 1:
                    placed = 1  # the innovation k = tick - 1 has an outlier at k or k + 1
                    self._last = self.tick
            else:
                self._restart()
            na = len(self._a)
            if na:
                a, du = self._a, self._du
                new = []
                for i in range(na):
                    acc = 0.0
                    for j in range(na):
                        acc = acc + s.a_aa[i][j] * a[j]
                    for j in range(3):
                        acc = acc + s.b_a[i][j] * du[j]
                    new.append(acc)
                self._a = new
        self._pcount += placed - self._placed[self._phead]
        self._placed[self._phead] = placed
        self._phead = (self._phead + 1) % s.count_window
        if self._pcount > s.m and self._count_c:
            bits |= TRIP_INNOVATION_OUTLIERS
        for c in self._live if fresh else ():
            ns = s.shifts[c]
            for w, K in enumerate(s.windows):
                lim = self._limit[w][c]
                if lim <= 0:
                    continue
                recent = self._recent[c][w]
                if self._valid >= K:
                    recent.append(self._sum[c][w])
                    del recent[:-ns]
                med = majority_side(recent, ns // 2 + 1)
                if med is None:
                    continue
                self.statistic[w][c] = med / QUANTUM_SCALE
                if not (-lim <= med <= lim):
                    bits |= (TRIP_SUM_CHANNEL << c) | (TRIP_SUM_WINDOW << w)
        self._yp = [float(v) for v in yg] if yg is not None else None
        self.tick += 1
        return bits

    def command(self, du: Sequence[float]) -> None:
        """The deviation command ``du_k`` flown at this tick (after :meth:`step`)."""
        self._du = [float(v) for v in du]


def innovation_flags(spec: InnovationSpec, dev: np.ndarray, du: np.ndarray,
                     gate: float | None = None) -> np.ndarray:  # fmt: skip
    """The innovation monitor's bits at every tick of a logged flight from a reset: the raw
    deviations ``dev`` (n, 6), velocity through the gate, and the deviation commands ``du``
    (n, 3) flown (:class:`InnovationMonitor` tick by tick; a row not finite is refused)."""
    d = np.array(dev, dtype=float).reshape(-1, 6)
    if gate is not None:
        d[:, 3:] = np.clip(d[:, 3:], -gate, gate)
    u = np.nan_to_num(np.asarray(du, dtype=float).reshape(-1, 3))
    mon = InnovationMonitor(spec)
    out = np.zeros(len(d), dtype=int)
    for k in range(len(d)):
        ok = bool(np.all(np.isfinite(d[k])))
        bits = mon.step(d[k].tolist() if ok else None)
        out[k] = bits if ok else 0  # a refused tick carries no premise bit (the export's rule)
        mon.command(u[k].tolist())
    return out
