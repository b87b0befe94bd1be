"""The guarantee on held-out flights: ``||e_k||`` against the certified bounds (DESIGN.md,
Closed-loop evaluation; paper, Bounded Perception Error Guarantee).

For a controller certified with an S-slope ``S``, error bound ``eps_e`` (and ``R0``), process
noise ``eps_w`` and responses ``Phi``, the guarantee is (DESIGN.md, Robust synthesis)::

    ||e|| <= gamma        = (eps_e + S a) / (1 - S ||Phi_xy||),  a = eps_w ||Phi_xx H|| + Delta
    ||e|| <= gamma_strict = R0 / (1 - S ||Phi_xy||)              (the paper's comparison)

``Delta`` is how far the flown states stray from the training states. The paper dropped it as
"difficult to calculate"; here it is measured: for every held-out sample ``k`` the distance
``d_k = min_i ||x_k - x_i||`` (infinity norm of the error model's scaled state) to the nearest
training state, with a KD-tree over the training states. ``gamma_k`` uses ``Delta = d_k`` for
sample ``k``; since ``d_k`` already includes the part of the deviation the perception error
itself causes, this is at least as large as the theorem's ``a``: a conservative, data-driven
reading of the bound. A flight's ``gamma`` is the largest ``gamma_k`` over the flight.

Both bounds rest on an assumption about the perception error away from the training data,
the S-slope: ``||e(x) - e(x_d)|| <= S ||x - x_d||`` within radius ``r`` of a training state
``x_d`` with ``||e(x_d)|| <= eps_e``, hence ``||e_k|| <= eps_e + S d_k`` (the *premise*). When
a bound fails the check says whether the premise failed on the flight (the certified S or
eps_e is too small for where the vehicle went: the assumption is violated) or whether the
bound failed although its premise held (which the theory rules out; look for a bug or a
flight outside the radius).

Outputs (``evaluate``): ``evaluation.parquet`` (one row per flight and controller),
``evaluation.json`` (the same rows, per-controller totals, warnings), ``samples.parquet``
(per-sample ``||e_k||``, ``d_k``, ``gamma_k`` for the report) and figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, load_controller_dir
from qsls.pipeline.control.sls import l1_norm
from qsls.pipeline.core.artifacts import StageWriter, require_stage, sha256_file, sha256_path
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.model import (
    ErrorModel,
    error_model_file,
    load_error_model,
)
from qsls.pipeline.evaluate.mismatch import flight_mismatches, skipped_controller_folders
from qsls.pipeline.evaluate.table import Evaluation
from qsls.pipeline.evaluate.training import TrainingData, load_training
from qsls.pipeline.ingest.flight import errors, read_flight, states


class EvaluateOptions(Options):
    """Options of the bound check (``qsls evaluate``)."""

    smooth_s: float = 1.0
    """Time constant (s) of the first-order average drawn over ``||e||`` in the figures
    (the paper's figure used 1 s); 0 draws the raw signal only. Numbers are never smoothed."""
    state_scale: tuple[float, float, float, float, float, float] | None = None
    """Per-coordinate weights of the state distance; default: the error model's."""
    figures: bool = True
    """Write the PNG figures."""
    max_figure_flights: int = 12
    """At most this many flights get a panel in the figures (all are in the tables)."""


# --------------------------------------------------------------------------- controllers
@dataclass(frozen=True)
class ControllerBound:
    """What the bound check needs from one controller folder's certificate."""

    name: str
    folder: Path
    status: str
    robust: bool
    S: float
    eps_e: float
    R0: float
    eps_w: float
    norm_phi_xx_h: float
    norm_phi_xy: float
    radius: float
    delta: float
    gamma_certificate: float
    model_sha256: str | None
    robustness_lhs: float | None = None
    certificate: dict[str, Any] = field(repr=False, default_factory=dict)

    @property
    def denominator(self) -> float:
        """``1 - S ||Phi_xy||``; the bound's formula is finite only when positive."""
        return 1.0 - self.S * self.norm_phi_xy

    @property
    def finite(self) -> bool:
        return self.denominator > 0

    @property
    def no_guarantee_reason(self) -> str | None:
        """Why the theorem does not apply to this controller (``None``: it does)."""
        if not self.finite:
            return f"S*||Phi_xy|| = {self.S * self.norm_phi_xy:.3g} >= 1"
        if self.status in ("failed", "solver_inaccurate"):
            return f"certificate status '{self.status}'"
        if self.robustness_lhs is not None and self.robustness_lhs >= 1.0:
            return f"robustness condition not met (lhs {self.robustness_lhs:.3g} >= 1)"
        return None

    @property
    def has_guarantee(self) -> bool:
        """The theorem applies: finite bound, a verified controller, and the robustness
        condition met (lhs < 1, the certificate's ``robustness_lhs``); a nominal or PD
        controller usually misses the last."""
        return self.no_guarantee_reason is None

    @property
    def gamma_strict(self) -> float:
        """``R0 / (1 - S ||Phi_xy||)`` (inf when ``S ||Phi_xy|| >= 1``)."""
        return self.R0 / self.denominator if self.finite else math.inf

    def gamma_at(self, distance: np.ndarray) -> np.ndarray:
        """``gamma_k = (eps_e + S (eps_w ||Phi_xx H|| + d_k)) / (1 - S ||Phi_xy||)``."""
        d = np.asarray(distance, dtype=float)
        if not self.finite:
            return np.full(d.shape, math.inf)
        a = self.eps_w * self.norm_phi_xx_h + d
        return (self.eps_e + self.S * a) / self.denominator

    def premise_at(self, distance: np.ndarray) -> np.ndarray:
        """The S-slope premise ``eps_e + S d_k``: the error the assumption allows at ``x_k``."""
        return self.eps_e + self.S * np.asarray(distance, dtype=float)


def load_controller_bound(folder: Path) -> ControllerBound:
    """The bound's numbers from a verified controller folder (:func:`load_controller_dir`):
    the setting from its certificate, the norms ``||Phi_xy||`` and ``||Phi_xx H||`` recomputed
    from its responses."""
    d = load_controller_dir(folder)
    c, taps = d.certificate, d.controller.taps
    return ControllerBound(
        name=d.name,
        folder=d.folder,
        status=c.status,
        robust=c.robust,
        S=c.S,
        eps_e=c.eps_e,
        R0=c.R0,
        eps_w=c.eps_w,
        norm_phi_xx_h=l1_norm(taps.Phi_xx, d.controller.model.H),
        norm_phi_xy=l1_norm(taps.Phi_xy),
        radius=c.radius,
        delta=c.delta,
        gamma_certificate=c.gamma,
        model_sha256=c.error_model_sha256,
        robustness_lhs=c.robustness_lhs,
        certificate=c.model_dump(),
    )


def load_bounds(folders: Sequence[Path]) -> list[ControllerBound]:
    """Every folder's bound, names made unique (``<synth folder>-<controller>`` on a clash,
    e.g. two synth outputs that both hold ``l1_robust``)."""
    from collections import Counter
    from dataclasses import replace

    bounds = [load_controller_bound(f) for f in folders]
    counts = Counter(b.name for b in bounds)
    return [
        replace(b, name=f"{b.folder.parent.name}-{b.name}") if counts[b.name] > 1 else b
        for b in bounds
    ]


def check_model_hash(bound: ControllerBound, model_file: Path, *, force: bool) -> str | None:
    """Compare the controller's recorded error-model hash with ``model_file``'s.

    Returns a warning (hash differs and ``force``, or no hash recorded), ``None`` when they
    match; raises :class:`InputError` when they differ and not ``force``.
    """
    if bound.model_sha256 is None:
        return f"{bound.name}: certificate records no error-model hash; cannot check it was certified against this model"
    ours = {sha256_file(model_file), sha256_path(model_file.parent)}
    if bound.model_sha256 in ours:
        return None
    msg = (
        f"{bound.name}: certified against error model {bound.model_sha256[:12]}, "
        f"but --model is {sha256_file(model_file)[:12]}"
    )
    if not force:
        raise InputError(msg + "; pass the model it was certified with, or --force to check anyway")
    return msg + " (checked anyway: --force)"


# --------------------------------------------------------------------------- the check
def check_flight(
    name: str,
    flight: pd.DataFrame,
    bound: ControllerBound,
    training: TrainingData,
    nearest: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[dict[str, Any], pd.DataFrame]:
    """One flight against one controller's bounds: the table row and the per-sample frame."""
    x = states(flight)
    e = errors(flight)
    t = flight["t"].to_numpy(float)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(e).all(axis=1)
    if not ok.any():
        raise InputError(f"flight {name}: no samples with finite states and errors")
    d, idx = nearest if nearest is not None else training.nearest(x[ok])
    x, e, t, n_dropped = x[ok], e[ok], t[ok], int((~ok).sum())
    e_norm = np.abs(e).max(axis=1)
    gamma_k = bound.gamma_at(d)
    gamma_strict = bound.gamma_strict
    premise_k = bound.premise_at(d)
    inside = d < bound.radius
    ratio, ratio_strict, premise_ratio = _ratios(e_norm, gamma_k, gamma_strict, premise_k)
    k_ratio = int(np.argmax(ratio))
    k_err = int(np.argmax(e_norm))
    k_dist = int(np.argmax(d))
    k_prem = int(np.argmax(premise_ratio))
    max_slope = _max_slope_to_training(e, d, idx, inside, training)
    bound_holds = bool(np.all(e_norm <= gamma_k)) if bound.finite else False
    strict_holds = bool(np.all(e_norm <= gamma_strict))
    premise_holds = bool(np.all(premise_ratio <= 1.0))
    frac_premise = float(np.mean(premise_ratio <= 1.0))
    within_radius = bool(np.all(inside))
    verdict = _verdict(
        bound,
        bound_holds,
        strict_holds,
        premise_holds,
        within_radius,
        float(premise_ratio[k_prem]),
        float(t[k_prem]),
        max_slope,
        frac_premise,
    )
    row = {
        "flight": name,
        "controller": bound.name,
        "status": bound.status,
        "robust": bound.robust,
        "S": bound.S,
        "eps_e": bound.eps_e,
        "R0": bound.R0,
        "norm_phi_xy": bound.norm_phi_xy,
        "norm_phi_xx_h": bound.norm_phi_xx_h,
        "has_guarantee": bound.has_guarantee,
        "gamma": float(gamma_k.max()),
        "gamma_min": float(gamma_k.min()),
        "gamma_certificate": bound.gamma_certificate,
        "gamma_strict": gamma_strict,
        "max_error_norm": float(e_norm[k_err]),
        "max_error_norm_t": float(t[k_err]),
        "rms_error_norm": float(np.sqrt(np.mean(e_norm**2))),
        "n_samples": len(t),
        "n_nonfinite_dropped": n_dropped,
        "frac_under_gamma": float(np.mean(e_norm <= gamma_k)),
        "frac_under_gamma_strict": float(np.mean(e_norm <= gamma_strict)),
        "max_ratio": float(ratio[k_ratio]),
        "max_ratio_t": float(t[k_ratio]),
        "max_ratio_px": float(x[k_ratio, 0]),
        "max_ratio_py": float(x[k_ratio, 1]),
        "max_ratio_pz": float(x[k_ratio, 2]),
        "max_ratio_strict": float(np.max(ratio_strict)),
        "max_distance_to_training": float(d[k_dist]),
        "max_distance_t": float(t[k_dist]),
        "mean_distance_to_training": float(d.mean()),
        "radius": bound.radius,
        "frac_within_radius": float(np.mean(inside)),
        "frac_premise_holds": frac_premise,
        "max_premise_ratio": float(premise_ratio[k_prem]),
        "max_premise_ratio_t": float(t[k_prem]),
        "max_slope_to_training": max_slope,
        "bound_holds": bound_holds,
        "strict_bound_holds": strict_holds,
        "assumption_holds": premise_holds and within_radius,
        "verdict": verdict,
    }
    samples = pd.DataFrame(
        {
            "flight": name,
            "controller": bound.name,
            "t": t,
            "error_norm": e_norm,
            "distance": d,
            "gamma": gamma_k,
            "gamma_strict": np.full(len(t), gamma_strict),
            "premise": premise_k,
        }
    )
    return row, samples


def _ratios(
    e_norm: np.ndarray, gamma_k: np.ndarray, gamma_strict: float, premise_k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``||e_k||`` over ``gamma_k``, over ``gamma_strict`` and over the premise ``eps_e + S d_k``
    (0 where a bound is infinite)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(gamma_k), e_norm / gamma_k, 0.0)
        strict = e_norm / gamma_strict if math.isfinite(gamma_strict) else np.zeros_like(e_norm)
        return ratio, strict, e_norm / premise_k


def _max_slope_to_training(
    e: np.ndarray, d: np.ndarray, idx: np.ndarray, inside: np.ndarray, training: TrainingData
) -> float:
    """``max_k ||e_k - e_i(k)|| / d_k`` to the nearest training state ``i(k)`` within the
    radius and beyond the model's minimum separation (NaN without training errors)."""
    if training.e is None:
        return math.nan
    use = (d > max(training.min_separation, 1e-9)) & inside
    if not np.any(use):
        return math.nan
    return float((np.abs(e - training.e[idx]).max(axis=1)[use] / d[use]).max())


def _verdict(
    bound: ControllerBound,
    holds: bool,
    strict_holds: bool,
    premise_holds: bool,
    within_radius: bool,
    premise_ratio: float,
    premise_t: float,
    max_slope: float,
    frac_premise: float = 0.0,
) -> str:
    if not bound.finite:
        return (
            f"no bound: S*||Phi_xy|| = {bound.S * bound.norm_phi_xy:.3g} >= 1 "
            "(not certified for this S)"
        )
    problems = []
    if not bound.has_guarantee:
        problems.append(
            f"no guarantee: {bound.no_guarantee_reason}, the formula's value is shown for comparison"
        )
    if not premise_holds:
        slope = f", held-out slope to training {max_slope:.3g} > S" if max_slope > bound.S else ""
        problems.append(
            f"assumption violated at {100 * (1 - frac_premise):.1f}% of samples: ||e|| reaches "
            f"{premise_ratio:.3g}x eps_e + S*d at t={premise_t:.2f}s (certified S={bound.S:.3g}, "
            f"eps_e={bound.eps_e:.3g} are too small for this flight{slope})"
        )
    if not within_radius:
        problems.append(f"flight leaves the radius r={bound.radius:.3g} around the training states")
    if holds and strict_holds:
        head = "holds"
    elif holds:
        head = "holds (strict bound exceeded)"
    else:
        head = "FAILS"
    if problems:
        return f"{head}; " + "; ".join(problems)
    if not holds:
        return f"{head} although its assumptions hold on this flight"
    return head


# --------------------------------------------------------------------------- stage
@dataclass(frozen=True)
class EvaluateResult:
    out: Path
    table: pd.DataFrame
    warnings: tuple[str, ...]

    def summary(self) -> dict[str, Any]:
        t = self.table
        out: dict[str, Any] = {
            "output": self.out.as_posix(),
            "flights": int(t["flight"].nunique()),
            "controllers": int(t["controller"].nunique()),
        }
        for c, g in t.groupby("controller", sort=False):
            out[f"{c}"] = (
                f"gamma_strict {g['gamma_strict'].iloc[0]:.4g}, max ||e|| {g['max_error_norm'].max():.4g}, "
                f"under gamma {100 * g['frac_under_gamma'].mean():.1f}%, "
                f"under strict {100 * g['frac_under_gamma_strict'].mean():.1f}%, "
                f"max ratio {g['max_ratio'].max():.3g}"
            )
        if self.warnings:
            out["warnings"] = len(self.warnings)
        return out


def resolve_model(path: Path) -> tuple[Path, Path]:
    """``(error_model.yaml, fit folder)`` from either."""
    f = error_model_file(path)
    return f, f.parent


def expand_controllers(folders: Sequence[Path]) -> list[Path]:
    """Controller folders; a synth output folder stands for every controller inside it."""
    out: list[Path] = []
    for f in folders:
        f = Path(f)
        if not f.is_dir():
            raise InputError(f"{f}: no such controller folder")
        if (f / CERTIFICATE_FILE).is_file():
            out.append(f)
            continue
        inner = sorted(p for p in f.iterdir() if p.is_dir() and (p / CERTIFICATE_FILE).is_file())
        if not inner:
            raise InputError(
                f"{f}: no {CERTIFICATE_FILE} (and no controller folders inside); pass a "
                "controller folder written by 'qsls synth'"
            )
        out.extend(inner)
    return out


def load_flights(folders: Sequence[Path]) -> list[tuple[str, pd.DataFrame]]:
    """Read held-out flights (flight folders or ``flight.parquet`` files), unique names."""
    if not folders:
        raise InputError("no flights given; pass at least one --flights folder from 'qsls ingest'")
    out: list[tuple[str, pd.DataFrame]] = []
    seen: dict[str, int] = {}
    for f in folders:
        f = Path(f)
        df = read_flight(f)
        base = f.name if f.is_dir() else f.parent.name
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}_{seen[base]}"
        out.append((name, df))
    return out


def bound_check(
    flights: Sequence[tuple[str, pd.DataFrame]],
    bounds: Sequence[ControllerBound],
    training: TrainingData,
    *,
    pairs: Sequence[tuple[int, int]] | None = None,
    progress: Progress = NULL_PROGRESS,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every flight against every controller (or the given ``(flight, controller)`` index
    pairs): ``(rows, samples)``. Nearest distances are computed once per flight."""
    if pairs is None:
        pairs = [(i, j) for i in range(len(flights)) for j in range(len(bounds))]
    progress.start("bound check", total=len(pairs))
    nearest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    rows, samples = [], []
    for i, j in pairs:
        name, df = flights[i]
        if i not in nearest:
            x = states(df)
            ok = np.isfinite(x).all(axis=1) & np.isfinite(errors(df)).all(axis=1)
            if not ok.any():
                raise InputError(f"flight {name}: no samples with finite states and errors")
            nearest[i] = training.nearest(x[ok])
        row, s = check_flight(name, df, bounds[j], training, nearest[i])
        rows.append(row)
        samples.append(s)
        progress.advance()
    progress.finish()
    return pd.DataFrame(rows), pd.concat(samples, ignore_index=True)


def controller_totals(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per controller over all its flights: the worst case and the fractions."""
    out = []
    for c, g in table.groupby("controller", sort=False):
        out.append(
            {
                "controller": c,
                "flights": len(g),
                "gamma_strict": float(g["gamma_strict"].iloc[0]),
                "gamma_max": float(g["gamma"].max()),
                "max_error_norm": float(g["max_error_norm"].max()),
                "frac_under_gamma": float(g["frac_under_gamma"].mean()),
                "frac_under_gamma_strict": float(g["frac_under_gamma_strict"].mean()),
                "max_ratio": float(g["max_ratio"].max()),
                "bound_holds_all": bool(g["bound_holds"].all()),
                "assumption_holds_all": bool(g["assumption_holds"].all()),
            }
        )
    return out


def evaluate(
    flights: Sequence[Path],
    error_model: Path,
    controllers: Sequence[Path],
    options: EvaluateOptions,
    out: Path,
    *,
    force: bool = False,
    progress: Progress = NULL_PROGRESS,
) -> EvaluateResult:
    """The bound check of every held-out flight against every controller's certificate."""
    model_file, fit_dir = resolve_model(error_model)
    model = load_error_model(model_file)
    folders = expand_controllers(controllers)
    if not folders:
        raise InputError("no controllers given; pass at least one --controller folder")
    bounds = load_bounds(folders)
    warnings = [w for b in bounds if (w := check_model_hash(b, model_file, force=force))]
    training = load_training(fit_dir, model, options.state_scale)
    held_out = load_flights(flights)
    warnings += skipped_controller_folders(controllers)
    warnings += flight_mismatches(held_out, bounds, training)
    for f in flights:
        try:
            require_stage(Path(f) if Path(f).is_dir() else Path(f).parent, "ingest")
        except InputError as exc:
            warnings.append(str(exc))
    table, samples = bound_check(held_out, bounds, training, progress=progress)
    return write_evaluation(
        out,
        table,
        samples,
        warnings,
        options=options,
        inputs=[model_file, *folders, *[Path(f) for f in flights]],
        model=model,
        force=force,
    )


def write_evaluation(
    out: Path,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    *,
    options: EvaluateOptions,
    inputs: Sequence[Path],
    model: ErrorModel,
    force: bool,
) -> EvaluateResult:
    """Write the stage folder: ``evaluation.parquet``, ``evaluation.json``,
    ``samples.parquet`` and figures."""
    with StageWriter(out, "evaluate", options=options, inputs=inputs, force=force) as w:
        totals = write_tables(w, table, samples, warnings, model, options)
        w.results.update(
            {
                "flights": int(table["flight"].nunique()),
                "controllers": totals,
                "warnings": len(warnings),
            }
        )
    return EvaluateResult(out=Path(out), table=table, warnings=tuple(warnings))


def write_tables(
    w: StageWriter,
    table: pd.DataFrame,
    samples: pd.DataFrame,
    warnings: Sequence[str],
    model: ErrorModel,
    options: EvaluateOptions,
    extra_json: dict[str, Any] | None = None,
    *,
    own_only: bool = False,
) -> list[dict[str, Any]]:
    """The bound check's files inside an open writer; returns the per-controller totals.
    ``own_only``: figures show each flight against the controller that flew it only."""
    totals = controller_totals(table) if len(table) else []
    w.write_parquet("samples.parquet", samples)
    doc = {
        "error_model": {
            "eps_e": model.eps_e,
            "R0": model.R0,
            "S_max": model.s_slope.max,
            "radius": model.radius,
            "state_scale": list(model.state_scale),
        },
        "controllers": totals,
        "rows": table.to_dict(orient="records"),
        "warnings": list(warnings),
        **(extra_json or {}),
    }
    Evaluation(table, doc).save(w)
    if options.figures and len(samples):
        from qsls.pipeline.evaluate import figures as plots

        sub = samples
        if own_only and "flown_by" in samples.columns:
            sub = samples[samples["controller"] == samples["flown_by"]]
        names = list(dict.fromkeys(sub["flight"]))[: options.max_figure_flights]
        sub = sub[sub["flight"].isin(names)]
        if not own_only:
            w.write_figure(
                "perception_error.png", plots.perception_error_figure(sub, options.smooth_s)
            )
        w.write_figure("distance_to_training.png", plots.distance_figure(sub, model.radius))
    return totals
