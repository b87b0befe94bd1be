"""The two streams of an ingest: read from bags or text files, then prepared.

- :func:`read_streams`: the VIO and truth trajectories from the sources (topics chosen as
  the options say, or automatically), one pass per bag; :func:`read_vio_stream`: the VIO
  stream of one source (``qsls replay``).
- :func:`prepare`: stamps (header or log time), non-finite check, stable sort, exact
  duplicates dropped, counted (:class:`Prepared`); :func:`check_streams` refuses a pair
  that would give a meaningless flight.
- :func:`interp` and :func:`gaps`: linear interpolation onto a grid that never bridges a
  gap longer than ``max_gap``, and the gaps the manifest lists (also used by ``replay``).

The flight itself is made of the two streams by the pure core,
:func:`qsls.pipeline.ingest.assemble.flight_from_streams`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.rotations import world_to_body
from qsls.pipeline.ingest.resample import interp_rows, median_spacing
from qsls.pipeline.ingest.sources.bags import BagSource
from qsls.pipeline.ingest.sources.base import Trajectory, detect
from qsls.pipeline.ingest.sources.msgtypes import TF
from qsls.pipeline.ingest.sources.select import (
    POSE_TYPES,
    TRUTH_TYPES,
    choose,
    choose_vio,
    describe,
    find_topic,
)
from qsls.pipeline.ingest.sources.text.reader import TEXT_READERS
from qsls.pipeline.ingest.sources.ulog import px4
from qsls.pipeline.ingest.sources.ulog.px4 import MSGTYPE_PREFIX

if TYPE_CHECKING:
    from qsls.pipeline.ingest.options import IngestOptions

CHUNK = 1 << 16
"""Rows computed at once where a stream-long computation is local to each row: its
temporaries stay bounded whatever the flight's length."""


@dataclass(frozen=True)
class Prepared:
    """A stream after stamp selection, sorting and de-duplication."""

    role: str
    source: str
    topic: str
    msgtype: str
    decoder: str
    t_ns: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray | None
    messages: int
    duplicates: int
    unsorted: int
    nonfinite: int
    glitches: int = 0
    """Truth discontinuities turned into gaps (:func:`truth_jumps`)."""
    variance: np.ndarray | None = None
    """An Odometry's covariance diagonals as recorded, ``(n, 12)``: pose (``x y z`` in its
    world frame, rotation about its ``x y z``), then twist (linear ``x y z``, angular, in
    its child frame); None when the stream has none (docs/ingest.md#covariances)."""

    @property
    def rate_hz(self) -> float:
        if len(self.t_ns) < 2:
            return 0.0
        return 1e9 / median_spacing(self.t_ns)

    def describe(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "topic": self.topic,
            "msgtype": self.msgtype,
            "decoder": self.decoder,
            "messages": self.messages,
            "samples": len(self.t_ns),
            "rate_hz": round(self.rate_hz, 3),
            "duplicates_dropped": self.duplicates,
            "unsorted": self.unsorted,
            "nonfinite_dropped": self.nonfinite,
            "discontinuities": self.glitches,
        }


# --------------------------------------------------------------------------- reading
def read_streams(sources: list[Path], o: IngestOptions, progress: Progress) -> list[Trajectory]:
    """``[vio, truth]`` trajectories, each with the path it was read from (``source``).

    A role read from a PX4 ULog (the only source, or ``--vio FILE`` / ``--truth FILE``)
    takes its topic ``NAME[:INSTANCE]`` from ``--vio-topic`` / ``--truth-topic``, by default
    :data:`~qsls.pipeline.ingest.sources.ulog.px4.DEFAULT_VIO_TOPIC` /
    :data:`~qsls.pipeline.ingest.sources.ulog.px4.DEFAULT_TRUTH_TOPIC` (:func:`_read_ulogs`;
    both roles from one log in one pass)."""
    sources = [Path(s) for s in sources]
    if not sources and (o.vio is None or o.truth is None):
        raise InputError("no input: give a bag (SOURCE...) or both --vio FILE and --truth FILE")
    texts: dict[str, Any] = {}
    ready: dict[str, str] = {}  # role -> where a stream read whole (text, ULog) came from
    ulogs: dict[str, Path] = {}
    bags: dict[Path, BagSource] = {}
    try:
        role_files: dict[str, list[Path]] = {}
        for role, given in (("vio", o.vio), ("truth", o.truth)):
            files = [Path(given)] if given is not None else sources
            role_files[role] = files
            for f in files:
                kind = detect(f)
                if kind in TEXT_READERS:
                    if given is None:
                        raise InputError(
                            f"{f}: a text trajectory; pass text files with --vio FILE --truth FILE"
                        )
                    texts[role] = TEXT_READERS[kind](f)
                    ready[role] = str(given)
                elif kind == "ulog":
                    if len(files) > 1:
                        raise InputError(
                            f"{f}: a PX4 ULog among several sources; give it alone, or pass "
                            "it with --vio FILE / --truth FILE"
                        )
                    ulogs[role] = f
                    ready[role] = str(f)
                elif f not in bags:
                    bags[f] = BagSource(f)
        texts.update(_read_ulogs(ulogs, o))
        topics = {p: b.topics() for p, b in bags.items()}
        vio_topics = [t for f in role_files["vio"] if f in bags for t in topics[f]]
        truth_topics = [t for f in role_files["truth"] if f in bags for t in topics[f]]
        if "vio" in texts and "truth" in texts:
            return _placed(texts, ready)
        vio_info = truth_info = None
        if "vio" in texts:
            truth_info = _pick_truth(truth_topics, o)
        elif "truth" in texts:
            vio_info = pick_vio(vio_topics, o.vio_topic)
        else:
            vio_info, truth_info = choose(
                vio_topics, truth_topics, o.vio_topic, o.truth_topic, o.truth_frame
            )
        fast = o.decoder == "fast"
        if truth_info is not None and truth_info.msgtype == TF and not o.truth_frame:
            # a TF topic alone: read it first, its reader lists the transforms to choose from
            bags[truth_info.source].read(truth_info.topic, fast=fast, progress=progress)
        out: dict[str, Any] = dict(texts)
        where: dict[str, str] = {}
        wanted: dict[Path, list[tuple[str, str, str | None]]] = {}
        for role, info in (("vio", vio_info), ("truth", truth_info)):
            if info is None:
                where[role] = ready[role]
                continue
            frame = o.truth_frame if role == "truth" else None
            wanted.setdefault(info.source, []).append((role, info.topic, frame))
            where[role] = str(info.source)
        for source, reqs in wanted.items():  # one pass per bag for both streams
            got = bags[source].read_many([(t, f) for _, t, f in reqs], fast=fast, progress=progress)
            out.update({role: g for (role, _, _), g in zip(reqs, got, strict=True)})
        return _placed(out, where)
    finally:
        for b in bags.values():
            b.close()


def _read_ulogs(ulogs: dict[str, Path], o: IngestOptions) -> dict[str, Trajectory]:
    """The roles read from PX4 ULogs (``{role: log}``), each log read once for the roles it
    serves (:func:`~qsls.pipeline.ingest.sources.ulog.reader.read_odometries`)."""
    if not ulogs:
        return {}
    # deferred: the ULog reader (its imports, 10 ms) only when a ULog is read
    from qsls.pipeline.ingest.sources.ulog.reader import parse_topic, read_odometries

    spec = {
        "vio": o.vio_topic or px4.DEFAULT_VIO_TOPIC,
        "truth": o.truth_topic or px4.DEFAULT_TRUTH_TOPIC,
    }
    out: dict[str, Trajectory] = {}
    for log in dict.fromkeys(ulogs.values()):
        roles = [r for r, f in ulogs.items() if f == log]
        got = read_odometries(log, [parse_topic(spec[r]) for r in roles])
        out.update(zip(roles, got, strict=True))
    return out


def _placed(streams: dict[str, Trajectory], where: dict[str, str]) -> list[Trajectory]:
    return [dataclasses.replace(streams[r], source=where[r]) for r in ("vio", "truth")]


def _pick_truth(topics: list[Any], o: IngestOptions) -> Any:
    """The truth topic when the VIO comes from a text file."""
    if o.truth_topic:
        t = find_topic(topics, o.truth_topic, "truth", TRUTH_TYPES)
    else:
        allowed = TRUTH_TYPES if o.truth_frame else POSE_TYPES
        c = [t for t in topics if t.msgtype in allowed and t.topic != "/tf_static"]
        if len(c) != 1:
            raise InputError(
                f"cannot choose the truth topic automatically ({len(c)} candidates: "
                f"{describe(c)}); pass --truth-topic"
            )
        t = c[0]
    if t.msgtype.endswith("TFMessage") and not o.truth_frame:
        raise InputError(f"topic {t.topic} is a TF topic; pass --truth-frame PARENT/CHILD")
    return t


def pick_vio(topics: list[Any], vio_topic: str | None) -> Any:
    """The VIO topic of ``topics``: the one named, else chosen (:func:`select.choose_vio`)."""
    if vio_topic:
        return find_topic(topics, vio_topic, "vio", POSE_TYPES)
    return choose_vio(topics, set())


def read_vio_stream(
    source: Path, vio_topic: str | None, *, fast: bool = True, progress: Progress = NULL_PROGRESS
) -> Trajectory:
    """The VIO stream of one source, as ingest reads it: a text trajectory (TUM, EuRoC csv),
    a PX4 ULog's topic (``vio_topic``, default ``vehicle_visual_odometry``), or the bag's VIO
    topic, named or chosen (:func:`pick_vio`). What ``qsls replay`` reads."""
    source = Path(source)
    kind = detect(source)
    if kind in TEXT_READERS:
        return dataclasses.replace(TEXT_READERS[kind](source), source=str(source))
    if kind == "ulog":
        # deferred: the ULog reader (its imports, 10 ms) only when a ULog is read
        from qsls.pipeline.ingest.sources.ulog.reader import parse_topic, read_odometry

        traj = read_odometry(source, *parse_topic(vio_topic or px4.DEFAULT_VIO_TOPIC))
        return dataclasses.replace(traj, source=str(source))
    with BagSource(source) as bag:
        info = pick_vio(bag.topics(), vio_topic)
        (traj,) = bag.read_many([(info.topic, None)], fast=fast, progress=progress)
    return dataclasses.replace(traj, source=str(source))


# --------------------------------------------------------------------------- preparing
def prepare(traj: Any, role: str, source: str, o: IngestOptions) -> Prepared:
    """Stamps, non-finite check, sort, exact-duplicate removal and, for the truth, jumps turned
    into gaps (:func:`truth_jumps`, :func:`drop_around`): the ingest stage's step 2."""
    t = traj.log_ns if o.stamp == "log" else traj.header_ns
    t = np.asarray(t, dtype=np.int64)
    p, q, v = traj.position, traj.orientation, traj.velocity
    if v is not None and traj.msgtype.startswith(MSGTYPE_PREFIX):
        v = world_velocity(traj, role, o)
    var = None
    if getattr(traj, "pose_var", None) is not None and getattr(traj, "twist_var", None) is not None:
        var = np.hstack([traj.pose_var, traj.twist_var])
    n = len(t)
    name = f"{role} stream {traj.name}"
    if n == 0:
        raise InputError(f"{name} has no messages; check the topic or the file")
    ok, qn = _usable(p, q, v)
    nonfinite = int(n - ok.sum())
    if nonfinite and not o.drop_nonfinite:
        first = int(np.flatnonzero(~ok)[0])
        raise InputError(
            f"{name}: {nonfinite} of {n} messages hold NaN, infinite or zero-quaternion values "
            f"(first is message {first}); fix the log or pass --drop-nonfinite to skip them"
        )
    if nonfinite:
        t, p, q, qn = t[ok], p[ok], q[ok], qn[ok]
        v = v[ok] if v is not None else None
        var = var[ok] if var is not None else None
    # the usual stream is sorted and without duplicates: nothing to reorder or drop then
    step = np.diff(t)
    unsorted = int(np.sum(step < 0))
    if unsorted:
        _refuse_clock_reset(step, name, o)
        order = np.argsort(t, kind="stable")
        t, p, q, qn = t[order], p[order], q[order], qn[order]
        v = v[order] if v is not None else None
        var = var[order] if var is not None else None
        step = np.diff(t)
    keep = np.concatenate([[True], step != 0])
    duplicates = int(len(t) - keep.sum())
    if duplicates:
        t, p, q, qn = t[keep], p[keep], q[keep], qn[keep]
        v = v[keep] if v is not None else None
        var = var[keep] if var is not None else None
    if len(t) < 10:
        raise InputError(f"{name}: only {len(t)} usable messages; at least 10 are needed")
    q /= qn[:, None]  # the norms of the finite quaternions kept (in place: the stream's own)
    glitches = 0
    if role == "truth":  # a discontinuity of the truth becomes a gap, never interpolated motion
        jumps = truth_jumps(t, p, o.max_truth_accel)
        glitches = len(jumps)
        if glitches:
            bad = drop_around(t, jumps, int(o.max_gap * 1e9 / 2) + 1)
            t, p, q = t[~bad], p[~bad], q[~bad]
            v = v[~bad] if v is not None else None
            var = var[~bad] if var is not None else None
            if len(t) < max(10, n // 2):
                raise InputError(
                    f"{name}: check --truth-topic and --vio-topic (swapped?), or raise "
                    f"ingest.max_truth_accel in the config: {glitches} jumps no vehicle could "
                    f"fly (accelerations above {o.max_truth_accel:g} m/s^2) leave {len(t)} of "
                    f"{n} messages; is it the motion-capture topic?"
                )
    return Prepared(
        role,
        source,
        traj.name,
        traj.msgtype,
        traj.decoder,
        t,
        p,
        q,
        v,
        n,
        duplicates,
        unsorted,
        nonfinite,
        glitches,
        var,
    )


def _usable(p: np.ndarray, q: np.ndarray, v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Which messages are usable (finite position, orientation and velocity, a quaternion of
    norm above 1e-9) and each quaternion's norm (its non-finite entries taken as 0)."""
    n = len(q)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    if v is not None:
        ok &= np.isfinite(v).all(axis=1)
    qn = np.empty(n)
    for a in range(0, n, CHUNK):  # row by row: the same norms, without copies of q
        qa = q[a : a + CHUNK]
        qn[a : a + CHUNK] = np.linalg.norm(np.where(np.isfinite(qa), qa, 0.0), axis=1)
    ok &= qn > 1e-9
    return ok, qn


def _refuse_clock_reset(step: np.ndarray, name: str, o: IngestOptions) -> None:
    """Stamps that go back by more than ``max_gap`` are a clock reset, not reordered
    messages: refused (sorting would splice two flights' times together)."""
    if step.min() < -o.max_gap * 1e9:
        k = int(np.argmin(step)) + 1
        raise InputError(
            f"{name}: its clock jumps back {-step.min() * 1e-9:.3g} s at message {k} "
            f"(--stamp {o.stamp}); a clock that was reset or set mid-flight: cut the log "
            "there, or try --stamp " + ("log" if o.stamp == "header" else "header")
        )


def world_velocity(traj: Any, role: str, o: IngestOptions) -> np.ndarray | None:
    """A PX4 ULog stream's velocity, which its reader gives in the world frame (ENU), as the
    velocity step will take it (docs/ingest.md#px4-ulog):

    - None (the positions differentiated instead) when it is not finite on every message
      whose pose is (a VIO or mocap source that sends velocity on some messages only);
    - for the VIO under ``vio_velocity_frame: body`` (the default, the ROS convention the
      step applies, ``v_w = R(q) v_b``): expressed in the body frame, ``v_b = R(q)^T v_w``,
      so that the step gives the logged world velocity back (to rounding);
    - otherwise as read.
    """
    v = traj.velocity
    posed = np.isfinite(traj.position).all(axis=1) & np.isfinite(traj.orientation).all(axis=1)
    if not np.isfinite(v[posed]).all():
        return None
    if role != "vio" or o.vio_velocity_frame != "body":
        return v
    out = np.empty_like(v, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):  # zero quaternions: dropped later
        for a in range(0, len(v), CHUNK):
            out[a : a + CHUNK] = world_to_body(traj.orientation[a : a + CHUNK], v[a : a + CHUNK])
    return out


GLITCH_JUMP_M = 0.01
"""A discontinuity also moves the position off the neighbouring motion by at least this much:
the acceleration of a few millimetres of noise at hundreds of hertz is never mistaken for one."""


def truth_jumps(t_ns: np.ndarray, p: np.ndarray, max_accel: float) -> np.ndarray:
    """Intervals ``[k, k+1]`` of a motion-capture stream that no vehicle could have flown: the
    interval's velocity differs from both neighbouring intervals' by an acceleration above
    ``max_accel`` (m/s^2) and moves the position at least :data:`GLITCH_JUMP_M` off their
    mean velocity (a tracker that jumps and comes back makes two such intervals, one that
    re-acquires with an offset makes one).

    Computed on windows of :data:`CHUNK` intervals and their neighbours (every quantity is
    local to an interval and its two neighbours): the same intervals as at once, in
    memory bounded by the window."""
    n = len(t_ns)
    if n < 4:
        return np.zeros(0, dtype=np.int64)
    t_ns = np.asarray(t_ns, np.int64)
    m = n - 1  # intervals
    found = []
    for a in range(0, m, CHUNK):
        b = min(a + CHUNK, m)
        lo, hi = max(a - 1, 0), min(b + 1, m)  # with the neighbouring intervals
        flags = _jump_flags(t_ns[lo : hi + 1], int(t_ns[0]), p[lo : hi + 1], max_accel)
        found.append(np.flatnonzero(flags[a - lo : b - lo]) + a)
    return np.concatenate(found)


def _jump_flags(t_ns: np.ndarray, t0: int, p: np.ndarray, max_accel: float) -> np.ndarray:
    """:func:`truth_jumps`' test of every interval of ``t_ns`` (the first and last taken as
    the stream's ends: their own velocity stands in for the missing neighbour's)."""
    t = (t_ns - t0) / 1e9
    h = np.diff(t)
    v = np.diff(p, axis=0) / h[:, None]
    if len(v) < 2:
        return np.zeros(len(v), dtype=bool)
    dv = np.abs(np.diff(v, axis=0)).max(axis=1) / (0.5 * (h[:-1] + h[1:]))  # between intervals
    before = np.concatenate([[0.0], dv])  # interval i against i-1
    after = np.concatenate([dv, [0.0]])  # interval i against i+1
    mean_nb = 0.5 * (np.vstack([v[:1], v[:-1]]) + np.vstack([v[1:], v[-1:]]))
    off = np.abs(v - mean_nb).max(axis=1) * h
    return (before > max_accel) & (after > max_accel) & (off >= GLITCH_JUMP_M)


def drop_around(t_ns: np.ndarray, intervals: np.ndarray, half_gap_ns: int) -> np.ndarray:
    """Samples to drop so that each jump becomes a gap the resampling will not bridge: those
    within ``half_gap_ns`` of the interval's ends."""
    bad = np.zeros(len(t_ns), dtype=bool)
    for k in intervals:
        lo, hi = int(t_ns[k]) - half_gap_ns, int(t_ns[k + 1]) + half_gap_ns
        bad |= (t_ns >= lo) & (t_ns <= hi)
    return bad


def check_streams(vio: Prepared, truth: Prepared, o: IngestOptions) -> None:
    """Refuse what would give a meaningless flight: the same stream as VIO and truth (the
    same source and topic, or identical samples: ``e = 0`` everywhere, a degenerate error
    model), or a stream whose own sampling step is longer than ``max_gap`` (no grid point
    could be interpolated from it)."""
    same_source = Path(vio.source).resolve() == Path(truth.source).resolve()
    if same_source and vio.topic == truth.topic:
        raise InputError(
            f"the VIO and truth streams are the same ({vio.topic} in {vio.source}); "
            "the errors would all be 0: give the VIO estimate and the ground truth"
        )
    if len(vio.t_ns) == len(truth.t_ns) and np.array_equal(vio.position, truth.position):
        raise InputError(
            f"the VIO ({vio.topic}) and truth ({truth.topic}) streams hold identical samples; "
            "the errors would all be 0: give the VIO estimate and the ground truth"
        )
    for s in (vio, truth):
        step = median_spacing(s.t_ns) * 1e-9
        if step > o.max_gap:
            raise InputError(
                f"the {s.role} stream {s.topic} has one sample every {step:.3g} s "
                f"({s.rate_hz:.3g} Hz), longer than --max-gap {o.max_gap:g} s, so no point "
                f"could be interpolated; raise --max-gap above {step:.3g} s (e.g. "
                f"{2 * step:.2g}) if interpolating across {step:.3g} s is acceptable"
            )


def interp(
    grid: np.ndarray, t: np.ndarray, values: np.ndarray, max_gap_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation at ``grid``; mask of grid points not bracketing a long gap.

    Computed on :data:`CHUNK` grid points at a time (each point's value is its own: the
    same as at once), so a grid as long as the stream costs its output, not ten times it."""
    values = np.asarray(values, dtype=float)
    if len(grid) > CHUNK:
        out = np.empty((len(grid), values.shape[1]))
        ok = np.empty(len(grid), dtype=bool)
        for a in range(0, len(grid), CHUNK):
            out[a : a + CHUNK], ok[a : a + CHUNK] = interp(
                grid[a : a + CHUNK], t, values, max_gap_ns
            )
        return out, ok
    i = np.searchsorted(t, grid, side="right") - 1
    inside = (i >= 0) & (i < len(t))
    i = np.clip(i, 0, len(t) - 1)
    exact = inside & (t[i] == grid)
    j = np.clip(i + 1, 0, len(t) - 1)
    bracket = inside & (i + 1 < len(t)) & ((t[j] - t[i]) <= max_gap_ns)
    valid = exact | bracket
    x = (grid - t[0]).astype(float)
    # the stream's stamps around the grid's only (the same brackets and weights)
    a = max(int(i.min()) if len(i) else 0, 0)
    b = min(int(j.max()) + 1 if len(j) else len(t), len(t))
    a, b = (0, len(t)) if b - a < 2 else (a, b)
    tt = (t[a:b] - t[0]).astype(float)
    return interp_rows(x, tt, values[a:b]), valid


def gaps(s: Prepared, lo: int, hi: int, max_gap_ns: int, t_first: int) -> list[dict[str, Any]]:
    """The gaps of ``s`` longer than ``max_gap_ns`` that overlap ``(lo, hi)``, as the
    manifest lists them (``t_start_s`` from ``t_first``)."""
    d = np.diff(s.t_ns)
    out = []
    for k in np.flatnonzero(d > max_gap_ns):
        a, b = int(s.t_ns[k]), int(s.t_ns[k + 1])
        if b <= lo or a >= hi:
            continue
        out.append(
            {
                "stream": s.role,
                "start_ns": a,
                "end_ns": b,
                "t_start_s": round((a - t_first) * 1e-9, 6),
                "duration_s": round((b - a) * 1e-9, 6),
            }
        )
    return out
