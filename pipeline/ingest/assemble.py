"""The pure ingest core: two streams in, one flight out, no files and no printing.

:func:`flight_from_streams` takes the VIO and truth :class:`Trajectory` objects (what a
reader of :mod:`qsls.pipeline.ingest.sources` returns, or streams built in memory) and does
steps 2 to 7 of docs/ingest.md#steps: stamps (:func:`~qsls.pipeline.ingest.streams.prepare`),
the clock offset ``tau`` (added to truth stamps), the twist and truth velocities
(:mod:`qsls.pipeline.ingest.velocity`), the alignment ``p' = R p + t``, ``v' = R v``
(:mod:`qsls.pipeline.ingest.align`) fitted on time-matched pairs, and the resampling onto
``t_k = t_0 + k dt`` (:func:`~qsls.pipeline.ingest.resample.time_grid`) of ``x`` = truth,
``y`` = aligned VIO, ``e = y - x``. :mod:`qsls.pipeline.ingest.stage` reads the sources into
it and writes what it returns; ``qsls replay`` runs the same velocity step and grid on its
one stream.

Memory: the stream-long arrays are dropped as soon as they are used, so a caller that holds
no reference to the streams (``flight_from_streams(streams.pop(0), streams.pop(), o)``)
ingests in the memory docs/performance.md describes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.rotations import matrix_to_quat, quat_to_matrix
from qsls.pipeline.ingest.align import Alignment, fit_alignment
from qsls.pipeline.ingest.flight import VAR_COLS, flight_table
from qsls.pipeline.ingest.options import IngestOptions
from qsls.pipeline.ingest.resample import check_grid, time_grid
from qsls.pipeline.ingest.sources.base import Trajectory
from qsls.pipeline.ingest.streams import Prepared, check_streams, gaps, interp, prepare
from qsls.pipeline.ingest.timesync import estimate_offset, gravity_rows
from qsls.pipeline.ingest.velocity import truth_velocity, vio_velocity

if TYPE_CHECKING:
    import pyarrow as pa

Track = tuple[np.ndarray, np.ndarray, np.ndarray]
"""A trajectory to export: stamps (int64 ns, VIO clock), positions ``(n, 3)`` and
quaternions ``(n, 4)``, ``x y z w``, in the truth frame."""


@dataclass(frozen=True)
class IngestedFlight:
    """What :func:`flight_from_streams` makes of two streams: the flight table
    (:func:`~qsls.pipeline.ingest.flight.flight_table`), what the stage's manifest records of
    it (``results``: clock offset, alignment, RMS errors, gaps, the streams) and, with
    ``export_tum``, both trajectories aligned (``tracks``: ``vio`` and ``truth``)."""

    table: pa.Table
    results: dict[str, Any]
    tracks: dict[str, Track]

    @property
    def samples(self) -> int:
        return int(self.table.num_rows)


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


def flight_from_streams(
    vio_stream: Trajectory, truth_stream: Trajectory, options: IngestOptions
) -> IngestedFlight:
    """The flight of a VIO and a truth stream under ``options``: ``x`` the truth, ``y`` the
    VIO aligned (``p' = R p + t``, ``v' = R v``), truth stamps shifted by ``tau``, both
    resampled onto ``t_k = t_0 + k dt`` (module docstring, docs/ingest.md#the-pure-core); a
    one-line :class:`~qsls.pipeline.core.errors.InputError` for streams that give none."""
    o = options
    vio = prepare(vio_stream, "vio", vio_stream.source, o)
    del vio_stream  # the other stamp's column: the stream-long arrays are dropped once unused
    truth = prepare(truth_stream, "truth", truth_stream.source, o)
    del truth_stream
    release_freed_memory()
    check_streams(vio, truth, o)
    streams = {"vio": vio.describe(), "truth": truth.describe()}
    gap_ns = round(o.max_gap * 1e9)
    truth_g = None
    if o.time_offset == "auto" and o.align in ("4dof", "none"):
        # the truth's orientations serve the offset search as its gravity directions only:
        # those (3 columns) replace them (4) from here on, unless the TUM export needs them

        truth_g = gravity_rows(truth.orientation)
        truth = drop_columns(truth, o.export_tum)
    tau, offset_info = clock_offset(vio, truth, o, truth_g)
    del truth_g
    tau_ns = round(tau * 1e9)
    tt = truth.t_ns + tau_ns  # truth on the VIO clock
    # what is left to do needs the orientations only for the VIO's twist and the TUM export
    truth = drop_columns(truth, o.export_tum)
    release_freed_memory()
    v_vio, vio_vsrc = vio_velocity(vio, o.vio_velocity_frame, o.velocity_window, o.max_gap)
    vio = drop_columns(vio, o.export_tum)
    release_freed_memory()
    v_truth, truth_vsrc = truth_velocity(truth, o.velocity_window, o.max_gap)

    lo, hi = max(vio.t_ns[0], tt[0]), min(vio.t_ns[-1], tt[-1])
    al = _fit_on_pairs(vio, tt, truth.position, (lo, hi), gap_ns, o.align)
    p_vio = al.apply(vio.position)
    v_vio = al.rotate(v_vio)
    vio = dataclasses.replace(vio, position=np.zeros((0, 3)))  # p_vio from here on

    table, n_dropped, stamp0, rms_p, rms_v = _on_grid(
        vio.t_ns, p_vio, v_vio, vio.variance, tt, truth.position, v_truth, (lo, hi), o
    )
    truth_vio_clock = dataclasses.replace(truth, t_ns=tt)
    found_gaps = gaps(vio, lo, hi, gap_ns, stamp0) + gaps(truth_vio_clock, lo, hi, gap_ns, stamp0)
    streams["vio"]["stamp"] = streams["truth"]["stamp"] = o.stamp
    results: dict[str, Any] = {
        "samples": table.num_rows,
        "dropped_grid_samples": n_dropped,
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
    if vio.variance is not None:  # only then: a flight without them keeps its manifest as before
        results["covariance_columns"] = list(VAR_COLS)
    tracks: dict[str, Track] = {}
    if o.export_tum:
        q_vio = matrix_to_quat(al.rotation[None] @ quat_to_matrix(vio.orientation))
        tracks = {"vio": (vio.t_ns, p_vio, q_vio), "truth": (tt, truth.position, truth.orientation)}
    # the stream-long arrays are done with: the writer's memory comes on top of the grid's only
    del vio, truth, truth_vio_clock, tt, p_vio, v_vio, v_truth
    release_freed_memory()
    return IngestedFlight(table, results, tracks)


def _on_grid(
    vio_t: np.ndarray,
    p_vio: np.ndarray,
    v_vio: np.ndarray,
    vio_var: np.ndarray | None,
    tt: np.ndarray,
    p_truth: np.ndarray,
    v_truth: np.ndarray,
    span: tuple[int, int],
    o: IngestOptions,
) -> tuple[pa.Table, int, int, float, float]:
    """Both streams resampled onto the common grid ``t_k = t_0 + k dt`` over ``span`` (truth
    on the VIO clock, ``tt``): the flight table of the ticks where both have data, how many
    ticks were dropped, the first kept stamp and the rms position and velocity errors
    ``sqrt(mean ||y - x||^2)``."""
    lo, hi = span
    gap_ns = round(o.max_gap * 1e9)
    check_grid(o.dt, vio_t, hi - lo)
    grid = time_grid(lo, hi, round(o.dt * 1e9))
    # each column block on its own (the same values as the stacked columns, no stream-long copy)
    (yp, ok_v), (yvv, _) = (
        interp(grid, vio_t, p_vio, gap_ns),
        interp(grid, vio_t, v_vio, gap_ns),
    )
    (xp, ok_t), (xvv, _) = (
        interp(grid, tt, p_truth, gap_ns),
        interp(grid, tt, v_truth, gap_ns),
    )
    yv, xv = np.hstack([yp, yvv]), np.hstack([xp, xvv])
    del yp, yvv, xp, xvv
    var = interp(grid, vio_t, vio_var, gap_ns)[0] if vio_var is not None else None
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
    return table, int(len(grid) - valid.sum()), int(stamps[0]), rms_p, rms_v


def _fit_on_pairs(
    vio: Prepared, tt: np.ndarray, p_truth: np.ndarray, span: tuple[int, int], gap_ns: int,
    method: str,
) -> Alignment:  # fmt: skip
    """The alignment (``method``) fitted on time-matched pairs: the VIO samples inside
    ``span`` (both streams' coverage) and the truth (stamps ``tt``, VIO clock) interpolated
    at their stamps, never across a gap longer than ``gap_ns``."""
    lo, hi = span
    # the stamps are sorted: the VIO samples inside [lo, hi] are one run, a view (no copies)
    sel = slice(int(np.searchsorted(vio.t_ns, lo)), int(np.searchsorted(vio.t_ns, hi, "right")))
    p_truth_at_vio, ok = interp(vio.t_ns[sel], tt, p_truth, gap_ns)
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
    return fit_alignment(src, dst, method, scratch_dst=True)  # dst is ours: centred in place


def clock_offset(
    vio: Prepared, truth: Prepared, o: IngestOptions, truth_g: np.ndarray | None = None
) -> tuple[float, dict[str, Any]]:
    """``time_offset_s`` (added to truth stamps, docs/conventions.md#clocks) and how it was found:
    given, or the minimum over the offset of the aligned mismatch (:mod:`timesync`);
    ``truth_g``: the truth's gravity directions in its body frame, computed by the caller
    (:func:`qsls.pipeline.ingest.timesync.gravity_rows`), else from its orientations."""
    if truth_g is None and o.time_offset == "auto":
        truth_g = gravity_rows(truth.orientation)

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


def drop_columns(s: Prepared, keep_orientation: bool) -> Prepared:
    """``s`` without its message velocity (used by then) and, unless kept, its orientations."""
    empty = np.zeros((0, 4))
    return dataclasses.replace(
        s, velocity=None, orientation=s.orientation if keep_orientation else empty
    )
