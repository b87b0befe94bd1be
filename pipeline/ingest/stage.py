"""``qsls ingest``: VIO and motion-capture streams onto one clock, one frame and one grid.

Steps (docs/ingest.md#steps); the stage reads (step 1) and writes (the folder, its
manifest); steps 2 to 7 are the pure core, :func:`qsls.pipeline.ingest.assemble.flight_from_streams`,
objects in and objects out:

1. Read the two streams (:mod:`qsls.pipeline.ingest.streams`, through
   :mod:`qsls.pipeline.ingest.sources`): a VIO topic (``nav_msgs/Odometry``) and a truth
   topic (pose types, or a TF transform) from one or two bags, or text files (TUM, EuRoC
   csv) given with ``vio`` / ``truth``.
2. Stamps (:func:`qsls.pipeline.ingest.streams.prepare`): header or log time; sort by
   stamp, drop exact duplicate stamps (the first message of a stamp is kept), count both.
   Non-finite values stop the stage (or are dropped and counted with ``drop_nonfinite``).
   A truth jump no vehicle could fly (``max_truth_accel``) becomes a gap, counted as
   ``discontinuities``.
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
import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.core.artifacts import StageWriter, check_output, parquet_bytes, prime_hashes
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.rotations import body_to_world
from qsls.pipeline.core.ticks import TICKS_FILE
from qsls.pipeline.ingest.assemble import flight_from_streams
from qsls.pipeline.ingest.flight import FLIGHT_FILE
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.plausible import ingest_warnings
from qsls.pipeline.ingest.sources.base import Trajectory, detect
from qsls.pipeline.ingest.sources.text.writer import tum_text
from qsls.pipeline.ingest.streams import read_streams
from qsls.pipeline.ingest.ticks import RecordedTicks, recorded_ticks, stated_setpoints

STAGE = "ingest"
TUM_FILES = {"vio": "vio_aligned.tum", "truth": "truth.tum"}
"""The files of ``export_tum``: both trajectories aligned, VIO clock, truth frame."""


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
    warnings: tuple[str, ...] = ()
    """What looks wrong in the flight (:mod:`qsls.pipeline.ingest.plausible`; the CLI prints
    each as ``warning:``)."""

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


FRAME_TOLERANCE = (1.0, 0.05, 0.005)
"""How far the estimate's frame and clock may be from the truth's for a tick log: yaw (deg),
translation (m), clock (s). Within them the alignment finds noise, not another frame."""


def one_frame(results: dict[str, Any]) -> None:
    """Refuse a tick log whose estimate and truth are not in one frame on one clock: the tick
    log is the log's own (docs/vehicle.md), so ingest's alignment (``p' = R p + t``) and clock
    offset must find nothing beyond :data:`FRAME_TOLERANCE`."""
    a = results["alignment"]
    yaw = abs(np.degrees(float(a.get("yaw_rad", 0.0))))
    rot = np.asarray(a.get("rotation", np.eye(3)), dtype=float)
    tilt = np.degrees(np.arccos(np.clip(rot[2, 2], -1.0, 1.0)))
    shift = float(np.linalg.norm(a.get("translation", (0.0, 0.0, 0.0))))
    tau = abs(float(results["time_offset_s"]))
    y_max, t_max, c_max = FRAME_TOLERANCE
    if max(yaw, tilt) > y_max or shift > t_max or tau > c_max:
        raise InputError(
            "--mass: ingest without --mass, or record the estimate and the truth in one "
            f"frame on one clock; the estimate's frame is {max(yaw, tilt):.2f} deg and "
            f"{shift:.3f} m off the truth's and its clock {tau:.4f} s (a tick log allows "
            f"{y_max:g} deg, {t_max:g} m, {c_max:g} s)"
        )


def one_clock(vio: Trajectory, truth: Trajectory) -> bool:
    """Whether both streams come from one PX4 ULog: PX4 stamped both on its one clock, so the
    offset between them is 0 (``time_offset: auto`` is not estimated)."""
    src = Path(vio.source)
    return (
        bool(vio.source)
        and vio.source == truth.source
        and src.is_file()
        and (detect(src) == "ulog")
    )


def commanded_ticks(vio: Trajectory, truth: Trajectory, o: IngestOptions) -> RecordedTicks:
    """The tick log of a flight whose log holds the controller's commands (``o.mass`` given):
    read from the estimate's log (:mod:`qsls.pipeline.ingest.ticks`):

    - a PX4 ULog: its attitude and trajectory setpoints, its hover thrust, the controller's
      identity where the log stamps it;
    - a bag recorded with mavros (docs/vehicle.md#what-to-log,
      :mod:`qsls.pipeline.ingest.sources.mavros`): the attitude setpoints
      (``--commands-topic``, default ``/mavros/setpoint_raw/target_attitude``, else
      ``/mavros/setpoint_raw/attitude``) and the reference (``--reference-topic``, default
      ``/qsls/reference``, else ``/mavros/setpoint_raw/local``). A bag states no hover thrust
      (``--hover-thrust`` required) and no identity. The estimate's twist goes to the world
      frame by ``vio_velocity_frame`` (the controller read a world velocity); the truth's
      twist is not used (its positions are differentiated, as ingest's are).
    """
    assert o.mass is not None
    src = Path(vio.source)
    kind = detect(src) if src.exists() else ""
    if kind in ("ros1", "rosbag2", "db3", "mcap"):
        # deferred: the commands' reader loads only for a log that holds commands
        from qsls.pipeline.ingest.sources import mavros

        if o.hover_thrust is None:
            raise InputError(
                f"--mass on a bag ({src.name}): a bag states no hover thrust; give the "
                "vehicle's with --hover-thrust (PX4's MPC_THR_HOVER or hover_thrust_estimate, "
                "in the commands topic's units: target_attitude's thrust is what PX4 got)"
            )
        cmd = o.commands_topic
        ref = o.reference_topic
        cmd = mavros.first_topic(src, [cmd] if cmd else mavros.COMMAND_TOPICS, "commands")
        commands = mavros.read_bag_commands(src, cmd)
        if o.reference is not None:
            setpoints, ref = (
                stated_setpoints(o.reference, commands.t_ns, o.feedforward, float(o.mass or 1.0)),
                o.reference,
            )
        else:
            ref = mavros.first_topic(src, [ref] if ref else mavros.REFERENCE_TOPICS, "reference")
            setpoints = mavros.read_bag_setpoints(src, ref)
        if vio.velocity is not None and o.vio_velocity_frame == "body":
            vio = dataclasses.replace(vio, velocity=body_to_world(vio.orientation, vio.velocity))
        made = recorded_ticks(
            vio, dataclasses.replace(truth, velocity=None), commands, setpoints, o.mass,
            hover_thrust=o.hover_thrust, max_gap_s=o.max_gap,
        )  # fmt: skip
        facts = {**made.facts, "stamps": {}, "log": src.name, "commands_topic": cmd,
                 "reference_topic": ref}  # fmt: skip
        return RecordedTicks(made.log, facts)
    if kind != "ulog":
        raise InputError(
            f"--mass: the controller's commands are read from a PX4 ULog or a bag recorded "
            f"with mavros; {src} is neither (drop --mass to ingest the estimate and the truth "
            "alone)"
        )
    # deferred: pyulog loads only for a log that holds commands
    from qsls.pipeline.ingest.sources.ulog.reader import read_commands, read_setpoints, ulog_info

    commands = read_commands(src)
    setpoints = (stated_setpoints(o.reference, commands.t_ns, o.feedforward, float(o.mass or 1.0)) if o.reference is not None
                 else read_setpoints(src))  # fmt: skip
    made = recorded_ticks(
        vio, truth, commands, setpoints, o.mass, hover_thrust=o.hover_thrust, max_gap_s=o.max_gap
    )
    info = ulog_info(src)
    stamps = {k: v for k, v in (info.get("info") or {}).items() if str(k).startswith("qsls_")}
    facts = {**made.facts, "stamps": stamps, "log": src.name, "frame": "px4 local (NED as ENU)",
             "reference_source": o.reference or "trajectory_setpoint"}  # fmt: skip
    return RecordedTicks(made.log, facts)


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
        # then the parquet writer's import (pyarrow, 40-60 ms of CPU), which the end of the
        # stage needs, while the main thread waits on the reading (SQLite and the
        # decompressors run without the GIL)
        hasher.submit(importlib.import_module, "pyarrow.parquet")
        try:
            return _ingest([Path(p) for p in sources], inputs, o, out, force, progress, hashed)
        finally:
            hasher.shutdown(wait=True)


def _ingest(
    sources: list[Path],
    inputs: list[Path],
    o: IngestOptions,
    out: Path,
    force: bool,
    progress: Progress,
    hashed: Any,
) -> IngestResult:
    streams = read_streams(sources, o, progress)
    ticks = commanded_ticks(streams[0], streams[1], o) if o.mass is not None else None
    one = one_clock(streams[0], streams[1]) and o.time_offset == "auto"
    core = o.model_copy(update={"time_offset": 0.0}) if one else o
    # the core gets the only references to the streams: it drops their arrays once used
    flight = flight_from_streams(streams.pop(0), streams.pop(), core)
    files = {TUM_FILES[role]: tum_text(*track).encode() for role, track in flight.tracks.items()}
    # the files are serialized while the input hash may still run; the writer needs it
    files = {FLIGHT_FILE: parquet_bytes(flight.table), **files}
    if ticks is not None:
        files[TICKS_FILE] = parquet_bytes(ticks.log.frame())
    hashed.result()
    r = dict(flight.results)
    warnings = ingest_warnings(flight.table, r)
    if warnings:  # only then: a flight without them keeps its manifest as before
        r["warnings"] = list(warnings)
    if ticks is not None:
        one_frame(r)
    if one:
        r["time_offset"] = {"method": "one clock: both streams of one PX4 ULog, stamped by PX4"}
    if ticks is not None:
        r["ticks"] = ticks.facts
    with StageWriter(out, STAGE, options=o, inputs=inputs, force=force) as w:
        for name, data in files.items():
            w.write_bytes(name, data)
        w.results.update(r)
    return IngestResult(
        out, flight.samples, r["time_offset_s"], r["alignment"], r["rms_position_m"],
        r["rms_velocity_mps"], r["streams"], r["gaps"], warnings,
    )  # fmt: skip
