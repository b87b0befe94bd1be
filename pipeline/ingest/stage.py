"""``qsls ingest``: VIO and motion-capture streams onto one clock, one frame and one grid.

Steps (docs/ingest.md#steps):

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
from typing import TYPE_CHECKING, Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.ingest.options import IngestOptions

if TYPE_CHECKING:
    from qsls.pipeline.ingest.streams import Prepared

STAGE = "ingest"


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
        # then the parquet writer's import (pyarrow, 40-60 ms of CPU), which the end of the
        # stage needs, while the main thread waits on the reading (SQLite and the
        # decompressors run without the GIL)
        hasher.submit(importlib.import_module, "pyarrow.parquet")
        try:
            return _ingest([Path(p) for p in sources], inputs, o, out, force, progress, hashed)
        finally:
            hasher.shutdown(wait=True)


def release_freed_memory() -> None:
    """Hand the C heap's free pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere): the reader's freed batches otherwise stay resident as heap fragments
    (25 MB after reading a 2 000 000-message bag)."""
    import contextlib
    import ctypes
    import sys

    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):  # not glibc
            ctypes.CDLL("libc.so.6").malloc_trim(0)


FINEST_GRID = 10
"""How much finer than the VIO's own sampling step ``dt`` may be (finer is interpolation only)."""


def check_grid(dt: float, vio_t_ns: np.ndarray, span_ns: int) -> None:
    """Refuse a ``dt`` far finer than the VIO's own sampling: a flight of interpolated
    samples that carry no new information, and gigabytes of them (``--dt 1e-6`` on 100 Hz
    data: 2.7 GB)."""
    step_s = float(np.median(np.diff(vio_t_ns))) * 1e-9 if len(vio_t_ns) > 1 else 0.0
    if step_s > 0 and dt * FINEST_GRID < step_s:
        n = int(span_ns * 1e-9 / dt)
        raise InputError(
            f"--dt {dt:g} s is {step_s / dt:,.0f} times finer than the VIO's own sampling step "
            f"({step_s:.3g} s): {n:,} samples (about {n * 13 * 8 / 1e9:.3g} GB) of interpolation "
            f"only; choose --dt of at least {step_s / FINEST_GRID:.3g} s (the paper's: 0.1)"
        )


def _clock_offset(
    vio: Prepared, truth: Prepared, o: IngestOptions, truth_g: np.ndarray | None = None
) -> tuple[float, dict[str, Any]]:
    """``time_offset_s`` (added to truth stamps, docs/conventions.md#clocks) and how it was found:
    given, or the minimum over the offset of the aligned mismatch (:mod:`timesync`);
    ``truth_g``: the truth's gravity directions in its body frame, computed by the caller
    (:func:`qsls.pipeline.ingest.timesync.gravity_rows`), else from its orientations."""
    from qsls.pipeline.ingest.timesync import gravity_rows

    if truth_g is None and o.time_offset == "auto":
        truth_g = gravity_rows(truth.orientation)
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
            vio_q=vio.orientation, truth_q=truth_g,
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


def _drop(s: Prepared, keep_orientation: bool) -> Prepared:
    """``s`` without its message velocity (used by then) and, unless kept, its orientations."""
    empty = np.zeros((0, 4))
    return dataclasses.replace(
        s, velocity=None, orientation=s.orientation if keep_orientation else empty
    )


def _square_sums(
    chosen: np.ndarray, other: np.ndarray, v_pos: np.ndarray, ok: np.ndarray
) -> tuple[float, float]:
    """``sum ||chosen - v_pos||^2`` and ``sum ||other - v_pos||^2`` over the rows ``ok``."""
    d1 = chosen[ok] - v_pos[ok]
    d2 = other[ok] - v_pos[ok]
    return float(np.sum(d1**2)), float(np.sum(d2**2))


def _frame_verdict(vio: Prepared, o: IngestOptions, mine2: float, theirs2: float, n: int) -> None:
    """Refuse a twist frame the VIO's own positions contradict: the twist read in the other
    frame matches the derivative of the VIO positions far better (``--vio-velocity-frame
    world`` on a body-frame bag gave 0.59 m/s of velocity error without a word); from the
    two sums of squares (:func:`_square_sums`) over ``n`` rows."""
    if n < 10:
        return
    mine, theirs = float(np.sqrt(mine2 / n)), float(np.sqrt(theirs2 / n))
    if mine > 0.1 and theirs < 0.6 * mine:
        right = "world" if o.vio_velocity_frame == "body" else "body"
        raise InputError(
            f"{vio.topic}: its twist read in the {o.vio_velocity_frame} frame is {mine:.2g} m/s "
            f"RMS off the derivative of its own positions, in the {right} frame {theirs:.2g} m/s; "
            f"pass --vio-velocity-frame {right}"
        )


FRAME_CHECK_WINDOW_S = 0.5
"""The differentiator's window for the twist-frame check (smooth: only the frame is judged)."""


def _vio_velocity(vio: Prepared, o: IngestOptions) -> tuple[np.ndarray, str]:
    """The VIO's velocity in its own world frame, and where it came from: the message twist
    (rotated from the body frame if asked) or, lacking one, the smoothing differentiator on
    positions."""
    from qsls.pipeline.core.rotations import body_to_world
    from qsls.pipeline.ingest.align import differentiate
    from qsls.pipeline.ingest.resample import median_spacing
    from qsls.pipeline.ingest.streams import CHUNK

    gap_ns = round(o.max_gap * 1e9)
    win = o.velocity_window
    if vio.velocity is None:
        v_vio = differentiate(vio.t_ns, vio.position, win, gap_ns)
        return v_vio, _SMOOTHED.format(win=win)
    body = o.vio_velocity_frame == "body"
    # block by block, without (n, 3, 3) matrices or a second stream-long velocity: the
    # twist rotated to the world frame, both frames compared with the positions' derivative
    # (differentiated on the block and a margin of twice the window either side), and
    # (body) the rotated twist written over the stream's own (its last use)
    v, sums, count = vio.velocity, np.zeros(2), 0
    n, rows = len(v), CHUNK
    pad = 2 * int(np.ceil(FRAME_CHECK_WINDOW_S / (median_spacing(vio.t_ns) * 1e-9))) + 8
    for a in range(0, n, rows):
        b = min(a + rows, n)
        lo, hi = max(a - pad, 0), min(b + pad, n)
        smooth = differentiate(vio.t_ns[lo:hi], vio.position[lo:hi], FRAME_CHECK_WINDOW_S, gap_ns)
        smooth = smooth[a - lo : b - lo]
        ok = np.isfinite(smooth).all(axis=1)
        as_body = body_to_world(vio.orientation[a:b], v[a:b])
        chosen, other = (as_body, v[a:b]) if body else (v[a:b], as_body)
        sums += _square_sums(chosen, other, smooth, ok)
        count += int(ok.sum())
        if body:
            v[a:b] = as_body
    _frame_verdict(vio, o, float(sums[0]), float(sums[1]), count)
    if body:
        return v, "message twist, body (child) frame rotated to world by the VIO orientation"
    return v, "message twist, world frame as published"


_SMOOTHED = "smoothing differentiator (Savitzky-Golay quadratic, {win:g} s window) on positions"


def _truth_velocity(truth: Prepared, o: IngestOptions) -> tuple[np.ndarray, str]:
    """The truth's velocity: always the smoothing differentiator on its positions."""
    from qsls.pipeline.ingest.align import differentiate

    win = o.velocity_window
    v = differentiate(truth.t_ns, truth.position, win, round(o.max_gap * 1e9))
    return v, _SMOOTHED.format(win=win)


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
    from qsls.pipeline.ingest.flight import FLIGHT_FILE, VAR_COLS, flight_table
    from qsls.pipeline.ingest.streams import check_streams, gaps, interp, prepare, read_streams

    vio_t, truth_t, where = read_streams(sources, o, progress)
    vio = prepare(vio_t, "vio", where["vio"], o)
    del vio_t  # the other stamp's column: the stream-long arrays are dropped once unused
    truth = prepare(truth_t, "truth", where["truth"], o)
    del truth_t
    release_freed_memory()
    check_streams(vio, truth, o)
    streams = {"vio": vio.describe(), "truth": truth.describe()}
    gap_ns = round(o.max_gap * 1e9)
    truth_g = None
    if o.time_offset == "auto" and o.align in ("4dof", "none"):
        # the truth's orientations serve the offset search as its gravity directions only:
        # those (3 columns) replace them (4) from here on, unless the TUM export needs them
        from qsls.pipeline.ingest.timesync import gravity_rows

        truth_g = gravity_rows(truth.orientation)
        truth = _drop(truth, o.export_tum)
    tau, offset_info = _clock_offset(vio, truth, o, truth_g)
    del truth_g
    tau_ns = round(tau * 1e9)
    tt = truth.t_ns + tau_ns  # truth on the VIO clock
    # what is left to do needs the orientations only for the VIO's twist and the TUM export
    truth = _drop(truth, o.export_tum)
    release_freed_memory()
    v_vio, vio_vsrc = _vio_velocity(vio, o)
    vio = _drop(vio, o.export_tum)
    release_freed_memory()
    v_truth, truth_vsrc = _truth_velocity(truth, o)

    # ---- alignment on time-matched pairs (VIO stamps inside the truth's coverage)
    lo, hi = max(vio.t_ns[0], tt[0]), min(vio.t_ns[-1], tt[-1])
    # the stamps are sorted: the VIO samples inside [lo, hi] are one run, a view (no copies)
    sel = slice(int(np.searchsorted(vio.t_ns, lo)), int(np.searchsorted(vio.t_ns, hi, "right")))
    p_truth_at_vio, ok = interp(vio.t_ns[sel], tt, truth.position, gap_ns)
    if ok.sum() < 10:
        raise InputError(
            f"only {int(ok.sum())} VIO samples fall where the truth stream has data; "
            "check the topics, --stamp and --time-offset"
        )
    if ok.all():
        src, dst = vio.position[sel], p_truth_at_vio
    else:
        src, dst = vio.position[sel][ok], p_truth_at_vio[ok]
    del p_truth_at_vio
    release_freed_memory()
    al = fit_alignment(src, dst, o.align, scratch_dst=True)  # dst is ours: centred in place
    del src, dst
    del ok, sel
    p_vio = al.apply(vio.position)
    v_vio = al.rotate(v_vio)
    vio = dataclasses.replace(vio, position=np.zeros((0, 3)))  # p_vio from here on

    # ---- common grid
    check_grid(o.dt, vio.t_ns, hi - lo)
    dt_ns = round(o.dt * 1e9)
    start = -(-lo // dt_ns) * dt_ns
    grid = np.arange(start, hi + 1, dt_ns, dtype=np.int64)
    # each column block on its own (the same values as the stacked columns, no stream-long copy)
    (yp, ok_v), (yvv, _) = (
        interp(grid, vio.t_ns, p_vio, gap_ns),
        interp(grid, vio.t_ns, v_vio, gap_ns),
    )
    (xp, ok_t), (xvv, _) = (
        interp(grid, tt, truth.position, gap_ns),
        interp(grid, tt, v_truth, gap_ns),
    )
    yv, xv = np.hstack([yp, yvv]), np.hstack([xp, xvv])
    del yp, yvv, xp, xvv
    var = interp(grid, vio.t_ns, vio.variance, gap_ns)[0] if vio.variance is not None else None
    valid = ok_v & ok_t
    if valid.sum() < 10:
        raise InputError(
            f"only {int(valid.sum())} samples of dt={o.dt:g} s where both streams have data; "
            "the streams overlap too little (check --max-gap, --dt and the topics)"
        )
    stamps = grid[valid]
    table = flight_table(stamps, xv[valid], yv[valid], None if var is None else var[valid])
    err = yv[valid] - xv[valid]
    rms_p = float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))))
    rms_v = float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1))))
    truth_vio_clock = dataclasses.replace(truth, t_ns=tt)
    found_gaps = gaps(vio, lo, hi, gap_ns, int(stamps[0])) + gaps(
        truth_vio_clock, lo, hi, gap_ns, int(stamps[0])
    )
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
        "gaps": found_gaps,
        "streams": streams,
    }
    if var is not None:  # only then: a flight without them keeps its manifest as before
        results["covariance_columns"] = list(VAR_COLS)
    files: dict[str, bytes] = {}
    if o.export_tum:
        q_vio = matrix_to_quat(al.rotation[None] @ quat_to_matrix(vio.orientation))
        files["vio_aligned.tum"] = _tum_text(vio.t_ns, p_vio, q_vio).encode()
        files["truth.tum"] = _tum_text(tt, truth.position, truth.orientation).encode()
    # the stream-long arrays are done with: the writer's memory comes on top of the grid's only
    del vio, truth, truth_vio_clock, tt, p_vio, v_vio, v_truth
    release_freed_memory()
    # the files are serialized while the input hash may still run; the writer needs it
    files = {FLIGHT_FILE: parquet_bytes(table), **files}
    hashed.result()
    with StageWriter(out, STAGE, options=o, inputs=inputs, force=force) as w:
        for name, data in files.items():
            w.write_bytes(name, data)
        w.results.update(results)
    return IngestResult(out, table.num_rows, tau, al.as_dict(), rms_p, rms_v, streams, found_gaps)
