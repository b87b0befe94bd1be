"""Warnings about an ingested flight that ran but looks wrong (docs/ingest.md#warnings):
streams that look swapped, and an error between the aligned VIO and the truth too large for
one flight of one vehicle. Pure: the flight table and the manifest's results in, sentences
out; the stage records them and the CLI prints them.

Swapped streams. An estimate is rougher than motion capture: its noise and its corrections
add to the motion, which both streams share. The roughness of a stream on the grid is
``rough(p) = rms_k ||p_{k+1} - 2 p_k + p_{k-1}||`` over runs of three consecutive grid points;
the streams look swapped when ``rough(y) < SMOOTHER * rough(x)`` (the "VIO" smoother than the
"truth"), or when the VIO topic records at least ``FASTER`` times the truth's rate (motion
capture records at 100 to 400 Hz, an estimate at its camera's 10 to 30 Hz) while it is not
the rougher one. Measured (dt 0.05 s): ``rough(y) / rough(x)`` is 1.71 (EuRoC V1_02), 3.61
(MH_04) and 9.5 (the simulator) with the right topics, 0.59 and 0.63 with them swapped.
"""

from __future__ import annotations

from typing import Any

import numpy as np

SMOOTHER = 0.8
"""``rough(y) / rough(x)`` below this: the VIO is the smoother stream (module docstring)."""
FASTER = 2.0
"""The VIO's rate over the truth's at or above this, with the VIO not the rougher: the rates
of motion capture and an estimate the other way round."""
IMPLAUSIBLE_RMS_M = 1.0
"""An RMS position error above this (m) after alignment is not a VIO's error over one flight
(EuRoC's estimators: 0.04 to 0.17 m; the simulator's: 0.08 m) but streams that do not
describe one motion: wrong topics, frames or clocks."""


def roughness(p: np.ndarray, t: np.ndarray, dt: float) -> float:
    """``rms_k ||p_{k+1} - 2 p_k + p_{k-1}||`` over the grid points whose neighbours are one
    ``dt`` away (no gap between them); NaN with fewer than 3 such points."""
    if len(p) < 3:
        return float("nan")
    ok = np.abs(t[2:] - t[:-2] - 2 * dt) < 1e-6 * max(dt, 1e-9)
    if not ok.any():
        return float("nan")
    d2 = (p[2:] - 2 * p[1:-1] + p[:-2])[ok]
    return float(np.sqrt(np.mean(np.sum(d2**2, axis=1))))


def _column(table: Any, name: str) -> np.ndarray:
    """An arrow table's float64 column as numpy, read from its buffers (every conversion
    pyarrow offers imports pandas, which an ingest never loads: tests/test_startup.py); nulls
    as NaN."""
    out = []
    for c in table.column(name).chunks:
        if str(c.type) != "double":
            out.append(np.asarray(c.to_numpy(zero_copy_only=False), dtype=float))
            continue
        data = np.frombuffer(c.buffers()[1], dtype=np.float64, count=len(c), offset=8 * c.offset)
        if c.null_count:
            valid = np.asarray(c.is_valid().to_numpy(zero_copy_only=False), dtype=bool)
            data = np.where(valid, data, np.nan)
        out.append(data)
    return np.concatenate(out) if out else np.zeros(0)


def swapped(table: Any, results: dict[str, Any]) -> str | None:
    """The warning when the streams look swapped (module docstring), naming both topics, the
    evidence and the flags to swap; None otherwise."""
    cols = table.column_names
    if not all(c in cols for c in ("t", "x_px", "y_px")):
        return None
    t = _column(table, "t")
    x = np.column_stack([_column(table, f"x_p{a}") for a in "xyz"])
    y = np.column_stack([_column(table, f"y_p{a}") for a in "xyz"])
    dt = float(results.get("dt", 0.0)) or (float(np.median(np.diff(t))) if len(t) > 1 else 0.0)
    rx, ry = roughness(x, t, dt), roughness(y, t, dt)
    ratio = ry / rx if rx > 0 else float("nan")
    v, tr = results["streams"]["vio"], results["streams"]["truth"]
    fv, ft = float(v.get("rate_hz", 0.0)), float(tr.get("rate_hz", 0.0))
    smoother = bool(ratio < SMOOTHER)
    faster = bool(ft > 0 and fv >= FASTER * ft and not ratio >= 1.0)
    if not (smoother or faster):
        return None
    signs = []
    if faster:
        signs.append(f"it records at {fv:.4g} Hz, the truth at {ft:.4g} Hz")
    if np.isfinite(ratio):
        signs.append(
            f"its second differences are {ratio:.2f} x the truth's (an estimate's are larger)"
        )
    return (
        "the streams look swapped: swap --vio-topic and --truth-topic (or --vio and --truth) "
        f"if the VIO '{v.get('topic')}' is the ground truth and '{tr.get('topic')}' the "
        f"estimate: {'; '.join(signs)}"
    )


def implausible_error(results: dict[str, Any]) -> str | None:
    """The warning when the RMS position error exceeds :data:`IMPLAUSIBLE_RMS_M`; None
    otherwise."""
    rms = float(results.get("rms_position_m", 0.0))
    if not rms > IMPLAUSIBLE_RMS_M:
        return None
    gaps = len(results.get("gaps") or [])
    return (
        f"check the topics, frames and clocks: the RMS position error between the aligned VIO "
        f"and the truth is {rms:.3g} m ({gaps} gap{'s' if gaps != 1 else ''}), above "
        f"{IMPLAUSIBLE_RMS_M:g} m, more than a VIO drifts over one flight; the streams may not "
        "describe one motion (another vehicle's topic, a frame not aligned by --align, or "
        "clocks apart: --time-offset, --stamp)"
    )


def ingest_warnings(table: Any, results: dict[str, Any]) -> tuple[str, ...]:
    """Every warning of an ingested flight (:func:`swapped`, :func:`implausible_error`)."""
    return tuple(w for w in (swapped(table, results), implausible_error(results)) if w)
