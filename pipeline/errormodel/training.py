"""The fit's training samples: the ingested flights read into one :class:`FitData`, with the
exclusions applied, a flight counted once, the realized disturbance ``w_k`` and the
measurement noise floor (docs/errormodel.md; :mod:`qsls.pipeline.errormodel.fit` estimates
the error model from them).

- Outliers: ``z = |e - median| / (1.4826 MAD)`` per axis; a sample with ``z > outlier_z`` on
  any axis is left out (``exclude_outliers``).
- Noise floor: per axis, ``sigma_a = 1.4826 median|D^2 e_a| / sqrt 6`` from second
  differences along each flight, over runs of consecutive kept samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core.artifacts import require_stage
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import GRAVITY, plant_model
from qsls.pipeline.errormodel.disturbance import INPUTS, RESIDUAL, flight_disturbance
from qsls.pipeline.errormodel.options import FitOptions
from qsls.pipeline.ingest.flight import Flight, errors, states

_MAD = 1.4826


@dataclass(frozen=True)
class FitData:
    """The training samples in memory, every flight's in one array: what :func:`fit_model`
    estimates the error model from (:func:`load_fit_data` reads it from ingested flights;
    a notebook may build it from arrays)."""

    names: list[str]
    flight_idx: np.ndarray  # (n,) index into names
    t: np.ndarray
    x: np.ndarray
    e: np.ndarray
    keep: np.ndarray  # (n,) bool: used for the model
    exclusions: dict[str, int]
    dt: float = float("nan")  # the flights' common sample period (s)
    w: np.ndarray | None = None  # (n, 6) w_k of the step k -> k+1 (NaN: unknown)
    w_source: str = ""


def _flight_names(flights: list[Path]) -> list[str]:
    names: list[str] = []
    seen: dict[str, int] = {}
    for f in flights:
        base = Path(f).resolve().name or str(f)
        k = seen.get(base, 0)
        seen[base] = k + 1
        names.append(base if k == 0 else f"{base}_{k + 1}")
    return names


def load_fit_data(flights: list[Path], options: FitOptions) -> FitData:
    """The samples of the ingested ``flights`` (and, with ``options.inputs``, their realized
    disturbance), with the exclusions of ``options`` applied as the ``keep`` mask."""
    if not flights:
        raise InputError("no flights given; pass one or more folders written by 'qsls ingest'")
    loaded = []
    for f in flights:
        f = Path(f)
        if not f.is_dir():
            raise InputError(f"{f}: not a folder; pass flight folders written by 'qsls ingest'")
        require_stage(f, "ingest")
        loaded.append(Flight.load(f))
    names = _flight_names(flights)
    if options.environments is not None and len(options.environments) != len(flights):
        raise InputError(
            f"environments: {len(options.environments)} names for {len(flights)} flights; give "
            "one environment per flight, in the flights' order"
        )
    _refuse_twins(flights, loaded, names)
    dt = _common_dt(loaded, names)
    tables = [fl.frame for fl in loaded]
    fi = np.concatenate([np.full(len(df), k) for k, df in enumerate(tables)])
    t = np.concatenate([df["t"].to_numpy(float) for df in tables])
    x = np.concatenate([states(df) for df in tables])
    e = np.concatenate([errors(df) for df in tables])
    if len(t) == 0:
        raise InputError("the flights hold no samples")
    finite = np.isfinite(x).all(axis=1) & np.isfinite(e).all(axis=1)
    keep = finite.copy()
    ex = {"nonfinite": int((~finite).sum())}
    late = t >= options.skip_start
    ex["skip_start"] = int((keep & ~late).sum())
    keep &= late
    if options.exclude_outliers and keep.any():
        z = robust_z(e[keep])
        out = np.zeros(len(keep), dtype=bool)
        out[np.flatnonzero(keep)] = (z > options.outlier_z).any(axis=1)
        ex["outliers"] = int(out.sum())
        keep &= ~out
    w, w_source = _disturbance(loaded, options, dt)
    if not keep.any():
        raise InputError(
            f"all {len(keep)} samples were excluded ("
            + ", ".join(f"{k}: {v}" for k, v in ex.items() if v)
            + "); relax --skip-start / --exclude-outliers"
        )
    return FitData(names, fi, t, x, e, keep, ex, dt, w, w_source)


def _refuse_twins(flights: list[Path], loaded: list[Flight], names: list[str]) -> None:
    """A flight counts once. Two folders with the same ground truth (the same folder twice,
    a symlink to it, a copy, or one flight ingested with a second estimator) are one flight:
    as two folds of leave-one-flight-out, leaving one out leaves its twin in, and S is tested
    on nothing."""
    import hashlib

    seen: dict[str, int] = {}
    for k, fl in enumerate(loaded):
        key = hashlib.sha256(np.ascontiguousarray(states(fl.frame)).tobytes()).hexdigest()
        j = seen.setdefault(key, k)
        if j != k:
            how = ("the same folder" if Path(flights[j]).resolve() == Path(flights[k]).resolve()
                   else "the same ground truth")  # fmt: skip
            raise _one_flight(flights, names, j, k, how)
    for j in range(len(loaded)):
        for k in range(j + 1, len(loaded)):
            if same_motion(loaded[j].frame, loaded[k].frame):
                raise _one_flight(flights, names, j, k, "the same motion at the same times")


def _one_flight(flights: list[Path], names: list[str], j: int, k: int, how: str) -> InputError:
    return InputError(
        f"flights '{names[j]}' ({flights[j]}) and '{names[k]}' ({flights[k]}) are one "
        f"flight ({how}): a flight counts once (two estimators of one flight are one "
        "flight too); pass it once"
    )


MIN_TWIN_OVERLAP_S = 30.0
"""Shorter overlaps are not compared by motion: two simulated flights of one reference on one
clock agree to millimetres during their take-off (8 s flights were taken for one)."""


def same_motion(a: Any, b: Any, tol_m: float = 0.01, max_shift_s: float = 0.3) -> bool:
    """Two ingests of one physical flight (another estimator, another export of the truth):
    on the stamps both cover (at least half of the shorter), after the best rigid motion (the
    two ingests' frames differ) and the best clock shift within ``max_shift_s`` (their offset
    estimates differ), the true positions agree to ``tol_m`` in the median. Measured: EuRoC
    V1_02's two estimators' ingests agree to 4 mm (80 s); two 20 s simulated flights of one
    reference differ by 28 mm or more (their tracking errors); flights overlapping less than
    :data:`MIN_TWIN_OVERLAP_S` are not compared."""
    col = "stamp_ns" if "stamp_ns" in a.columns and "stamp_ns" in b.columns else "t"
    scale = 1e-9 if col == "stamp_ns" else 1.0
    ta, tb = a[col].to_numpy(float) * scale, b[col].to_numpy(float) * scale
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    if hi - lo < max(MIN_TWIN_OVERLAP_S, 0.5 * min(ta[-1] - ta[0], tb[-1] - tb[0])):
        return False
    xa, xb = states(a)[:, :3], states(b)[:, :3]
    for shift in np.arange(-max_shift_s, max_shift_s + 1e-9, 0.01):
        sel = (ta + shift >= tb[0]) & (ta + shift <= tb[-1])
        pa = xa[sel]
        pb = np.column_stack([np.interp(ta[sel] + shift, tb, xb[:, i]) for i in range(3)])
        ok = np.isfinite(pa).all(axis=1) & np.isfinite(pb).all(axis=1)
        if ok.sum() < 20:
            continue
        ca, cb = pa[ok] - pa[ok].mean(axis=0), pb[ok] - pb[ok].mean(axis=0)
        u, _, vt = np.linalg.svd(ca.T @ cb)
        r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt  # Kabsch
        if np.median(np.linalg.norm(ca @ r - cb, axis=1)) < tol_m:
            return True
    return False


def _disturbance(loaded: list[Flight], options: FitOptions, dt: float) -> tuple[np.ndarray, str]:
    """``w_k`` of every sample (:mod:`qsls.pipeline.errormodel.disturbance`) and how it was
    measured."""
    if options.inputs is not None and len(options.inputs) != len(loaded):
        raise InputError(
            f"inputs: {len(options.inputs)} control logs for {len(loaded)} flights; give one "
            "per flight, in the flights' order"
        )
    plant = plant_model(options.plant, dt=dt, mass=options.mass)
    hover = np.array([0.0, 0.0, options.mass * GRAVITY])
    out = []
    for k, fl in enumerate(loaded):
        df = fl.frame
        logged = None
        if options.inputs is not None:
            logged = _read_inputs(Path(options.inputs[k]), int(df["stamp_ns"].iloc[0]))
        out.append(
            flight_disturbance(
                df["t"].to_numpy(float), states(df), dt, plant.A, plant.B, hover, logged
            )
        )
    return np.concatenate(out), INPUTS if options.inputs is not None else RESIDUAL


U_COLS = ("u_pitch", "u_roll", "u_thrust")


def _read_inputs(path: Path, stamp0_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t, u)`` of a control log, ``t`` in seconds from the flight's first sample."""
    if not path.is_file():
        raise InputError(f"inputs: {path} does not exist; give the flight's control log")
    try:
        df = pd.read_parquet(path, columns=["stamp_ns", *U_COLS])
    except Exception:
        raise InputError(
            f"inputs: {path} is not a control log (parquet with stamp_ns, {', '.join(U_COLS)})"
        ) from None
    t = (df["stamp_ns"].to_numpy(np.int64) - stamp0_ns) / 1e9
    return t, df[list(U_COLS)].to_numpy(float)


def _common_dt(flights: list[Flight], names: list[str]) -> float:
    """The flights' one sample period; flights of different ``dt`` are refused (the pair
    slopes and the noise floor from second differences assume one grid)."""
    dts = [fl.dt for fl in flights]
    if any(abs(d - dts[0]) > 1e-9 * max(abs(dts[0]), 1.0) for d in dts):
        listed = ", ".join(f"{n} {d:g} s" for n, d in zip(names, dts, strict=True))
        raise InputError(
            f"the flights have different dt ({listed}); ingest them with one --dt "
            "(the error model is for one controller period)"
        )
    return float(dts[0])


def robust_z(e: np.ndarray) -> np.ndarray:
    """``|e - median| / (1.4826 MAD)`` per axis (0 on an axis whose MAD is 0)."""
    med = np.median(e, axis=0)
    mad = _MAD * np.median(np.abs(e - med), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(e - med) / mad
    z[:, mad <= 0] = 0.0
    return z


def noise_floor(tr: FitData) -> np.ndarray:
    """Per-axis white-noise std of ``e`` from second differences along each flight (6,)."""
    d2 = []
    for k in range(len(tr.names)):
        sel = (tr.flight_idx == k) & tr.keep
        idx = np.flatnonzero(sel)
        if len(idx) < 3:
            continue
        # only runs of consecutive kept samples
        ok = (idx[2:] - idx[:-2]) == 2
        e = tr.e[idx]
        dd = e[2:] - 2 * e[1:-1] + e[:-2]
        d2.append(dd[ok])
    if not d2 or sum(len(a) for a in d2) == 0:
        return np.zeros(6)
    allv = np.concatenate(d2)
    return _MAD * np.median(np.abs(allv), axis=0) / math.sqrt(6.0)
