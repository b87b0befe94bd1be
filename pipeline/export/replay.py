"""``qsls replay CONTROLLER_DIR SOURCE --vio-topic T --reference SPEC --out OUT.mcap``.

A dry run before a real flight: a recorded VIO stream goes through the exported controller
at its ``dt``, and what it would have commanded is written as a ROS 2 MCAP
(:mod:`qsls.pipeline.export.rosout`).

1. The controller folder is verified and gated as by ``qsls export`` (certified only, unless
   ``allow_uncertified``); the controller that runs is the exported code itself: the stdlib
   Python module (``backend: python``) or the C compiled with the system compiler and loaded
   with ctypes (``backend: c``), ``u`` and the attitude conversion both.
2. The VIO stream is read by ingest's reader (any source ``qsls ingest`` reads,
   :func:`qsls.pipeline.ingest.streams.read_vio_stream`; the topic chosen as ingest chooses
   it), stamps prepared as ingest does (:func:`qsls.pipeline.ingest.streams.prepare`),
   velocity by ingest's step (:func:`qsls.pipeline.ingest.velocity.vio_velocity`: rotated to
   the VIO world frame, ``v_w = R(q) v_b``, or differentiated when the stream has none).
3. Resampled as ingest does: linear interpolation on ingest's grid ``t_k = t_0 + k dt``
   (:func:`qsls.pipeline.ingest.resample.time_grid`; ``t_0`` the first multiple of ``dt``
   in the stream); ticks between two samples further apart than
   ``max_gap`` are dropped and the gaps listed. The controller is reset at the start of
   each gap-free segment (its memory would otherwise hold samples from before the gap).
4. ``y - r`` with the reference ``r`` (:class:`qsls.pipeline.core.references.Reference`,
   given as ``KIND[:key=value,...]`` or a YAML file; its time is 0 at the first tick plus
   ``reference_t0``), the VIO put into the reference's frame first (:func:`reference_frame`:
   a 4-DoF fit of the recording onto the reference, a given transform, or none; a large
   first deviation or tilt is a warning), ``u = K (y - r)``, and
   ``pitch, roll, thrust = hover + feedforward + u`` -> thrust and quaternion.
5. Command limits: largest tilt, thrust range against hover ``m g``, the fraction of ticks
   with tilt beyond ``max_tilt_deg`` and with thrust outside ``thrust_band`` (times hover).
6. The premise monitor of the exported code (docs/monitor.md): the ticks where it would have
   tripped (the measurement proves the certificate's premise broken), by kind, the first,
   and each test in words, with its channel and how long it held (``disturbance above eps_w
   on vz for 2.3 s (from 1.7 s)``, :func:`qsls.pipeline.control.monitor.trip_summary`);
   beside it, when the VIO recorded covariances (docs/ingest.md#covariances), its own
   position uncertainty: ``sigma_k = sqrt(max_i var_i,k)`` over the position axes ``i``,
   its median and largest value over the stream (the recording has no truth, so no NEES:
   ``qsls evaluate`` gives that on an ingested flight, docs/evaluation.md).
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.monitor import (
    COUNT,
    PREMISE_BITS,
    TRIP,
    innovation_of,
    monitor_of,
    trip_summary,
)
from qsls.pipeline.core.artifacts import refuse_overlap, sha256_path
from qsls.pipeline.core.config import read_yaml, validate
from qsls.pipeline.core.errors import ConfigError, InputError, OutputExistsError
from qsls.pipeline.core.locks import check_writable, make_parent, unwritable
from qsls.pipeline.core.plant import GRAVITY, NX, Plant, feedforward_acceleration
from qsls.pipeline.core.references import Reference, ReferenceOptions, parse_reference
from qsls.pipeline.core.rotations import rot_z
from qsls.pipeline.core.units import NS
from qsls.pipeline.export.attitude import (
    AttitudeLimits,
    absolute_input,
    demanded_force,
    limited,
    quat_tilt_rad,
)
from qsls.pipeline.export.bank import INPUT_REFUSED, check_exportable, export_bank, facts
from qsls.pipeline.export.c import c_files
from qsls.pipeline.export.cbuild import CController, compile_shared
from qsls.pipeline.export.options import ReplayOptions
from qsls.pipeline.export.python import load_module, module
from qsls.pipeline.export.rosout import Ticks, Topics, write_mcap
from qsls.pipeline.export.statement import CHANNELS
from qsls.pipeline.ingest.align import Alignment, fit_alignment, segments
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.resample import time_grid
from qsls.pipeline.ingest.sources.msgtypes import EUROC, TUM
from qsls.pipeline.ingest.streams import gaps, interp, prepare, read_vio_stream
from qsls.pipeline.ingest.velocity import vio_velocity


@dataclass(frozen=True)
class ReplayResult:
    out: Path
    report: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        r, lim = self.report, self.report["limits"]
        gaps = r["gaps"]
        return {
            "output": str(self.out),
            "controller": f"{r['controller']} ({r['status']}, {r['backend']})",
            "VIO": f"{r['vio']['topic']} ({r['vio']['messages']} msgs, {r['vio']['rate_hz']} Hz)",
            "ticks": f"{r['ticks']} at dt = {r['dt']} s in {r['segments']} segment(s)",
            "VIO -> reference frame": _alignment_text(r["alignment"]),
            "first deviation (m)": r["first_deviation_m"],
            "largest tilt (deg)": lim["max_tilt_deg"],
            "thrust range / hover": f"{lim['thrust_min_ratio']:.3f} .. {lim['thrust_max_ratio']:.3f}",
            f"ticks with tilt > {lim['tilt_limit_deg']:g} deg": f"{lim['pct_tilt_exceeded']:.1f} %",
            f"ticks with thrust outside {lim['thrust_band']}x hover": (
                f"{lim['pct_thrust_outside']:.1f} %"
            ),
            f"ticks limited by the export ({lim['export_limits']})": f"{lim['pct_limited']:.1f} %",
            "premise monitor (docs/monitor.md)": _monitor_text(r["monitor"]),
            **(
                {"VIO's own position sigma (m)": _sigma_text(r["vio_uncertainty"])}
                if "vio_uncertainty" in r
                else {}
            ),
            "gaps": (
                "none"
                if not gaps
                else "; ".join(f"{g['t_start_s']:.3f} s (+{g['duration_s']:.3f} s)" for g in gaps)
            ),
        }


def _monitor_text(m: dict[str, Any]) -> str:
    if not m["active"]:
        return "off (no guarantee to monitor)"
    if not m["ticks_tripped"]:
        return "no trip (one-sided: this proves nothing about the premise)"
    inn = m.get("innovation") or {}
    proof = inn.get("mode") != "calibrated" or m["envelope_ticks"] or m["outlier_count_ticks"]
    head = (
        "premise broken"
        if proof
        else f"calibrated monitor tripped (false-trip rate {inn.get('false_trip_rate', 0):g} "
        "per flight: not a proof)"
    )
    text = (
        f"{head}: {m['ticks_tripped']} ticks tripped, the first at "
        f"{m['first_trip_t_s']:.2f} s (envelope {m['envelope_ticks']}, outlier count "
        f"{m['outlier_count_ticks']})"
    )
    if m.get("summary"):
        text += ": " + "; ".join(m["summary"])
    return text


def _sigma_text(u: dict[str, Any]) -> str:
    s = u["position_sigma_m"]
    return f"median {s['median']:.4g}, largest {s['max']:.4g} (its largest axis, as recorded)"


def vio_uncertainty(vio: Any) -> dict[str, Any] | None:
    """The VIO's recorded position uncertainty (module docstring, step 6); None without
    covariances."""
    if vio.variance is None:
        return None
    sigma = np.sqrt(np.clip(vio.variance[:, :3], 0.0, None).max(axis=1))
    return {"position_sigma_m": {"median": float(np.median(sigma)), "max": float(sigma.max())}}


def _alignment_text(al: dict[str, Any]) -> str:
    t = ", ".join(f"{v:.3f}" for v in al["translation"])
    return f"{al['method']}: yaw {al['yaw_deg']:.2f} deg, offset [{t}] m"


# --------------------------------------------------------------------------- inputs
def reference_options(spec: str) -> ReferenceOptions:
    """``--reference``: a reference in the one text form
    (:func:`~qsls.pipeline.core.references.parse_reference`, e.g.
    ``circle:radius=1.5,period=6,center=[0.5,0]``) or a YAML file of its options."""
    path = Path(spec)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        raw = read_yaml(path)
        return validate(ReferenceOptions, raw.get("reference", raw), str(path))
    return parse_reference(spec, "--reference")


def read_vio(source: Path, o: ReplayOptions) -> tuple[Any, np.ndarray]:
    """The prepared VIO stream (ingest's ``Prepared``) and its world-frame velocity (n, 3):
    ingest's reader (:func:`~qsls.pipeline.ingest.streams.read_vio_stream`), stamps
    (:func:`~qsls.pipeline.ingest.streams.prepare`) and velocity step
    (:func:`~qsls.pipeline.ingest.velocity.vio_velocity`, without its twist-frame check)."""
    source = Path(source)
    if not source.exists():
        raise InputError(f"{source}: no such file or folder")
    traj = read_vio_stream(source, o.vio_topic)
    # EuRoC's velocity is the dataset's own, world frame
    frame = "world" if traj.msgtype in (TUM, EUROC) else o.vio_velocity_frame
    io = IngestOptions(stamp=o.stamp, drop_nonfinite=o.drop_nonfinite, vio_velocity_frame=frame)
    vio = prepare(traj, "vio", str(source), io)
    del traj
    v, _ = vio_velocity(vio, frame, o.velocity_window, o.max_gap, check_frame=False)
    return vio, v


def resample(
    vio: Any, v: np.ndarray, dt: float, max_gap: float
) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]], list[slice]]:
    """Ingest's resampling of ``[p, v]`` onto its grid ``t_0 + k dt``
    (:func:`~qsls.pipeline.ingest.resample.time_grid`): stamps, values, gaps, segments."""
    dt_ns, gap_ns = round(dt * NS), round(max_gap * NS)
    lo, hi = int(vio.t_ns[0]), int(vio.t_ns[-1])
    grid = time_grid(lo, hi, dt_ns)
    values, valid = interp(grid, vio.t_ns, np.hstack([vio.position, v]), gap_ns)
    if valid.sum() < 2:
        raise InputError(
            f"the VIO stream gives only {int(valid.sum())} ticks of dt = {dt:g} s; "
            "nothing to replay (check the topic and --max-gap)"
        )
    stamps = grid[valid]
    found_gaps = gaps(vio, lo, hi, gap_ns, int(stamps[0]))
    # a run of valid grid points is a segment: consecutive kept stamps exactly dt apart
    return stamps, values[valid], found_gaps, segments(stamps, dt_ns)


def reference_frame(p_vio: np.ndarray, p_ref: np.ndarray, o: ReplayOptions) -> Any:
    """The transform putting VIO positions into the reference's frame (ingest's
    :class:`~qsls.pipeline.ingest.align.Alignment`): the given ``vio_to_reference``, or the
    ``align`` fit of the whole recording onto the reference at the same ticks (a reference
    without horizontal motion, hover, fixes no yaw: only the offset is fitted)."""
    if o.vio_to_reference is not None:
        x, y, z, yaw = o.vio_to_reference
        return Alignment("given", rot_z(np.radians(yaw)), np.array([x, y, z]))
    return fit_alignment(p_vio, p_ref, o.align)


def warnings(report: dict[str, Any], o: ReplayOptions) -> list[str]:
    """Loud lines for a dry run that starts far from its reference or beyond the tilt limit."""
    lim, dev = report["limits"], report["first_deviation_m"]
    if dev <= o.warn_deviation_m and lim["first_tilt_deg"] <= o.max_tilt_deg:
        return []
    return [
        f"the first command tilts {lim['first_tilt_deg']:.1f} deg (the controller asks "
        f"{lim['first_demanded_tilt_deg']:.1f} deg), {dev:.2f} m from the "
        f"reference (alignment: {report['alignment']['method']}); the VIO and the reference "
        "must share a frame: check --align / --vio-to-reference, --reference and --reference-t0 "
        "before flying this"
    ]


# --------------------------------------------------------------------------- controller
def exported_runtime(
    cdir: Any, backend: str, workdir: Path, limits: AttitudeLimits = AttitudeLimits()
) -> tuple[Any, Any]:
    """``(controller, attitude)`` of the exported code: ``step(y) -> u``, ``(u, acc) -> (T, q)``."""
    bank, fx = export_bank(cdir), facts(cdir, limits)
    if backend == "python":
        mod: Any = load_module(module(bank, fx))
        return mod.Controller(), mod.attitude

    for name, text in c_files(bank, fx, "qsls_ctrl", "double").items():
        (workdir / name).write_text(text)
    lib = compile_shared(workdir / "qsls_ctrl.c", workdir / "qsls_ctrl.so")
    c = CController(lib, dt=cdir.controller.dt, name=cdir.name)
    return c, c.attitude


def command_ticks(
    ctrl: Any,
    attitude: Any,
    stamps: np.ndarray,
    y_dev: np.ndarray,
    acc: np.ndarray,
    parts: list[slice],
    mass: float,
    hover_thrust: float,
) -> tuple[Ticks, np.ndarray]:
    """Run the controller over each segment (reset at its start) and convert to commands;
    also the monitor's bits per tick (docs/monitor.md)."""
    n = len(stamps)
    u = np.zeros((n, 3))
    thrust, q = np.zeros(n), np.zeros((n, 4))
    flags = np.zeros(n, dtype=int)
    for sl in parts:
        ctrl.reset()
        for k in range(sl.start, sl.stop):
            u[k] = np.asarray(ctrl.step(y_dev[k].tolist()), dtype=float)
            flags[k] = int(ctrl.flags)
            th, qq = attitude(u[k].tolist(), acc[k].tolist())
            thrust[k], q[k] = th, qq
    u_abs = absolute_input(u, acc, mass)
    ticks = Ticks(stamps, y_dev, u, u_abs, thrust, q, hover_thrust * thrust / (mass * GRAVITY))
    return ticks, flags


MAX_LISTED_TRIPS = 100
"""The report lists the times of at most this many tripped ticks (it counts all of them)."""


ENVELOPE_BIT, OUTLIER_BIT = 1, 2
"""The monitor's trip bits (docs/monitor.md); ``INPUT_REFUSED`` (4) is the step's refusal of a
non-finite measurement, counted apart."""


def monitor_report(cdir: Any, flags: np.ndarray, stamps: np.ndarray) -> dict[str, Any]:
    """Where the exported premise monitor would have tripped (docs/monitor.md): the ticks, by
    kind (the envelope's, its outlier count's, the innovation monitor's), the first one's time,
    each test in words (``summary``: test, channel, seconds held, from when), and the
    thresholds it checked. One-sided: a trip proves the certificate's premise broken on this
    recording; no trip proves nothing."""
    spec, inno = monitor_of(cdir), innovation_of(cdir)
    t = (stamps - stamps[0]) / NS
    hit = np.flatnonzero(flags & PREMISE_BITS)  # INPUT_REFUSED is no trip
    kinds = {TRIP: "envelope", COUNT: "outlier count"}
    dt = float(cdir.controller.dt)
    return {
        "active": spec.active or inno.active,
        "ticks_tripped": len(hit),
        "envelope_ticks": int(np.count_nonzero(flags & 1)),
        "outlier_count_ticks": int(np.count_nonzero(flags & 2)),
        "refused_ticks": int(np.count_nonzero(flags & INPUT_REFUSED)),
        "first_trip_t_s": float(t[hit[0]]) if len(hit) else None,
        "trip_t_s": [float(x) for x in t[hit[:MAX_LISTED_TRIPS]]],
        "thresholds": {
            CHANNELS[i]: {"threshold": spec.threshold[i], "kind": kinds[k]}
            for i, k in enumerate(spec.kind)
            if k in kinds
        },
        "outliers_allowed": {"m": spec.m, "window": spec.window},
        "innovation_ticks": int(
            np.count_nonzero(flags & (PREMISE_BITS & ~(ENVELOPE_BIT | OUTLIER_BIT)))
        ),
        "summary": trip_summary(flags & PREMISE_BITS, dt, t),
        "innovation": {
            "mode": inno.mode,
            "false_trip_rate": inno.false_trip_rate,
            "windows": list(inno.windows),
            "thresholds": {
                CHANNELS[c]: [inno.threshold[w][c] for w in range(len(inno.windows))]
                for c in inno.live_channels()
            },
            "outlier_thresholds": {
                CHANNELS[c]: v for c, v in enumerate(inno.outlier_threshold) if v > 0
            },
        },
    }


def limits(ticks: Ticks, mass: float, o: ReplayOptions) -> dict[str, Any]:
    """Largest commanded tilt, thrust range against hover, the shares (%) beyond the report's
    thresholds, and how often the exported helper's limits acted on the demand."""
    tilt = np.degrees(quat_tilt_rad(ticks.q))
    f = demanded_force(ticks.u_abs, mass)
    demanded = np.degrees(np.arctan2(np.hypot(f[:, 0], f[:, 1]), f[:, 2]))
    ratio = ticks.thrust / (mass * GRAVITY)
    lo, hi = o.thrust_band
    k = int(np.argmax(tilt))
    return {
        "max_tilt_deg": float(tilt[k]),
        "max_tilt_t_s": float((ticks.stamp_ns[k] - ticks.stamp_ns[0]) / NS),
        "first_tilt_deg": float(tilt[0]),
        "max_demanded_tilt_deg": float(demanded.max()),
        "first_demanded_tilt_deg": float(demanded[0]),
        "tilt_limit_deg": o.max_tilt_deg,
        "pct_tilt_exceeded": 100.0 * float(np.mean(tilt > o.max_tilt_deg)),
        "hover_thrust_n": mass * GRAVITY,
        "thrust_min_n": float(ticks.thrust.min()),
        "thrust_max_n": float(ticks.thrust.max()),
        "thrust_min_ratio": float(ratio.min()),
        "thrust_max_ratio": float(ratio.max()),
        "thrust_band": [lo, hi],
        "pct_thrust_outside": 100.0 * float(np.mean((ratio < lo) | (ratio > hi))),
        "export_limits": o.limits.describe(),
        "pct_limited": 100.0 * float(np.mean(limited(f, mass, o.limits))),
        "normalized_thrust_max": float(ticks.thrust_normalized.max()),
    }


# --------------------------------------------------------------------------- the command
def replay(
    folder: Path, source: Path, options: ReplayOptions, out: Path, *, force: bool = False
) -> ReplayResult:
    """The dry run (module docstring); writes ``out`` (an ``.mcap`` file) atomically."""
    out = Path(out)
    if out.suffix != ".mcap":
        raise ConfigError(f"--out {out}: the replay is written as an MCAP file; name it *.mcap")
    refuse_overlap(out, [folder, source], "output file")
    check_writable(out, "output file")
    if out.exists() and not force:
        raise OutputExistsError(f"{out} already exists; pass --force to overwrite it")
    if out.is_dir():
        raise OutputExistsError(f"{out} is a folder; choose another --out")
    cdir = load_controller_dir(folder)
    check_exportable(cdir, options.allow_uncertified)
    ref_opts = reference_options(options.reference)
    c = cdir.controller
    vio, v = read_vio(source, options)
    stamps, yv, gaps, parts = resample(vio, v, c.dt, options.max_gap)
    t_ref = (stamps - stamps[0]) / NS + options.reference_t0
    p_r, v_r, _ = Reference(ref_opts).arrays(t_ref)
    # the model's feedforward, as the simulator flies it (docs/guarantee.md, Disturbance in
    # deviation coordinates): the acceleration it stands for goes to the attitude map
    plant: Plant = "attitude" if c.model.A.shape[0] > NX else "hover"
    uff = Reference(ref_opts).feedforward(t_ref, c.dt, c.mass, plant)
    acc = feedforward_acceleration(uff, c.mass)
    al = reference_frame(yv[:, :3], p_r, options)
    yv = np.hstack([al.apply(yv[:, :3]), al.rotate(yv[:, 3:])])
    y_dev = yv - np.hstack([p_r, v_r])
    with tempfile.TemporaryDirectory(prefix="qsls-replay-") as tmp:
        ctrl, attitude = exported_runtime(cdir, options.backend, Path(tmp), options.limits)
        ticks, flags = command_ticks(
            ctrl, attitude, stamps, y_dev, acc, parts, c.mass, options.hover_thrust
        )
    report: dict[str, Any] = {
        "controller": cdir.name,
        "status": cdir.certificate.status,
        "controller_sha256": cdir.certificate.controller_sha256,
        "backend": options.backend,
        # the source by name and content, not by path: the same replay is the same bytes
        # wherever the recording lives
        "source": Path(source).name,
        "source_sha256": sha256_path(Path(source)),
        "vio": {**vio.describe(), "source": Path(source).name},
        "reference": ref_opts.model_dump(mode="json"),
        "dt": c.dt,
        "ticks": len(stamps),
        "segments": len(parts),
        "first_stamp_ns": int(stamps[0]),
        "gaps": gaps,
        "controller_reset_at_ns": [int(stamps[sl.start]) for sl in parts],
        "alignment": {**al.as_dict(), "yaw_deg": float(np.degrees(al.yaw_rad))},
        "first_deviation_m": float(np.linalg.norm(y_dev[0, :3])),
        "limits": limits(ticks, c.mass, options),
        "monitor": monitor_report(cdir, flags, stamps),
        "topics": {"command": options.command_topic, "deviation": Topics.deviation},
    }
    if (u := vio_uncertainty(vio)) is not None:  # only then: other replays keep their bytes
        report["vio_uncertainty"] = u
    report["warnings"] = warnings(report, options)
    topics = Topics(command=options.command_topic, frame_id=options.frame_id)
    make_parent(out, "output file")
    try:
        write_mcap(out, ticks, topics, json.dumps(report, sort_keys=True))
    except PermissionError as exc:
        raise unwritable(out, exc, "output file") from None
    return ReplayResult(out, report)
