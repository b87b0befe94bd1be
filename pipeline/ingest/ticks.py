"""A recorded flight's tick log: the controller's own ticks, rebuilt from a vehicle's log
(docs/vehicle.md#the-tick-log-of-a-recorded-flight).

A controller that flew on the vehicle left, per tick, the command it sent (an attitude
setpoint and a normalized thrust, stamped at the tick) and the reference it tracked. Its
tick log (:class:`~qsls.pipeline.core.ticks.TickLog`, the format every simulated flight
keeps) is rebuilt on the log's own clock and frame:

- ``t_k``: the command's stamp (``t_0`` = the first command: 0 s);
- ``y_k``: the estimate the controller read: the newest estimate message that had arrived
  at ``t_k`` (its log stamp ``<= t_k``), so the estimator's transport latency is the log's,
  not a guess;
- ``x_k``: the truth at ``t_k`` by its capture stamp, linear between samples (its velocity
  the truth's own where it has one, else the positions' central differences); a tick the
  truth does not bracket within ``max_gap`` is refused, not interpolated;
- ``r_k``, ``uff_k``: the newest position setpoint at ``t_k`` and its acceleration through
  the paper's ``B`` (:func:`~qsls.pipeline.core.plant.feedforward_input`);
- ``u_k``: the command back to the paper's input
  (:func:`~qsls.pipeline.core.attitude.input_from_attitude`) with the user's mass and the
  hover thrust the log states.

Objects in, objects out: the stage reads the log and writes ``ticks.parquet``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from qsls.pipeline.core.attitude import input_from_attitude
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import feedforward_acceleration, feedforward_input
from qsls.pipeline.core.references import Reference, parse_reference
from qsls.pipeline.core.ticks import TickLog
from qsls.pipeline.core.units import NS

if TYPE_CHECKING:
    from qsls.pipeline.ingest.sources.base import Trajectory
    from qsls.pipeline.ingest.sources.ulog.reader import AttitudeCommands, PositionSetpoints

MIN_TICKS = 20
"""Fewer commands make no flight (two seconds at 10 Hz)."""


@dataclass(frozen=True)
class RecordedTicks:
    """The tick log and what the manifest says of it."""

    log: TickLog
    facts: dict[str, object]


def _latest(stamps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the newest stamp ``<= t`` (``-1`` where there is none)."""
    return np.searchsorted(stamps, t, side="right") - 1


def _sorted(t_ns: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    order = np.argsort(t_ns, kind="stable")
    return (np.asarray(t_ns)[order], *(np.asarray(a)[order] for a in arrays))


def _truth_at(truth: Trajectory, t: np.ndarray, max_gap_ns: int) -> np.ndarray:
    """``x_k`` (k, 6): the truth at ``t`` (ns) by its capture stamps (module docstring)."""
    has_v = truth.velocity is not None and bool(np.isfinite(truth.velocity).all())
    vel = truth.velocity if has_v and truth.velocity is not None else np.zeros_like(truth.position)
    ts, p, v = _sorted(truth.header_ns, truth.position, vel)
    keep = np.concatenate([[True], np.diff(ts) > 0])
    ts, p, v = ts[keep], p[keep], v[keep]
    if not has_v:
        v = np.gradient(p, ts / NS, axis=0)
    j = np.searchsorted(ts, t, side="right")
    outside = (j == 0) | (j == len(ts))
    jj = np.clip(j, 1, len(ts) - 1)
    gap = ts[jj] - ts[jj - 1]
    bad = outside | (gap > max_gap_ns)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"the truth ({truth.name}) does not cover the controller's tick at "
            f"{(t[k] - t[0]) / NS:.3f} s ({int(bad.sum())} ticks; "
            + ("outside its stamps" if outside[k] else f"a gap of {gap[k] / NS:.3g} s")
            + "): a tick log needs the true state at every tick; cut the log to where the "
            "motion capture saw the vehicle, or raise --max-gap"
        )
    a = ((t - ts[jj - 1]) / gap)[:, None]
    xs = np.hstack([p, v])
    return (1 - a) * xs[jj - 1] + a * xs[jj]


def stated_setpoints(
    spec: str, t_ns: np.ndarray, feedforward: str = "sampled", mass: float = 1.0
) -> PositionSetpoints:
    """The reference ``spec`` (:func:`~qsls.pipeline.core.references.parse_reference`) as the
    controller tracked it: sampled at the command stamps ``t_ns``, from the first (0 s). Its
    acceleration is the one the controller's feedforward stood for: the reference's at the
    command (``sampled``), or the model's of a plant (``hover``, ``attitude``: the step mean
    of its inverse over the median tick, for a vehicle of ``mass``)."""
    # deferred: the ULog reader (and pyulog) loads only for a log that holds commands
    from qsls.pipeline.ingest.sources.ulog.reader import PositionSetpoints

    t = (np.asarray(t_ns, dtype=np.int64) - int(t_ns[0])) / NS
    ref = Reference(parse_reference(spec, "--reference"))
    p, v, a = ref.arrays(t)
    if feedforward in ("hover", "attitude") and len(t) > 1:
        dt = float(np.median(np.diff(t)))
        uff = ref.feedforward(t, dt, mass, "attitude" if feedforward == "attitude" else "hover")
        a = feedforward_acceleration(uff, mass)
    return PositionSetpoints(np.asarray(t_ns, dtype=np.int64), p, v, a, np.zeros(len(t)))


def reference_summary(ref: np.ndarray) -> dict[str, float]:
    """What a flight's reference ``r_k`` (k, 6) was, in numbers a certificate can state and a
    later flight be compared with: its horizontal centre and mean radius about it, its mean
    height, and its largest speed."""
    c = ref[:, :2].mean(axis=0)
    radius = np.hypot(ref[:, 0] - c[0], ref[:, 1] - c[1])
    return {
        "center_x": float(c[0]), "center_y": float(c[1]), "radius_m": float(radius.mean()),
        "height_m": float(ref[:, 2].mean()),
        "speed_max_mps": float(np.linalg.norm(ref[:, 3:6], axis=1).max()),
    }  # fmt: skip


def _command_stamps(commands: AttitudeCommands) -> np.ndarray:
    """The commands' stamps (ns), refused in one line when they cannot be the controller's
    ticks: too few, out of order (the log's clock jumped) or with a gap (a logger dropout)."""
    t = np.asarray(commands.t_ns, dtype=np.int64)
    if len(t) < MIN_TICKS:
        raise InputError(
            f"the log holds {len(t)} commands (vehicle_attitude_setpoint); a tick log needs "
            f"{MIN_TICKS}: log the controller's setpoints for the whole flight"
        )
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise InputError(
            f"command {k} is stamped at or before the one before it: the log's clock jumped; "
            "cut the log there"
        )
    step = np.diff(t)
    lost = step > 1.5 * np.median(step)
    if lost.any():
        k = int(np.flatnonzero(lost)[0])
        raise InputError(
            "log the setpoints without dropouts (a faster SD card, a smaller SDLOG_PROFILE) or "
            f"ingest without --mass: the log lost the controller's commands at "
            f"{(t[k] - t[0]) / NS:.3f} s (a gap of {step[k] / NS:.3g} s, {int(lost.sum())} such "
            "gaps; a logger dropout?), so the replay cannot prove who flew it"
        )
    return t


def recorded_ticks(
    vio: Trajectory,
    truth: Trajectory,
    commands: AttitudeCommands,
    setpoints: PositionSetpoints,
    mass: float,
    *,
    hover_thrust: float | None = None,
    max_gap_s: float = 0.25,
) -> RecordedTicks:
    """The tick log of a recorded flight (module docstring); ``hover_thrust`` overrides the
    log's (its estimate, else its parameter)."""
    if vio.velocity is None or not np.isfinite(vio.velocity).all():
        raise InputError(
            f"the estimate ({vio.name}) has no velocity at every message, while the controller "
            "read one: name the estimator's odometry topic (--vio-topic)"
        )
    t = _command_stamps(commands)
    vs, vp, vv = _sorted(vio.log_ns, vio.position, vio.velocity)
    iy = _latest(vs, t)
    ss = np.asarray(setpoints.t_ns, dtype=np.int64)
    ir = _latest(ss, t)
    first = int(np.flatnonzero((iy >= 0) & (ir >= 0))[0]) if ((iy >= 0) & (ir >= 0)).any() else -1
    if first < 0:
        raise InputError(
            "no command was sent after both an estimate and a position setpoint: the log "
            "holds no tick the controller could have computed"
        )
    t, iy, ir = t[first:], iy[first:], ir[first:]
    q, thrust = np.asarray(commands.q)[first:], np.asarray(commands.thrust)[first:]
    hover = (np.full(len(t), float(hover_thrust)) if hover_thrust is not None
             else np.asarray(commands.hover_thrust, dtype=float)[first:])  # fmt: skip
    if not np.isfinite(hover).all() or (hover <= 0).any():
        raise InputError(
            "the log states no hover thrust (no valid hover_thrust_estimate and no "
            "MPC_THR_HOVER): give the vehicle's with --hover-thrust"
        )
    y = np.hstack([vp[iy], vv[iy]])
    ref = np.hstack([setpoints.p[ir], setpoints.v[ir]])
    acc = np.asarray(setpoints.a)[ir]
    if not (np.isfinite(ref).all() and np.isfinite(acc).all()):
        k = int(np.flatnonzero(~np.isfinite(np.hstack([ref, acc])).all(axis=1))[0])
        raise InputError(
            f"the position setpoint at tick {k} holds NaN (PX4 writes NaN for an unset "
            "field): the controller must log the full reference (position, velocity, "
            "acceleration) it tracked"
        )
    x = _truth_at(truth, t, round(max_gap_s * NS))
    u = input_from_attitude(q, thrust, hover, mass)
    uff = feedforward_input(acc, mass)
    step = np.diff(t) / NS
    log = TickLog((t - t[0]) / NS, x, y, u, ref, uff)
    facts: dict[str, object] = {
        "ticks": len(t),
        "dt_s": float(np.median(step)),
        "dt_spread_s": float(step.max() - step.min()),
        "first_tick_ns": int(t[0]),
        "mass_kg": float(mass),
        "hover_thrust": float(np.median(hover)),
        "hover_source": "given" if hover_thrust is not None else commands.hover_source,
        "thr_mdl_fac": commands.thr_mdl_fac,
        "estimate_age_s": float(np.max(t - vs[iy]) / NS),
        "reference": reference_summary(ref),
    }
    return RecordedTicks(log, facts)
