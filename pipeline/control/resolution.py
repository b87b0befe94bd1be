"""A synthesis problem resolved: the options' names (``max``, ``lofo``, ``p95``...) looked up
on the error model and its training states, every number of the premise, and the premise's
record with the share of the training data violating each number
(:mod:`qsls.pipeline.control.premise`). Pure (:func:`resolve`); :func:`read_model` is what a
stage reads for it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.guarantee import PremiseNumbers
from qsls.pipeline.premise.numbers import grouped_premise
from qsls.pipeline.control.options import ProblemOptions
from qsls.pipeline.control.premise import Premise, group_record, premise_record
from qsls.pipeline.core.artifacts import sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import LinearModel, plant_model
from qsls.pipeline.errormodel import honest
from qsls.pipeline.errormodel.model import (
    TRAINING_FILE,
    ErrorModel,
    error_model_file,
    load_error_model,
)
from qsls.pipeline.errormodel.premise import Measured, Spec, TrainingStates, training_beside


@dataclass(frozen=True)
class Resolved:
    """A problem's numbers, names resolved against the error model and its training data:
    the premise's numbers (:class:`PremiseNumbers`, the one form the guarantee's arithmetic,
    the synthesis and the certificate read) and their record with how each was chosen and the
    share of the training data violating it (:class:`Premise`), the plant, the cost's weights
    and the premise's shape (weights, channels)."""

    model: LinearModel
    Q: np.ndarray
    R: np.ndarray
    numbers: PremiseNumbers
    shape: sls.Shape = field(default_factory=sls.Shape)
    premise: Premise | None = None

    def values(self, nominal: sls.Taps | None = None) -> sls.Values:
        return sls.Values(Q=self.Q, R=self.R, numbers=self.numbers, nominal=nominal)

    def structure(
        self, T: int, norm: sls.Norm, cost: Any, robust: bool, sp_: bool
    ) -> sls.Structure:
        sh = self.shape
        return sls.Structure(
            T, norm, cost, robust, sp_, state_scale=sh.state_scale, error_scale=sh.error_scale,
            measure=sh.measure, m=sh.m, gate=sh.gate and robust, bias=sh.bias,
        )  # fmt: skip

    def record(self) -> dict[str, Any]:
        """The premise's numbers as a certificate states them."""
        p = self.numbers
        return {
            "S": p.S, "eps_e": p.eps, "radius": p.radius, "delta": p.delta, "eps_w": p.eps_w,
            "R0": p.R0, "m": p.m, "eps_o": p.eps_o, "measure": self.shape.measure, "gate": p.gate,
            "eps_b": p.eps_b,
        }  # fmt: skip


def _how(value: Any) -> str:
    return "number" if isinstance(value, int | float) else str(value)


def _needs_model(what: str, v: Any, em: ErrorModel | None) -> ErrorModel:
    if em is None:
        raise InputError(
            f"{what} = '{v}' names a number of an error model, but none was given; "
            "pass --model or give a number"
        )
    return em


def _eps(
    opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None, trivial: bool
) -> float:
    v = opts.eps_e
    if isinstance(v, int | float):
        return float(v)
    em = _needs_model("eps_e", v, em)
    if meas is not None:
        key = str(v).strip()
        if key == "max":
            return meas.eps
        if key.startswith("p"):
            try:
                return float(np.percentile(meas.dense, float(key[1:])))
            except ValueError:
                pass
    elif not trivial:
        raise InputError(
            "eps_e: with measure, beta or error_scale set, the dense bound is measured on the "
            "training states, but the error model has none beside it; pass the fit folder (in Python: TrainingStates)"
        )
    return em.resolve_eps_e(v)


def _slope(opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None) -> float:
    v = opts.S
    if isinstance(v, int | float):
        return float(v)
    em = _needs_model("S", v, em)
    if str(v).strip() != "lofo":
        return em.resolve_s(v)
    if meas is None:
        raise InputError(
            "S = lofo is measured on the training states beside the error model, which are "
            "missing; pass the fit folder (in Python: TrainingStates), or give S as a number"
        )
    if math.isnan(meas.slope.S):
        raise InputError(
            "S = lofo leaves one training flight out at a time and needs at least two in one "
            "environment; fit on more flights, or give S as a number (the premise is then "
            "untested: relaxed)"
        )
    if not math.isfinite(meas.slope.S):
        raise InputError(
            "S = lofo is infinite: a left-out sample exceeds the other flights' largest error at "
            "distance 0 from them; give S as a number (relaxed) or raise beta / error_scale"
        )
    return meas.slope.S


def _disturbance(
    opts: ProblemOptions, em: ErrorModel | None, meas: Measured | None
) -> tuple[float, str]:
    """``eps_w``: a number, or the training flights' realized disturbance ``||H^-1 w_k||``."""
    v = opts.eps_w
    if isinstance(v, int | float):
        return float(v), "number"
    name = "max" if v is None else str(v).strip()
    if meas is not None and meas.w_norm is not None:
        q = None if name == "max" else _percentile(name, "eps_w")
        w = meas.eps_w(q)
        if w is not None:
            return w, name
    if v is None and (em is None or em.disturbance is None):
        return 0.01, "default (assumed, not measured)"
    if em is None:
        raise InputError(f"eps_w = '{v}' needs an error model; pass --model or give a number")
    if opts.H is not None:
        raise InputError(
            "eps_w with H: the disturbance is measured as ||H^-1 w|| on the training states, "
            "which are missing beside the error model; pass the fit folder (in Python: "
            "TrainingStates) or give a number"
        )
    return em.resolve_eps_w(name), name


def _group_bounds(
    opts: ProblemOptions, eps: float, meas: Measured | None, spec: Spec
) -> dict[str, float]:
    """``eps_g`` for every measured channel group (docs/guarantee.md, Channel groups) when
    ``eps_groups`` is set: a number, ``max`` (the group's training maximum of ``|d_g|_e``) or
    ``clip`` (velocities: ``max_j w_e,j beta``, which ``d = clip_beta(e)`` never exceeds); a
    group not named keeps ``eps``. Empty when ``eps_groups`` is not set."""
    if not opts.eps_groups:
        return {}
    measured = honest.measured_channels(opts.measure)
    out: dict[str, float] = {}
    for g, channels in honest.GROUPS.items():
        if not set(channels) <= set(measured):
            if g in opts.eps_groups:
                raise InputError(
                    f"eps_groups: {g} is not measured (measure: {opts.measure}); drop it"
                )
            continue
        v = opts.eps_groups.get(g, eps)  # type: ignore[call-overload]
        if v == "clip":
            if g != "velocity" or opts.beta is None:
                raise InputError(
                    f"eps_groups: {g}: clip is the velocity group's clip level w_e,v beta; "
                    "it needs beta (and applies to velocity only)"
                )
            v = max(spec.error_scale[j] for j in channels) * float(opts.beta)
        elif v == "max":
            if meas is None:
                raise InputError(
                    f"eps_groups: {g}: max is measured on the training states beside the error "
                    "model, which are missing; pass the fit folder or give a number"
                )
            v = float(meas.groups[g].max())
        if not float(v) > 0:
            raise InputError(f"eps_groups: {g}'s bound is {v}; need a number > 0")
        out[g] = float(v)
    return out


def _percentile(name: str, what: str) -> float:
    try:
        if name.startswith("p"):
            return float(name[1:])
    except ValueError:
        pass
    raise InputError(f"{what} = '{name}': use max, pNN or a number")


def resolve(
    opts: ProblemOptions, em: ErrorModel | None, training: TrainingStates | None = None
) -> Resolved:
    """Numbers for every setting, names (``max``, ``lofo``, ``p95``...) looked up on the error
    model and its training states, and the premise they form with its violated shares (pure:
    no file is read)."""
    if opts.radius is not None:
        radius = float(opts.radius)
    elif em is not None:
        radius = float(em.radius)
    else:
        raise InputError("radius: give a number (no error model to take it from)")
    if em is not None and em.plant != opts.plant:
        raise InputError(
            f"plant {opts.plant}: the error model's disturbance was measured through the "
            f"{em.plant} plant; synthesize with plant: {em.plant}, or refit with plant: {opts.plant}"
        )
    if em is not None and em.dt is not None and abs(em.dt - opts.dt) > 1e-9 * max(em.dt, 1.0):
        raise InputError(
            f"dt {opts.dt:g} s: the error model was fitted on flights sampled every {em.dt:g} s "
            "(its windows, outlier counts and eps_w are per step of that length); synthesize "
            f"with --dt {em.dt:g}, or ingest the training flights at {opts.dt:g} s and refit"
        )
    if opts.H is not None and abs(np.linalg.det(np.asarray(opts.H))) < 1e-12:
        raise InputError(
            "H must be invertible: eps_w bounds ||H^-1 w|| of the realized disturbance"
        )
    state_scale = tuple(em.state_scale) if em is not None else (1.0,) * 6
    spec = Spec(
        measure=opts.measure, beta=math.inf if opts.beta is None else float(opts.beta),
        state_scale=state_scale, error_scale=tuple(opts.error_scale), radius=radius,
        window=opts.T, risk=opts.outlier_risk,
        H=None if opts.H is None else tuple(tuple(r) for r in opts.H),
    )  # fmt: skip
    trivial = (
        opts.measure == "full" and opts.beta is None and all(w == 1.0 for w in opts.error_scale)
    )
    meas = training.measured(spec) if em is not None and training is not None else None
    where = None
    if em is not None:
        where = (
            training.source if training is not None
            else f"no {TRAINING_FILE} beside the error model: shares not computed"
        )  # fmt: skip
    eps_e = _eps(opts, em, meas, trivial)
    S = _slope(opts, em, meas)
    for name, val in (("S", S), ("eps_e", eps_e)):
        if not (math.isfinite(val) and val >= 0):
            raise InputError(
                f"{name} = '{getattr(opts, name)}' is {val}; need a finite number >= 0"
            )
    bounds = _group_bounds(opts, eps_e, meas, spec)
    groups_at = meas
    if bounds:
        eps_e, S, scale = grouped_premise(spec.error_scale, bounds, S)
        spec = replace(spec, error_scale=scale)
        meas = training.measured(spec) if meas is not None and training is not None else None
    eps_w, how_w = _disturbance(opts, em, meas)
    outlier_ch = opts.measure == "full" and opts.beta is not None
    if not outlier_ch:
        m = 0
    elif opts.m == "auto":
        m = meas.outliers.m if meas is not None else 0
    else:
        m = int(opts.m)
    if opts.gate is not None and not outlier_ch:
        raise InputError("gate: a velocity gate needs measure: full and beta (it bounds outliers)")
    if opts.gate is not None and opts.eps_o is not None:
        raise InputError("give gate or eps_o, not both: the gate sets eps_o = 2 gate - beta")
    if outlier_ch and opts.eps_o is None and opts.gate is None:
        raise InputError(
            "beta clips the velocity errors, so what it clips off is an outlier: give eps_o, a "
            "bound on one outlier from the estimator's physics, or a velocity gate (never the "
            "sample maximum)"
        )
    if opts.gate is not None:
        assert opts.beta is not None
        if 2 * opts.gate <= opts.beta:
            raise InputError(f"gate {opts.gate:g} must exceed beta / 2 = {opts.beta / 2:g}")
        eps_o = 2 * opts.gate - opts.beta
    else:
        eps_o = float(opts.eps_o or 0.0) if outlier_ch else 0.0
    if opts.delta is None:
        delta = float(em.delta) if em is not None else 0.0
    elif isinstance(opts.delta, int | float):
        delta = float(opts.delta)
    elif opts.delta == "delta" and em is not None:
        delta = float(em.delta)
    else:
        raise InputError(
            f"delta = '{opts.delta}': give a number (or omit it to use the error model's)"
        )
    # R0: the error bound in use unless set, so that gamma_strict <= gamma
    R0 = eps_e if opts.R0 is None else (
        float(opts.R0) if isinstance(opts.R0, int | float) else em.resolve_eps_e(opts.R0)  # type: ignore[union-attr]
    )  # fmt: skip
    from_em = "error model" if em is not None else "default"
    how = {
        "eps_e": _how(opts.eps_e) if not bounds else "groups", "S": _how(opts.S), "eps_w": how_w,
        "m": "binomial" if opts.m == "auto" else "number",
        "eps_o": "gate (2V - beta)" if opts.gate is not None else "given",
        "r": from_em if opts.radius is None else "number",
        "Delta": from_em if opts.delta is None else _how(opts.delta),
    }  # fmt: skip
    chosen = PremiseNumbers(eps_e, S, radius, eps_w, delta, eps_o, m, R0, opts.gate, opts.eps_b)
    premise = premise_record(chosen, how, meas, em, where, group_record(groups_at, bounds))
    H = None if opts.H is None else np.asarray(opts.H)
    model = plant_model(opts.plant, dt=opts.dt, mass=opts.mass, H=H)
    extra = model.nx - len(state_scale)  # the attitude plant's states: unweighted, unmeasured
    shape = sls.Shape(
        (*state_scale, *(0.0,) * extra), (*spec.error_scale, *(1.0,) * extra), opts.measure, m,
        opts.gate is not None, opts.eps_b > 0,
    )  # fmt: skip
    return Resolved(
        model, pad_weight(np.asarray(opts.Q), model.nx), np.asarray(opts.R), chosen, shape, premise
    )


EXTRA_STATE_WEIGHT = 1e-6
"""The cost's weight on the attitude plant's extra states: Q stays positive definite, the
cost is the user's on the physical states."""


def pad_weight(Q: np.ndarray, n: int) -> np.ndarray:
    """``Q`` (6 x 6) on the first states of an ``n``-state plant, :data:`EXTRA_STATE_WEIGHT`
    on the rest of the diagonal."""
    if Q.shape[0] == n:
        return Q
    out = np.eye(n) * EXTRA_STATE_WEIGHT
    out[: Q.shape[0], : Q.shape[1]] = Q
    return out


@dataclass(frozen=True)
class ModelInput:
    """What a stage reads for its error model: the model, the sha256 of ``error_model.yaml``,
    the file, and the training states beside it (each None when absent)."""

    model: ErrorModel | None = None
    sha256: str | None = None
    file: Path | None = None
    training: TrainingStates | None = None

    @property
    def inputs(self) -> list[Path]:
        return [self.file] if self.file is not None else []


def read_model(path: Path | None) -> ModelInput:
    """The error model of ``path`` (a fit folder or its ``error_model.yaml``) and the training
    states beside it, read once; empty without a path."""
    if path is None:
        return ModelInput()
    f = error_model_file(path)
    return ModelInput(load_error_model(f), sha256_file(f), f, training_beside(f))
