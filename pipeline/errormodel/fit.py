"""``qsls fit``: the data-driven perception error model (docs/errormodel.md; paper III-C).

Training data: the aligned samples ``(x_i, e_i)`` of ingested flights, ``e = y - x``.

- ``eps_e = max_i ||e_i||`` (infinity norm) and percentiles of ``||e_i||``; per-axis statistics.
- The S-slope with radius ``r``: the pair slopes ``s_ij = ||e_i - e_j|| / ||W (x_i - x_j)||``
  over pairs ``min_separation <= ||W (x_i - x_j)|| < r`` (``W = diag(state_scale)``), from
  :mod:`qsls.pipeline.errormodel.slopes`: the exact max (the paper's ``S_hat``), percentiles over pairs,
  percentiles of each sample's largest slope, and the pairs that set the largest slopes.
- ``R0``: the error bound of the guarantee (``eps_e`` unless ``r0`` names another).
- ``delta = max_k min_i ||W (r_k - x_i)||``: how far the reference states ``r_k`` stray from
  the training states.

**Minimum separation (the noise floor).** A pair closer than the measurement noise has
``||e_i - e_j||`` made of noise, not of the state dependence, and ``s_ij ~ noise / d`` grows
without bound as ``d -> 0`` (two laps passing within a millimetre give slopes in the
hundreds). By default (``min_separation: auto``) pairs closer than
``min_separation_factor`` (3) times the noise floor are left out of the S-slope statistics.
The noise floor is estimated from the data: per axis, the white-noise standard deviation of
``e`` from second differences along each flight, ``sigma_a = 1.4826 median|D^2 e_a| / sqrt 6``
(robust to outliers; smooth bias and drift cancel to second order), weighted by the state
scale, and the largest over axes (the infinity norm). The value used and the number of pairs
it left out are in the output; ``min_separation: 0`` keeps every pair at a positive distance.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.core.artifacts import StageWriter, check_output, require_stage
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.core.references import Reference, parse_reference
from qsls.pipeline.errormodel import figures as fit_plots
from qsls.pipeline.errormodel.environments import apart
from qsls.pipeline.errormodel.model import (
    ERROR_MODEL_FILE,
    TRAINING_FILE,
    W_COLS,
    AxisStats,
    DisturbanceStats,
    ErrorModel,
    SlopeStats,
    WorstPair,
)
from qsls.pipeline.errormodel.options import FitOptions as FitOptions
from qsls.pipeline.errormodel.slopes import (
    PairSlopes,
    nearest_distance,
    pair_slopes,
    pct_name,
    percentile_table,
)
from qsls.pipeline.errormodel.training import FitData, load_fit_data, noise_floor
from qsls.pipeline.errormodel.training import same_motion as same_motion  # evaluate's twins
from qsls.pipeline.ingest.flight import AXES, E_COLS, X_COLS, read_flight, states

STAGE = "fit"
FIGURES = fit_plots.FIGURES


@dataclass(frozen=True)
class FitResult:
    out: Path
    model: ErrorModel
    noise_floor: dict[str, float]
    n_candidates: int
    warnings: tuple[str, ...] = ()
    """What the user needs to know about the model (the CLI prints each as ``warning:``)."""

    def summary(self) -> dict[str, Any]:
        m = self.model
        s = m.s_slope
        out: dict[str, Any] = {
            "flights": len(m.flights),
            "samples": m.n_samples,
            "excluded samples": m.n_excluded,
            "radius": m.radius,
            "min separation": m.min_separation,
            "pairs (counted)": m.n_pairs,
            "pairs below min separation": m.n_pairs_below_min_separation,
            "eps_e (max ||e||)": m.eps_e,
        }
        for k, v in m.eps_e_percentiles.items():
            out[f"eps_e {k}"] = v
        out["S max"] = s.max
        for k, v in s.percentiles.items():
            out[f"S {k}"] = v
        for k, v in s.local_max_percentiles.items():
            out[f"S local_{k}"] = v
        out["percentile rel. error"] = s.percentile_rel_error
        out["R0"] = m.R0
        out["delta"] = m.delta
        if m.disturbance is not None:
            out["eps_w (max ||w||)"] = f"{m.disturbance.max:.4g} ({m.disturbance.source})"
        if m.worst_pairs:
            w = m.worst_pairs[0]
            out["worst pair"] = (
                f"{w.flight} t={w.t_i:.2f}s / {w.flight_j or w.flight} t={w.t_j:.2f}s"
            )
        out["output"] = str(self.out)
        return out


# --------------------------------------------------------------------------- reference
def reference_states(options: FitOptions) -> tuple[np.ndarray | None, str | None]:
    """The reference states ``r_k`` (m, 6) and a description, or (None, None)."""
    ref = options.reference
    if ref is None:
        return None, None
    if isinstance(ref, str):
        p = Path(ref)
        if p.is_dir():
            require_stage(p, "ingest")
            df = read_flight(p)
            xr = states(df)
            xr = xr[np.isfinite(xr).all(axis=1)]
            if len(xr) == 0:
                raise InputError(f"{p}: the reference flight has no finite states")
            return xr, f"flight {p.as_posix()}"
        kinds = ("circle", "hover", "figure8")
        if ref.partition(":")[0].strip() not in kinds:
            raise InputError(
                f"reference '{ref}' is neither a flight folder nor a reference like "
                "'circle:radius=1,height=1,period=5' (kinds: circle, hover, figure8)"
            )
        ref = parse_reference(ref)

    dur = ref.natural_duration()
    t0 = 0.0 if options.reference_lead_in else float(getattr(ref, "start_s", 0.0))
    t = t0 + np.arange(0.0, dur - t0 + 0.5 * options.reference_dt, options.reference_dt)
    desc = ref.kind + ":" + ",".join(f"{k}={v}" for k, v in ref.model_dump().items() if k != "kind")
    return Reference(ref).states(t), desc


# --------------------------------------------------------------------------- bootstrap
def bootstrap_weights(flight_idx: np.ndarray, n_rep: int, block: int, seed: int) -> np.ndarray:
    """(B, n) multiplicities of a moving-block bootstrap within each flight (seeded)."""
    rng = np.random.default_rng(seed)
    n = len(flight_idx)
    W = np.zeros((n_rep, n))
    groups = [np.flatnonzero(flight_idx == k) for k in np.unique(flight_idx)]
    for b in range(n_rep):
        for idx in groups:
            m = len(idx)
            L = min(block, m)
            nblk = -(-m // L)
            starts = rng.integers(0, m - L + 1, size=nblk)
            pick = (starts[:, None] + np.arange(L)[None, :]).ravel()[:m]
            W[b] += np.bincount(idx[pick], minlength=n)
    return W


def _interval(values: np.ndarray, level: float) -> list[float]:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return [float("nan"), float("nan")]
    a = (1 - level) / 2 * 100
    lo, hi = np.percentile(v, [a, 100 - a])
    return [float(lo), float(hi)]


def _bootstrap_summary(
    enorm: np.ndarray, W: np.ndarray, ps: PairSlopes, options: FitOptions
) -> dict[str, Any]:
    qs = options.percentiles
    lvl = options.bootstrap_level
    emax: list[float] = []
    epct: dict[str, list[float]] = {pct_name(q): [] for q in qs}
    for w in W:
        sel = w > 0
        emax.append(float(enorm[sel].max()))
        vals = np.repeat(enorm[sel], w[sel].astype(np.int64))
        for q, v in zip(qs, np.percentile(vals, qs), strict=True):
            epct[pct_name(q)].append(float(v))
    bs = ps.bootstrap
    assert bs is not None
    s_int: dict[str, list[float]] = {"max": _interval(bs.max, lvl)}
    for k, v in bs.percentiles.items():
        s_int[k] = _interval(v, lvl)
    for k, v in bs.local_max_percentiles.items():
        s_int[f"local_{k}"] = _interval(v, lvl)
    return {
        "replicates": len(W),
        "seed": options.seed,
        "block_samples": options.bootstrap_block,
        "level": lvl,
        "method": "moving-block bootstrap of the samples within each flight "
        "(a pair counts w_i w_j times); percentile intervals",
        "eps_e": {"max": _interval(np.array(emax), lvl)}
        | {k: _interval(np.array(v), lvl) for k, v in epct.items()},
        "s_slope": s_int,
    }


# --------------------------------------------------------------------------- the stage
def _axis_stats(e: np.ndarray) -> dict[str, AxisStats]:
    out = {}
    for k, a in enumerate(AXES):
        v = e[:, k]
        out[a] = AxisStats(
            mean=float(v.mean()),
            std=float(v.std()),
            rms=float(np.sqrt(np.mean(v * v))),
            max_abs=float(np.abs(v).max()),
        )
    return out


@dataclass(frozen=True)
class Fitted:
    """What :func:`fit_model` estimated: the model, the kept samples' indices into the data
    and the pair slopes (for the stage's tables and figures)."""

    model: ErrorModel
    idx: np.ndarray
    slopes: PairSlopes


def fit_model(data: FitData, options: FitOptions, progress: Progress = NULL_PROGRESS) -> Fitted:
    """The error model of ``data`` under ``options`` (module docstring; docs/errormodel.md),
    nothing read or written: ``eps_e = max_i ||e_i||``, the S-slope statistics over the pairs
    within ``r``, ``R0``, ``Delta`` from the reference and the disturbance statistics."""
    names = {pct_name(q) for q in options.percentiles}
    _resolve_r0(options.r0, 0.0, dict.fromkeys(names, 0.0))  # a clear error now, not later
    tr = data
    ref_x, ref_desc = reference_states(options)
    idx = np.flatnonzero(tr.keep)
    x, e = tr.x[idx], tr.e[idx]
    _refuse_zero_error(e, tr)
    scale = np.asarray(options.state_scale, dtype=float)
    if np.any(scale <= 0):
        raise InputError(f"state scale must be 6 positive weights, got {list(scale)}")
    sigma = noise_floor(tr)
    min_sep, rule = _min_separation(options, float(np.max(sigma * scale)))
    W = None
    if options.bootstrap > 0:
        W = bootstrap_weights(
            tr.flight_idx[idx], options.bootstrap, options.bootstrap_block, options.seed
        )
    env = environment_codes(options, tr.flight_idx[idx])
    ps = pair_slopes(
        apart(x, env, scale), e, options.radius, min_separation=min_sep, state_scale=scale,
        percentiles=options.percentiles, top_k=options.top_pairs, bootstrap_weights=W,
        jobs=options.jobs, progress=progress,
    )  # fmt: skip
    if ps.n_pairs == 0:
        raise InputError(
            f"no pair of samples within radius {options.radius:g} and at least "
            f"{min_sep:.4g} apart ({ps.n_in_radius} pairs closer than the minimum separation); "
            "increase --radius or lower --min-separation"
        )
    enorm = np.abs(e).max(axis=1)
    eps_pct = percentile_table(enorm, options.percentiles)
    delta = 0.0 if ref_x is None else float(nearest_distance(x, ref_x, scale).max())
    model = ErrorModel(
        eps_e=float(enorm.max()),
        eps_e_percentiles=eps_pct,
        per_axis=_axis_stats(e),
        radius=float(options.radius),
        min_separation=float(min_sep),
        min_separation_rule=rule,
        noise_floor={a: float(v) for a, v in zip(AXES, sigma, strict=True)},
        state_scale=[float(v) for v in scale],
        s_slope=SlopeStats(
            max=ps.max,
            percentiles=ps.percentiles,
            local_max_percentiles=ps.local_max_percentiles,
            percentile_rel_error=ps.percentile_rel_error,
            n_samples_with_partners=ps.n_with_partners,
        ),
        R0=_resolve_r0(options.r0, float(enorm.max()), eps_pct),
        delta=delta,
        delta_reference=ref_desc,
        n_samples=len(idx),
        n_pairs=ps.n_pairs,
        n_pairs_below_min_separation=ps.n_below_min_separation,
        n_excluded=int(len(tr.keep) - len(idx)),
        exclusions=tr.exclusions,
        worst_pairs=_worst_pairs(tr, idx, ps),
        bootstrap=_bootstrap_summary(enorm, W, ps, options) if W is not None else None,
        flights=tr.names,
        disturbance=_disturbance_stats(tr, idx, options.percentiles),
        dt=float(tr.dt),
        plant=options.plant,
    )
    return Fitted(model, idx, ps)


def fit(
    flights: list[Path],
    options: FitOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> FitResult:
    """``qsls fit``: read ``flights``, :func:`fit_model`, write ``out`` (module docstring)."""
    flights = [Path(f) for f in flights]
    check_output(Path(out), force, flights)  # before the work, not after it
    names = {pct_name(q) for q in options.percentiles}
    _resolve_r0(options.r0, 0.0, dict.fromkeys(names, 0.0))  # a clear error before reading
    data = load_fit_data(flights, options)
    fitted = fit_model(data, options, progress)
    warnings = fit_warnings(options)
    _write(Path(out), fitted.model, data, fitted.idx, fitted.slopes, options, flights, force,
           warnings)  # fmt: skip
    return FitResult(
        out=Path(out), model=fitted.model, noise_floor=fitted.model.noise_floor,
        n_candidates=fitted.slopes.n_candidates, warnings=warnings,
    )  # fmt: skip


NO_REFERENCE = (
    "no reference given: Delta (the reference's largest distance to the training states, "
    "docs/guarantee.md) is 0, so a controller designed on this model promises nothing once "
    "the reference leaves the training states, and a calibration on such flights finds "
    "'reference' broken with no inflation covering it; give the reference flown "
    "(--reference circle:radius=1,height=1,period=5, or a flight folder), or state Delta at "
    "synthesis (--delta)"
)
"""The fit's warning when no reference gives ``Delta`` (it is then 0, not measured)."""


def fit_warnings(options: FitOptions) -> tuple[str, ...]:
    """The warnings of a fit with ``options`` (:data:`NO_REFERENCE` when no reference)."""
    return (NO_REFERENCE,) if options.reference is None else ()


def _disturbance_stats(
    tr: FitData, idx: np.ndarray, percentiles: list[float]
) -> DisturbanceStats | None:
    """Max and percentiles of ``||w_k||_inf`` over the kept samples' steps."""
    if tr.w is None:
        return None
    w = np.abs(tr.w[idx]).max(axis=1)
    w = w[np.isfinite(w)]
    if not len(w):
        return None
    return DisturbanceStats(
        max=float(w.max()), percentiles=percentile_table(w, percentiles), source=tr.w_source,
        n_steps=len(w),
    )  # fmt: skip


def _refuse_zero_error(e: np.ndarray, tr: FitData) -> None:
    """An error model of zeros (VIO equal to the truth) would certify any controller."""
    if not np.abs(e).max() > 0:
        raise InputError(
            f"every training sample of {', '.join(tr.names)} has zero error (e = y - x = 0): "
            "the VIO equals the truth, so the model would be eps_e = S = 0 and certify "
            "anything; ingest the VIO estimate against the ground truth (not one stream twice)"
        )


def _min_separation(options: FitOptions, floor: float) -> tuple[float, str]:
    """The minimum pair separation and how it was chosen (module doc, noise floor)."""
    if options.min_separation == "auto":
        min_sep = options.min_separation_factor * floor
        rule = (
            f"auto: {options.min_separation_factor:g} x noise floor {floor:.4g} "
            "(white-noise std of e from second differences, largest scaled axis)"
        )
        if min_sep >= 0.5 * options.radius:
            min_sep = 0.5 * options.radius
            rule += f"; capped at radius / 2 = {min_sep:.4g}"
        return min_sep, rule
    min_sep = float(options.min_separation)
    if min_sep >= options.radius:
        raise InputError(
            f"min separation {min_sep:g} must be smaller than the radius {options.radius:g}"
        )
    return min_sep, "given"


def _worst_pairs(tr: FitData, idx: np.ndarray, ps: PairSlopes) -> list[WorstPair]:
    x, e = tr.x[idx], tr.e[idx]
    return [
        WorstPair(
            flight=tr.names[tr.flight_idx[idx[w.i]]],
            flight_j=tr.names[tr.flight_idx[idx[w.j]]],
            t_i=float(tr.t[idx[w.i]]),
            t_j=float(tr.t[idx[w.j]]),
            x_i=[float(v) for v in x[w.i]],
            x_j=[float(v) for v in x[w.j]],
            e_i=[float(v) for v in e[w.i]],
            e_j=[float(v) for v in e[w.j]],
            distance=w.distance,
            slope=w.slope,
        )
        for w in ps.worst
    ]


def _write(
    out: Path,
    model: ErrorModel,
    tr: FitData,
    idx: np.ndarray,
    ps: PairSlopes,
    options: FitOptions,
    flights: list[Path],
    force: bool,
    warnings: tuple[str, ...] = (),
) -> None:
    """The stage folder: error_model.yaml, training_states.parquet, figures, manifest (its
    results hold the ``warnings``)."""
    x, e = tr.x[idx], tr.e[idx]
    training = pd.DataFrame(
        {"flight": [tr.names[k] for k in tr.flight_idx[idx]], "t": tr.t[idx]}
        | {c: x[:, k] for k, c in enumerate(X_COLS)}
        | {c: e[:, k] for k, c in enumerate(E_COLS)}
        | ({c: tr.w[idx, k] for k, c in enumerate(W_COLS)} if tr.w is not None else {})
        | (
            {"environment": [options.environments[k] for k in tr.flight_idx[idx]]}
            if options.environments is not None
            else {}
        )
    )
    results = {
        "eps_e": model.eps_e,
        "s_max": ps.max,
        **{f"s_{k}": v for k, v in ps.percentiles.items()},
        "n_samples": len(idx),
        "n_pairs": ps.n_pairs,
        "delta": model.delta,
        "eps_w": model.disturbance.max if model.disturbance else None,
        "dt": tr.dt,
        "warnings": list(warnings),
    }
    with StageWriter(out, STAGE, options=options, inputs=flights, force=force) as w:
        w.write_yaml(ERROR_MODEL_FILE, model)
        w.write_parquet(TRAINING_FILE, training)
        if options.figures:
            figs = fit_plots.make_figures(model, ps, tr, idx, options.percentiles)
            for name, fig in figs.items():
                w.write_figure(name, fig)
        w.results.update(results)


def environment_codes(options: FitOptions, flight_idx: np.ndarray) -> np.ndarray | None:
    """The environment code of every sample (None without ``options.environments``)."""
    if options.environments is None:
        return None
    codes = {name: k for k, name in enumerate(dict.fromkeys(options.environments))}
    per_flight = np.array([codes[n] for n in options.environments], dtype=np.int64)
    return per_flight[flight_idx]


def _resolve_r0(r0: float | str, eps_e: float, pcts: dict[str, float]) -> float:
    if isinstance(r0, int | float):
        return float(r0)
    key = str(r0).strip()
    if key in ("max", "eps_e"):
        return eps_e
    if key in pcts:
        return pcts[key]
    try:
        return float(key)
    except ValueError:
        raise InputError(
            f"r0 '{r0}': use max, a number, or one of the percentiles ({', '.join(pcts)})"
        ) from None
