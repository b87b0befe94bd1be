"""``qsls ingest``: VIO and motion-capture streams onto one clock, one frame and one grid.

Steps (DESIGN.md names):

1. Read the two streams (:mod:`qsls.pipeline.ingest.sources`): a VIO topic (``nav_msgs/Odometry``)
   and a truth topic (pose types, or a TF transform) from one or two bags, or text files
   (TUM, EuRoC csv) given with ``vio`` / ``truth``.
2. Stamps: header or log time; sort by stamp, drop exact duplicate stamps (the first
   message of a stamp is kept), count both. Non-finite values stop the stage (or are
   dropped and counted with ``drop_nonfinite``).
3. Clock offset ``tau`` (``time_offset_s``, added to truth stamps to put them on the VIO
   clock): given, or estimated (:mod:`qsls.pipeline.ingest.timesync`).
4. Frame: VIO velocity to the VIO world frame (``body``: ``v_w = R(q) v_b``; ``world``: as
   is; no twist: smoothing differentiator), then the alignment ``p' = R p + t``,
   ``v' = R v`` (:mod:`qsls.pipeline.ingest.align`) fitted on time-matched pairs.
5. Truth velocity: the smoothing differentiator on truth positions.
6. Resampling: both streams linearly interpolated onto ``t_k = t_0 + k dt`` over their
   common interval (``t_0`` the first multiple of ``dt`` inside it, VIO clock); a grid
   point between two samples of either stream further apart than ``max_gap`` is dropped,
   and those gaps are listed in the manifest.
7. ``flight.parquet`` (:func:`qsls.pipeline.ingest.flight.flight_table`): ``x`` = truth,
   ``y`` = aligned VIO, ``e = y - x``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator

from qsls.pipeline.core.config import Options
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress

STAGE = "ingest"


class IngestOptions(Options):
    """Options of ``qsls ingest`` (defaults are the built-in defaults)."""

    vio_topic: str | None = None
    """VIO topic (nav_msgs/Odometry, or a pose topic); chosen automatically when unambiguous."""
    truth_topic: str | None = None
    """Ground-truth topic; chosen automatically when unambiguous."""
    vio: Path | None = None
    """File holding the VIO stream (bag, TUM, EuRoC csv)."""
    truth: Path | None = None
    """File holding the truth stream (bag, TUM, EuRoC csv)."""
    dt: float = Field(0.1, gt=0)
    """Resampling period (s)."""
    align: Literal["4dof", "se3", "none"] = "4dof"
    """Frame alignment of the VIO to the truth: yaw + translation, full SE(3), or none."""
    time_offset: Literal["auto"] | float = "auto"
    """Seconds added to truth stamps to reach the VIO clock, or ``auto`` (estimated)."""
    vio_velocity_frame: Literal["body", "world"] = "body"
    """Frame of the Odometry twist: body (ROS convention) or world (VINS-style)."""
    stamp: Literal["header", "log"] = "header"
    """Time of a message: its header stamp or the bag's log time."""
    max_gap: float = Field(0.25, gt=0)
    """Never interpolate across a gap longer than this (s)."""
    truth_frame: str | None = None
    """PARENT/CHILD transform of a TF topic."""
    export_tum: bool = False
    """Also write both aligned trajectories as TUM files (for evo)."""
    max_time_offset: float = Field(2.0, gt=0)
    """Search range of ``time_offset: auto`` (s)."""
    min_overlap: float = Field(3.0, gt=0)
    """Least common time of the two streams (s)."""
    velocity_window: float = Field(0.1, gt=0)
    """Window of the smoothing differentiator (s)."""
    drop_nonfinite: bool = False
    """Skip messages with NaN/inf values instead of stopping."""
    decoder: Literal["fast", "deserializer"] = "fast"
    """Message decoding: the fast field reader, or rosbags' full deserializer (a check)."""

    @field_validator("truth_frame")
    @classmethod
    def _frame(cls, v: str | None) -> str | None:
        if v is not None and (v.count("/") < 1 or not all(v.strip("/").split("/", 1))):
            raise ValueError("expected PARENT/CHILD, e.g. world/body")
        return v.strip("/") if v else v


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

    @property
    def rate_hz(self) -> float:
        if len(self.t_ns) < 2:
            return 0.0
        return float(1e9 / np.median(np.diff(self.t_ns)))

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
        }


@dataclass(frozen=True)
class IngestResult:
    out: Path
    samples: int
    time_offset_s: float
    alignment: dict[str, Any]
    rms_position_m: float
    rms_velocity_mps: float
    streams: dict[str, dict[str, Any]]
    gaps: list[dict[str, Any]] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        v, t = self.streams["vio"], self.streams["truth"]
        return {
            "output": str(self.out),
            "samples": self.samples,
            "vio": _describe_stream(v),
            "truth": _describe_stream(t),
            "time offset (s)": round(self.time_offset_s, 4),
            "alignment": f"{self.alignment['method']}, yaw {np.degrees(self.alignment['yaw_rad']):.2f} deg",
            "RMS position error (m)": round(self.rms_position_m, 4),
            "RMS velocity error (m/s)": round(self.rms_velocity_mps, 4),
            "gaps": len(self.gaps),
            "duplicates dropped": v["duplicates_dropped"] + t["duplicates_dropped"],
        }


def _describe_stream(s: dict[str, Any]) -> str:
    kind = str(s["msgtype"]).rsplit("/", 1)[-1]
    return f"{s['topic']} ({kind}, {s['messages']} msgs, {s['rate_hz']:.1f} Hz)"


# --------------------------------------------------------------------------- reading
def _read_streams(
    sources: list[Path], o: IngestOptions, progress: Progress
) -> tuple[Any, Any, dict[str, str]]:
    """(vio Trajectory, truth Trajectory, {role: source path})."""
    from qsls.pipeline.ingest.sources.bags import BagSource
    from qsls.pipeline.ingest.sources.base import detect
    from qsls.pipeline.ingest.sources.select import choose
    from qsls.pipeline.ingest.sources.text import read_euroc, read_tum
    from qsls.pipeline.ingest.sources.write import TF

    sources = [Path(s) for s in sources]
    if not sources and (o.vio is None or o.truth is None):
        raise InputError("no input: give a bag (SOURCE...) or both --vio FILE and --truth FILE")
    texts: dict[str, Any] = {}
    bags: dict[Path, BagSource] = {}
    try:
        role_files: dict[str, list[Path]] = {}
        for role, given in (("vio", o.vio), ("truth", o.truth)):
            files = [Path(given)] if given is not None else sources
            role_files[role] = files
            for f in files:
                kind = detect(f)
                if kind in ("tum", "euroc"):
                    if given is None:
                        raise InputError(
                            f"{f}: a text trajectory; pass text files with --vio FILE --truth FILE"
                        )
                    texts[role] = (read_tum if kind == "tum" else read_euroc)(f)
                elif f not in bags:
                    bags[f] = BagSource(f)
        topics = {p: b.topics() for p, b in bags.items()}
        vio_topics = [t for f in role_files["vio"] if f in bags for t in topics[f]]
        truth_topics = [t for f in role_files["truth"] if f in bags for t in topics[f]]
        if "vio" in texts and "truth" in texts:
            return texts["vio"], texts["truth"], {"vio": str(o.vio), "truth": str(o.truth)}
        vio_info = truth_info = None
        if "vio" in texts:
            truth_info = _pick_truth(truth_topics, o)
        elif "truth" in texts:
            vio_info = _pick_vio(vio_topics, o)
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
                where[role] = str(o.vio if role == "vio" else o.truth)
                continue
            frame = o.truth_frame if role == "truth" else None
            wanted.setdefault(info.source, []).append((role, info.topic, frame))
            where[role] = str(info.source)
        for source, reqs in wanted.items():  # one pass per bag for both streams
            got = bags[source].read_many([(t, f) for _, t, f in reqs], fast=fast, progress=progress)
            out.update({role: g for (role, _, _), g in zip(reqs, got, strict=True)})
        return out["vio"], out["truth"], where
    finally:
        for b in bags.values():
            b.close()


def _pick_truth(topics: list[Any], o: IngestOptions) -> Any:
    """The truth topic when the VIO comes from a text file."""
    from qsls.pipeline.ingest.sources.select import POSE_TYPES, TRUTH_TYPES, describe, find_topic

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


def _pick_vio(topics: list[Any], o: IngestOptions) -> Any:
    from qsls.pipeline.ingest.sources.select import POSE_TYPES, choose_vio, find_topic

    if o.vio_topic:
        return find_topic(topics, o.vio_topic, "vio", POSE_TYPES)
    return choose_vio(topics, set())


# --------------------------------------------------------------------------- preparing
def prepare(traj: Any, role: str, source: str, o: IngestOptions) -> Prepared:
    """Stamps, non-finite check, sort, exact-duplicate removal (module docstring, step 2)."""
    t = traj.log_ns if o.stamp == "log" else traj.header_ns
    t = np.asarray(t, dtype=np.int64)
    p, q, v = traj.position, traj.orientation, traj.velocity
    n = len(t)
    name = f"{role} stream {traj.name}"
    if n == 0:
        raise InputError(f"{name} has no messages; check the topic or the file")
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    if v is not None:
        ok &= np.isfinite(v).all(axis=1)
    qn = np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1)
    ok &= qn > 1e-9
    nonfinite = int(n - ok.sum())
    if nonfinite and not o.drop_nonfinite:
        first = int(np.flatnonzero(~ok)[0])
        raise InputError(
            f"{name}: {nonfinite} of {n} messages hold NaN, infinite or zero-quaternion values "
            f"(first is message {first}); fix the log or pass --drop-nonfinite to skip them"
        )
    if nonfinite:
        t, p, q = t[ok], p[ok], q[ok]
        v = v[ok] if v is not None else None
    unsorted = int(np.sum(np.diff(t) < 0))
    order = np.argsort(t, kind="stable")
    t, p, q = t[order], p[order], q[order]
    v = v[order] if v is not None else None
    keep = np.concatenate([[True], np.diff(t) != 0])
    duplicates = int(len(t) - keep.sum())
    t, p, q = t[keep], p[keep], q[keep]
    v = v[keep] if v is not None else None
    if len(t) < 10:
        raise InputError(f"{name}: only {len(t)} usable messages; at least 10 are needed")
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
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
    )


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
        step = float(np.median(np.diff(s.t_ns))) * 1e-9
        if step > o.max_gap:
            raise InputError(
                f"the {s.role} stream {s.topic} has one sample every {step:.3g} s "
                f"({s.rate_hz:.3g} Hz), longer than --max-gap {o.max_gap:g} s, so no point "
                f"could be interpolated; raise --max-gap above {step:.3g} s (e.g. "
                f"{2 * step:.2g}) if interpolating across {step:.3g} s is acceptable"
            )


def _interp(
    grid: np.ndarray, t: np.ndarray, values: np.ndarray, max_gap_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation at ``grid``; mask of grid points not bracketing a long gap."""
    i = np.searchsorted(t, grid, side="right") - 1
    inside = (i >= 0) & (i < len(t))
    i = np.clip(i, 0, len(t) - 1)
    exact = inside & (t[i] == grid)
    j = np.clip(i + 1, 0, len(t) - 1)
    bracket = inside & (i + 1 < len(t)) & ((t[j] - t[i]) <= max_gap_ns)
    valid = exact | bracket
    x = (grid - t[0]).astype(float)
    tt = (t - t[0]).astype(float)
    out = np.column_stack([np.interp(x, tt, values[:, k]) for k in range(values.shape[1])])
    return out, valid


def _gaps(s: Prepared, lo: int, hi: int, max_gap_ns: int, t_first: int) -> list[dict[str, Any]]:
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


def _tum_text(t_ns: np.ndarray, p: np.ndarray, q: np.ndarray) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw (VIO clock, truth frame; written by qsls ingest)"]
    for k in range(len(t_ns)):
        sec, ns = divmod(int(t_ns[k]), 1_000_000_000)
        vals = " ".join(f"{x:.9f}" for x in (*p[k], *q[k]))
        lines.append(f"{sec}.{ns:09d} {vals}")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- entry point
def ingest(
    sources: list[Path],
    options: IngestOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> IngestResult:
    """Read, synchronize, align and resample one flight into ``out`` (module docstring).

    BLAS runs one thread meanwhile (``threadpoolctl``, process-wide, the setting before is
    restored): the input hash has the other core. Ingests in several threads of one process
    at once are not supported (qsls runs them one after another, or in processes): the
    last to leave could keep the limit.
    """
    from concurrent.futures import ThreadPoolExecutor

    from qsls.pipeline.core.artifacts import check_output, prime_hashes

    o = options
    out = Path(out)
    check_output(out, force)  # fail before the (possibly long) reading
    inputs = [
        Path(p)
        for p in dict.fromkeys([*map(str, sources), *[str(x) for x in (o.vio, o.truth) if x]])
    ]
    # Hash the inputs for the manifest while the bags are read (hashlib releases the GIL):
    # on an indexed bag holding camera images the hash of every byte, not the read, is the
    # longest part. It gets the second core to itself: OpenBLAS's workers keep spinning
    # after each threaded call and took that core from it (611 MB MCAP with images:
    # 0.50 -> 0.45 s; more BLAS threads gain nothing on these sizes).
    from threadpoolctl import threadpool_limits

    hasher = ThreadPoolExecutor(max_workers=1)
    with threadpool_limits(limits=1, user_api="blas"):
        hashed = hasher.submit(prime_hashes, [p for p in inputs if p.exists()])
        try:
            return _ingest([Path(p) for p in sources], inputs, o, out, force, progress, hashed)
        finally:
            hasher.shutdown(wait=True)


def _clock_offset(vio: Prepared, truth: Prepared, o: IngestOptions) -> tuple[float, dict[str, Any]]:
    """``time_offset_s`` (added to truth stamps, DESIGN.md Conventions) and how it was found:
    given, or the minimum over the offset of the aligned mismatch (:mod:`timesync`)."""
    from qsls.pipeline.ingest.timesync import estimate_offset

    def overlap_s(tau_ns: int) -> float:
        return (
            min(vio.t_ns[-1], truth.t_ns[-1] + tau_ns) - max(vio.t_ns[0], truth.t_ns[0] + tau_ns)
        ) * 1e-9

    def span(s: Prepared, shift: int = 0) -> str:
        return f"{(s.t_ns[0] + shift) * 1e-9:.3f}..{(s.t_ns[-1] + shift) * 1e-9:.3f} s"

    given = o.time_offset != "auto"
    tau_ns0 = round(float(o.time_offset) * 1e9) if given else 0
    ov = overlap_s(tau_ns0)
    if ov < o.min_overlap:
        what = (
            "do not overlap" if ov <= 0 else f"overlap only {ov:.2f} s (need {o.min_overlap:g} s)"
        )
        hint = "check the offset" if given else "give --time-offset SECONDS if the clocks differ"
        raise InputError(
            f"the VIO ({span(vio)}) and truth ({span(truth, tau_ns0)}) streams {what} in time; "
            f"check that both come from the same flight and --stamp {o.stamp}, or {hint}"
        )
    if given:
        tau = float(o.time_offset)
        offset_info: dict[str, Any] = {"method": "given"}
    else:
        est = estimate_offset(
            vio.t_ns, vio.position, truth.t_ns, truth.position,
            vio_q=vio.orientation, truth_q=truth.orientation,
            method=o.align, max_offset_s=o.max_time_offset, min_overlap_s=o.min_overlap,
        )  # fmt: skip
        spread = float(np.sqrt(np.mean(np.sum((truth.position - truth.position.mean(0)) ** 2, 1))))
        if est.rms_m > 0.5 * spread:
            raise InputError(
                f"the streams do not match at any clock offset within +-{est.search_s:.2f} s "
                f"(best aligned position RMS {est.rms_m:.3g} m against a trajectory spread of "
                f"{spread:.3g} m); check the topics and --stamp, raise --max-time-offset, "
                "or give --time-offset SECONDS"
            )
        if est.at_edge:
            raise InputError(
                f"the clock offset estimate hit the edge of the search range (+-{est.search_s:.2f} s); "
                "raise --max-time-offset or give --time-offset SECONDS"
            )
        tau = est.offset_s
        offset_info = {
            "method": (
                f"auto: log of the aligned ({o.align}) position mean square plus log of the "
                "body-frame gravity direction mismatch, minimized over the offset"
                if est.uses_attitude
                else f"auto: aligned ({o.align}) position RMS minimized over the offset"
            ),
            "rms_m": est.rms_m,
            **({"tilt_rms": est.tilt_rms} if est.uses_attitude else {}),
            "samples": est.samples,
            "search_s": est.search_s,
        }
    return tau, offset_info


def _velocities(
    vio: Prepared, truth: Prepared, o: IngestOptions
) -> tuple[np.ndarray, str, np.ndarray, str]:
    """Velocities in each stream's own world frame, and where each came from: the VIO's
    message twist (rotated from the body frame if asked) or, lacking one, the smoothing
    differentiator on positions; the truth's always from the differentiator."""
    from qsls.pipeline.core.rotations import body_to_world
    from qsls.pipeline.ingest.align import differentiate

    gap_ns = round(o.max_gap * 1e9)
    win = o.velocity_window
    if vio.velocity is not None:
        if o.vio_velocity_frame == "body":
            v_vio = body_to_world(vio.orientation, vio.velocity)
            vio_vsrc = "message twist, body (child) frame rotated to world by the VIO orientation"
        else:
            v_vio = vio.velocity
            vio_vsrc = "message twist, world frame as published"
    else:
        v_vio = differentiate(vio.t_ns, vio.position, win, gap_ns)
        vio_vsrc = (
            f"smoothing differentiator (Savitzky-Golay quadratic, {win:g} s window) on positions"
        )
    v_truth = differentiate(truth.t_ns, truth.position, win, gap_ns)
    truth_vsrc = (
        f"smoothing differentiator (Savitzky-Golay quadratic, {win:g} s window) on positions"
    )

    return v_vio, vio_vsrc, v_truth, truth_vsrc


def _ingest(
    sources: list[Path],
    inputs: list[Path],
    o: IngestOptions,
    out: Path,
    force: bool,
    progress: Progress,
    hashed: Any,
) -> IngestResult:
    from qsls.pipeline.core.artifacts import StageWriter, parquet_bytes
    from qsls.pipeline.core.rotations import matrix_to_quat, quat_to_matrix
    from qsls.pipeline.ingest.align import fit_alignment
    from qsls.pipeline.ingest.flight import FLIGHT_FILE, flight_table

    vio_t, truth_t, where = _read_streams(sources, o, progress)
    vio = prepare(vio_t, "vio", where["vio"], o)
    truth = prepare(truth_t, "truth", where["truth"], o)
    check_streams(vio, truth, o)
    gap_ns = round(o.max_gap * 1e9)
    tau, offset_info = _clock_offset(vio, truth, o)
    tau_ns = round(tau * 1e9)
    tt = truth.t_ns + tau_ns  # truth on the VIO clock

    v_vio, vio_vsrc, v_truth, truth_vsrc = _velocities(vio, truth, o)

    # ---- alignment on time-matched pairs (VIO stamps inside the truth's coverage)
    lo, hi = max(vio.t_ns[0], tt[0]), min(vio.t_ns[-1], tt[-1])
    sel = (vio.t_ns >= lo) & (vio.t_ns <= hi)
    p_truth_at_vio, ok = _interp(vio.t_ns[sel], tt, truth.position, gap_ns)
    if ok.sum() < 10:
        raise InputError(
            f"only {int(ok.sum())} VIO samples fall where the truth stream has data; "
            "check the topics, --stamp and --time-offset"
        )
    al = fit_alignment(vio.position[sel][ok], p_truth_at_vio[ok], o.align)
    p_vio = al.apply(vio.position)
    v_vio = al.rotate(v_vio)

    # ---- common grid
    dt_ns = round(o.dt * 1e9)
    start = -(-lo // dt_ns) * dt_ns
    grid = np.arange(start, hi + 1, dt_ns, dtype=np.int64)
    yv, ok_v = _interp(grid, vio.t_ns, np.hstack([p_vio, v_vio]), gap_ns)
    xv, ok_t = _interp(grid, tt, np.hstack([truth.position, v_truth]), gap_ns)
    valid = ok_v & ok_t
    if valid.sum() < 10:
        raise InputError(
            f"only {int(valid.sum())} samples of dt={o.dt:g} s where both streams have data; "
            "the streams overlap too little (check --max-gap, --dt and the topics)"
        )
    stamps = grid[valid]
    table = flight_table(stamps, xv[valid], yv[valid])
    err = yv[valid] - xv[valid]
    rms_p = float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))))
    rms_v = float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1))))
    truth_vio_clock = dataclasses.replace(truth, t_ns=tt)
    gaps = _gaps(vio, lo, hi, gap_ns, int(stamps[0])) + _gaps(
        truth_vio_clock, lo, hi, gap_ns, int(stamps[0])
    )
    streams = {"vio": vio.describe(), "truth": truth.describe()}
    streams["vio"]["stamp"] = streams["truth"]["stamp"] = o.stamp
    results: dict[str, Any] = {
        "samples": table.num_rows,
        "dropped_grid_samples": int(len(grid) - valid.sum()),
        "dt": o.dt,
        "time_offset_s": tau,
        "time_offset": offset_info,
        "alignment": al.as_dict(),
        "rms_position_m": rms_p,
        "rms_velocity_mps": rms_v,
        "velocity_source": {"vio": vio_vsrc, "truth": truth_vsrc},
        "duplicates_dropped": {"vio": vio.duplicates, "truth": truth.duplicates},
        "unsorted_stamps": {"vio": vio.unsorted, "truth": truth.unsorted},
        "nonfinite_dropped": {"vio": vio.nonfinite, "truth": truth.nonfinite},
        "gaps": gaps,
        "streams": streams,
    }
    # the files are serialized while the input hash may still run; the writer needs it
    files = {FLIGHT_FILE: parquet_bytes(table)}
    if o.export_tum:
        q_vio = matrix_to_quat(al.rotation[None] @ quat_to_matrix(vio.orientation))
        files["vio_aligned.tum"] = _tum_text(vio.t_ns, p_vio, q_vio).encode()
        files["truth.tum"] = _tum_text(tt, truth.position, truth.orientation).encode()
    hashed.result()
    with StageWriter(out, STAGE, options=o, inputs=inputs, force=force) as w:
        for name, data in files.items():
            w.write_bytes(name, data)
        w.results.update(results)
    return IngestResult(out, table.num_rows, tau, al.as_dict(), rms_p, rms_v, streams, gaps)
