"""Read a PX4 ULog through pyulog: pose streams, the controller's commands and setpoints.

docs/ingest.md#px4-ulog. Public:

- :func:`ulog_topics`, :func:`ulog_info`: what a log holds (a whole pass over it);
- :func:`read_odometry`: a ``vehicle_odometry``- or ``vehicle_local_position``-format topic
  as a :class:`~qsls.pipeline.ingest.sources.base.Trajectory` (position ENU, orientation the
  FLU body in ENU ``[x, y, z, w]``, velocity in the world frame, ENU);
- :func:`read_commands`: ``vehicle_attitude_setpoint`` (attitude, thrust) with the hover
  thrust in force at each command (:class:`AttitudeCommands`);
- :func:`read_setpoints`: ``trajectory_setpoint`` (:class:`PositionSetpoints`).

Stamps: every ``*_ns`` is the log's microsecond clock (time since boot) times 1000. Frames:
PX4's world is NED (or FRD: a z-down world whose x is not north, converted like NED) and
its body FRD; they go to ENU and FLU by :func:`qsls.pipeline.core.rotations.ned_to_enu`,
:func:`~qsls.pipeline.core.rotations.frd_to_flu` and
:func:`~qsls.pipeline.core.rotations.frd_ned_to_flu_enu`.

pyulog parses only the topics asked for, from the stream :func:`.scan.walk` makes of the
file (its framing walked once, the other topics' data left out); a log that ends inside a
message (cut off) or that pyulog finds damaged is refused in one line (:mod:`.scan`).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.rotations import (
    body_to_world,
    frd_ned_to_flu_enu,
    frd_to_flu,
    ned_to_enu,
    yaw_ned_to_enu,
    yaw_quat,
)
from qsls.pipeline.ingest.sources.base import Trajectory
from qsls.pipeline.ingest.sources.ulog import px4, scan
from qsls.pipeline.ingest.sources.ulog.scan import load

MAX_CLOCK_STEP_BACK_US = 250_000
"""A topic whose ``timestamp`` goes back further than this (0.25 s) had its clock reset."""

_BLOCK = 1 << 16
"""Rows rotated at once (no ``(n, 3, 3)`` matrices for a whole topic)."""

POSE_HINT = (
    "PX4 logs vehicle_visual_odometry and vehicle_mocap_odometry only with SDLOG_PROFILE "
    "bit 7 (computer vision) set or a logger topics file (etc/logging/logger_topics.txt on "
    "the SD card); log them, or name another topic with --vio-topic / --truth-topic"
)


# --------------------------------------------------------------------------- the results
@dataclass(frozen=True)
class AttitudeCommands:
    """The attitude controller's input as logged (``vehicle_attitude_setpoint``).

    ``t_ns`` (n,) int64: the message's ``timestamp`` * 1000. ``q`` (n, 4) ``[x, y, z, w]``:
    the commanded FLU body in ENU (``q_d``, FRD in NED, converted). ``thrust`` (n,): the
    normalized thrust's magnitude, ``|thrust_body|`` (older PX4: ``|thrust|``), 0..1.
    ``hover_thrust`` (n,): the hover throttle in force at each command: the latest
    ``hover_thrust_estimate`` with ``valid`` set and ``timestamp <= t``, else the parameter
    ``MPC_THR_HOVER`` in force then, NaN where neither. ``hover_source``:
    ``hover_thrust_estimate``, ``MPC_THR_HOVER``, ``mixed`` (both served) or ``none``.
    ``thr_mdl_fac``: the parameter ``THR_MDL_FAC`` (thrust curve), None when not logged."""

    t_ns: np.ndarray
    q: np.ndarray
    thrust: np.ndarray
    hover_thrust: np.ndarray
    hover_source: str
    thr_mdl_fac: float | None


@dataclass(frozen=True)
class PositionSetpoints:
    """The position controller's input as logged (``trajectory_setpoint``), ENU: ``t_ns``
    (n,) int64 (``timestamp`` * 1000), ``p``, ``v``, ``a`` (n, 3) (NaN where PX4 left an axis
    free, as logged; ``a`` NaN throughout when the generation logs none), ``yaw`` (n,) rad
    about z up from east (``pi/2 - yaw_ned``)."""

    t_ns: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    yaw: np.ndarray


# --------------------------------------------------------------------------- loading
def _dataset(u: Any, name: str, instance: int) -> Any | None:
    return next((d for d in u.data_list if d.name == name and d.multi_id == instance), None)


def _flat_fields(u: Any, name: str) -> list[str]:
    """The field names of format ``name`` as pyulog flattens them (``q[0]``..), top level."""
    out: list[str] = []
    for _type, size, field in u.message_formats[name].fields:
        out.extend([f"{field}[{i}]" for i in range(size)] if size > 0 else [field])
    return out


def _columns(d: dict[str, np.ndarray], names: Iterable[str]) -> np.ndarray:
    """Fields ``names`` as the columns of one float64 array ``(n, k)``."""
    cols = [d[n] for n in names]
    out = np.empty((len(cols[0]), len(cols)))
    for j, c in enumerate(cols):
        out[:, j] = c
    return out


def _attitudes(d: dict[str, np.ndarray], wxyz: tuple[str, ...]) -> np.ndarray:
    """The FLU body in ENU ``[x, y, z, w]`` of PX4 quaternion fields ``wxyz`` (FRD in NED,
    ``[w, x, y, z]``, read in ``[x, y, z, w]`` order): :func:`frd_ned_to_flu_enu`."""
    return frd_ned_to_flu_enu(_columns(d, (*wxyz[1:], wxyz[0])))


def _stamps(path: Path, topic: str, d: dict[str, np.ndarray], start_us: int) -> np.ndarray:
    """``timestamp`` (µs, int64), refused when it goes back more than
    :data:`MAX_CLOCK_STEP_BACK_US` (a clock reset: no single clock for the topic)."""
    t = d["timestamp"].astype(np.int64)
    if len(t) > 1:
        step = np.diff(t)
        k = int(np.argmin(step))
        if step[k] < -MAX_CLOCK_STEP_BACK_US:
            raise InputError(
                f"{path}: {topic}'s timestamp jumps back {-step[k] * 1e-6:.3g} s at "
                f"{(t[k] - start_us) * 1e-6:.3f} s into the log (message {k + 1}); its clock "
                "was reset mid-log (a reboot?): use a log of one boot"
            )
    return t


def _sample_stamps(d: dict[str, np.ndarray], t_us: np.ndarray) -> np.ndarray:
    """``timestamp_sample`` (µs) where the topic has it (and set), else ``timestamp``."""
    ts = d.get("timestamp_sample")
    if ts is None:
        return t_us
    ts = ts.astype(np.int64)
    return np.where(ts > 0, ts, t_us)


# --------------------------------------------------------------------------- listing
@functools.lru_cache(maxsize=4)
def _whole(path: str, _mtime_ns: int, _size: int) -> tuple[list[tuple[str, int, int]], dict]:
    """:func:`ulog_topics` and :func:`ulog_info` of ``path`` (one walk, kept per file
    version)."""
    p = Path(path)
    found = scan.walk(p, [], stamps=True)
    if found is None:  # a framing the walk does not follow: pyulog over all of it
        u = scan.load_whole(p, None)
        topics = sorted((d.name, int(d.multi_id), len(d.data["timestamp"])) for d in u.data_list)
        last, dropouts = (
            int(u.last_timestamp),
            [(int(o.timestamp), int(o.duration)) for o in u.dropouts],
        )
    else:
        u = scan.parse(found.kept, p, [], False)
        topics = sorted(
            (name, int(inst), found.counts[k])
            for k, (name, inst) in found.subscriptions.items()
            if found.counts.get(k)
        )
        last, dropouts = int(found.last_us), [(int(t), int(d)) for t, d in found.dropouts]
    info = {
        "parameters": dict(u.initial_parameters),
        "info": dict(u.msg_info_dict),
        "start_us": int(u.start_timestamp),
        "last_us": last,
        "dropouts": dropouts,
    }
    return topics, info


def _summary(path: Path) -> tuple[list[tuple[str, int, int]], dict]:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file; check the path")
    st = path.stat()
    return _whole(str(path.resolve()), st.st_mtime_ns, st.st_size)


def ulog_topics(path: Path) -> list[tuple[str, int, int]]:
    """``(topic, instance, message count)`` of every topic logged in ``path`` (with at least
    one message), sorted. One walk through the log's framing (:func:`.scan.walk`), no data
    buffered; the result is kept for the file as it is."""
    return list(_summary(path)[0])


def ulog_info(path: Path) -> dict[str, Any]:
    """``{"parameters": initial parameters, "info": info strings, "start_us": the header's
    start, "last_us": the last message's timestamp, "dropouts": [(timestamp_us, ms), ...]}``
    of ``path`` (the same walk as :func:`ulog_topics`; the dropouts' stamps are the largest
    data timestamp before each, as pyulog gives them)."""
    info = _summary(path)[1]
    return {  # copies: the caller's to change, not the cache's
        **info,
        "parameters": dict(info["parameters"]),
        "info": dict(info["info"]),
        "dropouts": list(info["dropouts"]),
    }


def parse_topic(spec: str) -> tuple[str, int]:
    """``NAME[:INSTANCE]`` -> ``(NAME, INSTANCE)`` (instance 0 unless given)."""
    name, sep, inst = spec.strip().lstrip("/").partition(":")
    if not sep:
        return name, 0
    if not inst.isdigit():
        raise InputError(f"topic {spec!r}: expected NAME or NAME:INSTANCE (e.g. {name}:1)")
    return name, int(inst)


def topic_label(topic: str, instance: int) -> str:
    """``topic`` or ``topic:instance`` (instance > 0): a stream's name."""
    return f"{topic}:{instance}" if instance else topic


def _pose_topics(path: Path, u: Any) -> str:
    """The odometry and local position topics of ``path`` with their counts, for an error
    (``u``: its definitions)."""
    names = {n for n in u.message_formats if px4.format_kind(_flat_fields(u, n))}
    listed = [t for t in ulog_topics(path) if t[0] in names]
    return ", ".join(f"{topic_label(n, i)} ({c} msgs)" for n, i, c in listed) or "none"


def _missing(path: Path, u: Any, topic: str, instance: int) -> InputError:
    return InputError(
        f"{path.name} has no topic {topic_label(topic, instance)}; its odometry and local "
        f"position topics: {_pose_topics(path, u)}; {POSE_HINT}"
    )


# --------------------------------------------------------------------------- odometry
def read_odometry(path: Path, topic: str, instance: int = 0) -> Trajectory:
    """Topic ``topic`` (instance ``instance``) of ``path``, a ``vehicle_odometry``- or
    ``vehicle_local_position``-format topic, as a :class:`Trajectory`:

    - stamps: ``header_ns`` = ``timestamp_sample`` * 1000 where the topic has it, else
      ``timestamp`` * 1000; ``log_ns`` = ``timestamp`` * 1000;
    - ``position`` ENU = ``[p_n[1], p_n[0], -p_n[2]]`` of the NED (or FRD world) position;
    - ``orientation`` ``[x, y, z, w]``, the FLU body in ENU: ``q(ENU<-NED) q_ned_frd
      q(FRD<-FLU)``; a local position topic has none: ``vehicle_attitude`` (for a
      ``_groundtruth`` topic ``vehicle_attitude_groundtruth``) at the nearest sample stamp,
      or, not logged, the yaw-only quaternion of ``heading`` (older: ``yaw``);
    - ``velocity`` in the world frame, ENU: a world-frame velocity (NED, FRD) converted as
      the position, a body-frame one (``BODY_FRD``) rotated by the message's attitude,
      ``v = R(q_enu_flu) [v_x, -v_y, -v_z]``; NaN where the frame is unknown or PX4 logged
      NaN; None when every one is NaN (then ingest differentiates the positions).

    An FRD world frame (``pose_frame`` FRD: z down, x forward at start, not north) is
    converted as NED is: the result is a z-up world whose heading is arbitrary, which the
    ingest's alignment absorbs. A one-line :class:`InputError` when the topic is not
    logged (listing the odometry and position topics the log has), is of another format,
    or its pose frame is unknown; or its clock jumps back (:data:`MAX_CLOCK_STEP_BACK_US`).
    """
    (traj,) = read_odometries(path, [(topic, instance)])
    return traj


def read_odometries(path: Path, wanted: Sequence[tuple[str, int]]) -> list[Trajectory]:
    """:func:`read_odometry` of each ``(topic, instance)`` of ``wanted``, in one pass."""
    path = Path(path)
    head = load(path, [], header_only=True)
    kinds: list[str] = []
    names: set[str] = set()
    for topic, instance in wanted:
        if topic not in head.message_formats:
            raise _missing(path, head, topic, instance)
        kind = px4.format_kind(_flat_fields(head, topic))
        if kind is None:
            raise InputError(
                f"{path.name}: topic {topic} is not an odometry or local position topic "
                f"(fields {', '.join(_flat_fields(head, topic)[:12])}, ...); name one "
                f"of: {_pose_topics(path, head)}"
            )
        kinds.append(kind)
        names.add(topic)
        if kind == px4.LOCAL_POSITION and _attitude_topic(topic) in head.message_formats:
            names.add(_attitude_topic(topic))
    u = load(path, sorted(names))
    out = []
    for (topic, instance), kind in zip(wanted, kinds, strict=True):
        d = _dataset(u, topic, instance)
        if d is None:
            raise _missing(path, head, topic, instance)
        conv = _odometry if kind == px4.ODOMETRY else _local_position
        out.append(conv(path, u, topic, instance, d.data))
    return out


def _attitude_topic(topic: str) -> str:
    return px4.ATTITUDE_GROUNDTRUTH if topic.endswith("_groundtruth") else px4.ATTITUDE


def _trajectory(
    topic: str, instance: int, kind: str, t_us: np.ndarray, header_us: np.ndarray,
    p: np.ndarray, q: np.ndarray, v: np.ndarray, world: str,
) -> Trajectory:  # fmt: skip
    has_v = bool(np.isfinite(v).any())
    return Trajectory(
        name=topic_label(topic, instance),
        msgtype=px4.MSGTYPE_PREFIX + kind,
        header_ns=header_us * 1000,
        log_ns=t_us * 1000,
        position=p,
        orientation=q,
        velocity=v if has_v else None,
        frame_id=world,
        child_frame_id="FLU",
        decoder="pyulog",
    )


def _odometry(
    path: Path, u: Any, topic: str, instance: int, d: dict[str, np.ndarray]
) -> Trajectory:
    """A ``vehicle_odometry``-format topic (:func:`read_odometry`)."""
    label = topic_label(topic, instance)
    t = _stamps(path, label, d, int(u.start_timestamp))
    pos_f = px4.first_present(d, px4.POSITION_FIELDS)
    assert pos_f is not None  # format_kind checked it
    p = ned_to_enu(_columns(d, pos_f))
    q = _attitudes(d, px4.QUATERNION_FIELDS)
    gen = px4.frame_field(d)
    frames = np.full(len(t), px4.NED, dtype=np.uint8)
    if gen is not None:
        frames = _frames(d[gen], px4.POSE_FRAMES[gen])
        unknown = frames == px4.UNKNOWN
        if unknown.any():
            k = int(np.flatnonzero(unknown)[0])
            raise InputError(
                f"{path.name}: {label} has {int(unknown.sum())} messages in a pose frame "
                f"other than NED or FRD ({gen} {int(d[gen][k])} at message {k}); their "
                "positions cannot be converted: the sender must set the frame (MAVLink "
                "ODOMETRY frame_id MAV_FRAME_LOCAL_NED or MAV_FRAME_LOCAL_FRD)"
            )
    v = _odometry_velocity(d, gen, q)
    world = "ENU" if (frames == px4.NED).all() else "ENU (from FRD: heading arbitrary)"
    return _trajectory(topic, instance, px4.ODOMETRY, t, _sample_stamps(d, t), p, q, v, world)


def _odometry_velocity(d: dict[str, np.ndarray], gen: str | None, q: np.ndarray) -> np.ndarray:
    """An odometry's velocity in ENU (n, 3) (:func:`read_odometry`): a world frame's (NED,
    FRD) as positions are, ``BODY_FRD`` rotated by the attitude ``q`` (FLU in ENU),
    ``v = R(q) [v_x, -v_y, -v_z]``, NaN for another frame or none logged."""
    n = len(q)
    fields = px4.first_present(d, px4.VELOCITY_FIELDS)
    if fields is None:
        return np.full((n, 3), np.nan)
    raw = _columns(d, fields)
    if gen is not None and "velocity_frame" in d:
        vf = _frames(d["velocity_frame"], px4.VELOCITY_FRAMES[gen])
    else:
        vf = np.full(n, px4.NED, dtype=np.uint8)
    world = (vf == px4.NED) | (vf == px4.FRD)
    if world.all():  # the usual: no row of another frame
        return ned_to_enu(raw)
    v = np.full((n, 3), np.nan)
    v[world] = ned_to_enu(raw[world])
    for rows in _blocks(np.flatnonzero(vf == px4.BODY_FRD)):
        v[rows] = body_to_world(q[rows], frd_to_flu(raw[rows]))
    return v


def _frames(codes: np.ndarray, names: dict[int, int]) -> np.ndarray:
    """The reader's frame codes (:data:`px4.NED`, ...) of PX4's frame codes ``codes``
    (:data:`px4.UNKNOWN` for one not in ``names``)."""
    lut = np.full(256, px4.UNKNOWN, dtype=np.uint8)
    for code, frame in names.items():
        lut[code] = frame
    return lut[np.asarray(codes).astype(np.uint8)]


def _blocks(rows: np.ndarray) -> Iterable[np.ndarray]:
    for a in range(0, len(rows), _BLOCK):
        yield rows[a : a + _BLOCK]


def _local_position(
    path: Path, u: Any, topic: str, instance: int, d: dict[str, np.ndarray]
) -> Trajectory:
    """A ``vehicle_local_position``-format topic (:func:`read_odometry`)."""
    label = topic_label(topic, instance)
    t = _stamps(path, label, d, int(u.start_timestamp))
    header = _sample_stamps(d, t)
    p = ned_to_enu(_columns(d, ("x", "y", "z")))
    v = ned_to_enu(_columns(d, ("vx", "vy", "vz")))
    att = _dataset(u, _attitude_topic(topic), 0)
    if att is not None:
        ta = _sample_stamps(att.data, att.data["timestamp"].astype(np.int64))
        order = np.argsort(ta, kind="stable")
        ta = ta[order]
        qa = _attitudes(att.data, px4.QUATERNION_FIELDS)[order]
        q = qa[_nearest(ta, header)]
    else:
        heading = next((f for f in px4.HEADING_FIELDS if f in d), None)
        yaw = d[heading].astype(float) if heading else np.zeros(len(t))
        q = yaw_quat(yaw_ned_to_enu(yaw))
    return _trajectory(topic, instance, px4.LOCAL_POSITION, t, header, p, q, v, "ENU")


def _nearest(sorted_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index into ``sorted_t`` of the stamp nearest each of ``t``."""
    i = np.clip(np.searchsorted(sorted_t, t), 1, max(len(sorted_t) - 1, 1))
    before = np.clip(i - 1, 0, len(sorted_t) - 1)
    after = np.clip(i, 0, len(sorted_t) - 1)
    return np.where(np.abs(t - sorted_t[before]) <= np.abs(sorted_t[after] - t), before, after)


# --------------------------------------------------------------------------- commands
def read_commands(path: Path) -> AttitudeCommands:
    """The attitude setpoints of ``path`` (``vehicle_attitude_setpoint``, instance 0) and the
    hover thrust in force at each (:class:`AttitudeCommands`): ``q_d`` (FRD in NED,
    ``[w, x, y, z]``) -> FLU in ENU ``[x, y, z, w]``; thrust ``|thrust_body|`` (FRD,
    normalized: hover is about ``[0, 0, -0.5]``) or, older PX4, ``|thrust|``."""
    path = Path(path)
    u = load(path, [px4.ATTITUDE_SETPOINT, px4.HOVER_THRUST_ESTIMATE])
    sp = _dataset(u, px4.ATTITUDE_SETPOINT, 0)
    if sp is None:
        raise InputError(
            f"{path.name} has no {px4.ATTITUDE_SETPOINT} messages: the controller's setpoints "
            "must be logged (PX4's default SDLOG_PROFILE logs them; was the controller "
            "running?); give the log of the controlled flight"
        )
    d = sp.data
    t = _stamps(path, px4.ATTITUDE_SETPOINT, d, int(u.start_timestamp))
    q = _attitudes(d, px4.Q_D_FIELDS)
    if set(px4.THRUST_BODY_FIELDS) <= set(d):
        thrust = np.linalg.norm(_columns(d, px4.THRUST_BODY_FIELDS), axis=1)
    elif "thrust" in d:
        thrust = np.abs(d["thrust"].astype(float))
    else:
        raise InputError(
            f"{path.name}: {px4.ATTITUDE_SETPOINT} has neither thrust_body nor thrust; "
            "a PX4 generation this reader does not know"
        )
    hover, source = _hover_thrust(u, t)
    fac = u.initial_parameters.get(px4.THR_MDL_PARAM)
    return AttitudeCommands(
        t_ns=t * 1000,
        q=q,
        thrust=thrust,
        hover_thrust=hover,
        hover_source=source,
        thr_mdl_fac=None if fac is None else float(fac),
    )


def _hover_thrust(u: Any, t_us: np.ndarray) -> tuple[np.ndarray, str]:
    """The hover throttle in force at each ``t_us`` and where it came from
    (:class:`AttitudeCommands`): the latest valid estimate at or before ``t``, else the
    parameter's value then (its initial value, changed where the log records a change)."""
    out = np.full(len(t_us), np.nan)
    used: list[str] = []
    est = _dataset(u, px4.HOVER_THRUST_ESTIMATE, 0)
    from_est = np.zeros(len(t_us), dtype=bool)
    if est is not None:
        ok = est.data["valid"].astype(bool) & np.isfinite(est.data["hover_thrust"])
        te = est.data["timestamp"].astype(np.int64)[ok]
        he = est.data["hover_thrust"].astype(float)[ok]
        order = np.argsort(te, kind="stable")
        te, he = te[order], he[order]
        i = np.searchsorted(te, t_us, side="right") - 1
        from_est = i >= 0
        out[from_est] = he[i[from_est]]
        if from_est.any():
            used.append(px4.HOVER_THRUST_ESTIMATE)
    rest = ~from_est
    changes = [(int(ts), float(v)) for ts, k, v in u.changed_parameters if k == px4.HOVER_PARAM]
    first = u.initial_parameters.get(px4.HOVER_PARAM)
    if rest.any() and (first is not None or changes):
        tp = np.array([np.iinfo(np.int64).min] + [c[0] for c in changes], dtype=np.int64)
        vp = np.array([np.nan if first is None else float(first)] + [c[1] for c in changes])
        j = np.searchsorted(tp, t_us[rest], side="right") - 1
        out[rest] = vp[j]
        if np.isfinite(out[rest]).any():
            used.append(px4.HOVER_PARAM)
    source = {0: "none", 1: used[0] if used else "none", 2: "mixed"}[len(used)]
    return out, source


# --------------------------------------------------------------------------- setpoints
def read_setpoints(path: Path) -> PositionSetpoints:
    """The trajectory setpoints of ``path`` (``trajectory_setpoint``, instance 0) in ENU
    (:class:`PositionSetpoints`): ``position[3]``, ``velocity[3]``, ``acceleration[3]``
    (older PX4: ``x, y, z``, ``vx, vy, vz``, ``acceleration[3]`` or ``acc_x, acc_y,
    acc_z``), NED -> ENU as positions are; ``yaw`` -> ``pi/2 - yaw``; NaN stays NaN."""
    path = Path(path)
    u = load(path, [px4.TRAJECTORY_SETPOINT])
    sp = _dataset(u, px4.TRAJECTORY_SETPOINT, 0)
    if sp is None:
        raise InputError(
            f"{path.name} has no {px4.TRAJECTORY_SETPOINT} messages: the controller's "
            "setpoints must be logged (PX4's default SDLOG_PROFILE logs them; was the "
            "vehicle in a position mode?); give the log of the controlled flight"
        )
    d = sp.data
    t = _stamps(path, px4.TRAJECTORY_SETPOINT, d, int(u.start_timestamp))

    def vec(groups: tuple[tuple[str, ...], ...]) -> np.ndarray:
        f = px4.first_present(d, groups)
        return np.full((len(t), 3), np.nan) if f is None else ned_to_enu(_columns(d, f))

    yaw = d["yaw"].astype(float) if "yaw" in d else np.full(len(t), np.nan)
    return PositionSetpoints(
        t_ns=t * 1000,
        p=vec(px4.POSITION_FIELDS),
        v=vec(px4.VELOCITY_FIELDS),
        a=vec(px4.ACCELERATION_FIELDS),
        yaw=yaw_ned_to_enu(yaw),
    )
