"""The premise chosen (docs/guarantee.md, The premise package): the options' names (``max``,
``lofo``, ``p95``...) looked up on the error model and its training states, every number of the
premise (:class:`~qsls.pipeline.premise.numbers.PremiseNumbers`) and its record with the share of
the training data violating each number (:class:`~qsls.pipeline.premise.record.Premise`).

:func:`choose_premise` is pure (no file is read); :func:`read_model` is what a stage reads for
it: the error model and the training states beside it. Control receives what it returns and
never opens the error model itself.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from qsls.pipeline.core.artifacts import sha256_file
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import GROUPS, measured_channels
from qsls.pipeline.errormodel.model import (
    TRAINING_FILE,
    ErrorModel,
    error_model_file,
    load_error_model,
)
from qsls.pipeline.premise.measure import ONES, Measured, Spec, TrainingStates, training_beside
from qsls.pipeline.premise.numbers import PremiseNumbers, grouped_premise
from qsls.pipeline.premise.record import Premise, group_record, premise_record


class PremiseSettings(Protocol):
    """The settings a premise is chosen from (``ProblemOptions``'s premise fields, read only)."""

    @property
    def eps_e(self) -> float | str: ...
    @property
    def S(self) -> float | str: ...
    @property
    def eps_w(self) -> float | str | None: ...
    @property
    def eps_groups(self) -> Mapping[Any, float | str] | None: ...
    @property
    def radius(self) -> float | None: ...
    @property
    def delta(self) -> float | str | None: ...
    @property
    def R0(self) -> float | str | None: ...
    @property
    def eps_o(self) -> float | None: ...
    @property
    def eps_b(self) -> float: ...
    @property
    def m(self) -> int | str: ...
    @property
    def gate(self) -> float | None: ...
    @property
    def beta(self) -> float | None: ...
    @property
    def measure(self) -> str: ...
    @property
    def error_scale(self) -> Sequence[float]: ...
    @property
    def outlier_risk(self) -> float: ...
    @property
    def H(self) -> Sequence[Sequence[float]] | None: ...
    @property
    def T(self) -> int: ...
    @property
    def plant(self) -> str: ...
    @property
    def dt(self) -> float: ...


# --------------------------------------------------------------------------- the error model's names
_PCT = re.compile(r"^p(\d+(?:\.\d+)?)$")


def lookup_s(em: ErrorModel, name: str | float) -> float:
    """The S-slope called ``name`` (``max``, ``p95``, ``local_p99``) or a number."""
    if isinstance(name, int | float):
        return float(name)
    key = str(name).strip()
    if key == "max":
        return em.s_slope.max
    table, what = em.s_slope.percentiles, "s_slope.percentiles"
    if key.startswith("local_"):
        table, what, key = (
            em.s_slope.local_max_percentiles,
            "s_slope.local_max_percentiles",
            key[6:],
        )
    return _lookup(table, key, what, name)


def lookup_eps_w(em: ErrorModel, name: str | float) -> float:
    """The disturbance bound called ``name`` (``max``, ``pNN``) or a number."""
    if isinstance(name, int | float):
        return float(name)
    if em.disturbance is None:
        raise InputError(
            f"eps_w '{name}': this error model has no measured disturbance; refit it "
            "with this qsls or give eps_w as a number"
        )
    key = str(name).strip()
    if key == "max":
        return em.disturbance.max
    return _lookup(em.disturbance.percentiles, key, "disturbance.percentiles", name)


def lookup_eps_e(em: ErrorModel, name: str | float) -> float:
    """The error bound called ``name`` (``max``, ``p99``, ``R0``) or a number."""
    if isinstance(name, int | float):
        return float(name)
    key = str(name).strip()
    if key == "max":
        return em.eps_e
    if key == "R0":
        return em.R0
    return _lookup(em.eps_e_percentiles, key, "eps_e_percentiles", name)


def _lookup(table: dict[str, float], key: str, what: str, name: Any) -> float:
    if not _PCT.match(key):
        raise InputError(f"'{name}' is not a name in the error model (use max, pNN or local_pNN)")
    if key not in table:
        have = ", ".join(sorted(table)) or "none"
        raise InputError(
            f"'{name}' is not in the error model's {what} (it has: {have}); refit with --percentiles"
        )
    return float(table[key])


def largest_pair_slope(em: ErrorModel | None) -> float:
    """``S_hat``: the error model's largest pair slope (the paper's estimator; inf without one)."""
    return lookup_s(em, "max") if em is not None else math.inf


# --------------------------------------------------------------------------- each number
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
    opts: PremiseSettings, em: ErrorModel | None, meas: Measured | None, trivial: bool
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
    return lookup_eps_e(em, v)


def _slope(opts: PremiseSettings, em: ErrorModel | None, meas: Measured | None) -> float:
    v = opts.S
    if isinstance(v, int | float):
        return float(v)
    em = _needs_model("S", v, em)
    if str(v).strip() != "lofo":
        return lookup_s(em, v)
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
    opts: PremiseSettings, em: ErrorModel | None, meas: Measured | None
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
    return lookup_eps_w(em, name), name


def _group_bounds(
    opts: PremiseSettings, eps: float, meas: Measured | None, spec: Spec
) -> dict[str, float]:
    """``eps_g`` for every measured channel group (docs/guarantee.md, Channel groups) when
    ``eps_groups`` is set: a number, ``max`` (the group's training maximum of ``|d_g|_e``) or
    ``clip`` (velocities: ``max_j w_e,j beta``, which ``d = clip_beta(e)`` never exceeds); a
    group not named keeps ``eps``. Empty when ``eps_groups`` is not set."""
    if not opts.eps_groups:
        return {}
    measured = measured_channels(opts.measure)
    out: dict[str, float] = {}
    for g, channels in GROUPS.items():
        if not set(channels) <= set(measured):
            if g in opts.eps_groups:
                raise InputError(
                    f"eps_groups: {g} is not measured (measure: {opts.measure}); drop it"
                )
            continue
        v = opts.eps_groups.get(g, eps)
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


# --------------------------------------------------------------------------- the premise
def _check_setting(opts: PremiseSettings, em: ErrorModel | None) -> None:
    """The plant, ``dt`` and ``H`` the premise is measured in: the error model's."""
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


def _spec(opts: PremiseSettings, em: ErrorModel | None) -> Spec:
    """The norms, channels, clip and window the premise is measured in; its radius ``r``."""
    if opts.radius is not None:
        radius = float(opts.radius)
    elif em is not None:
        radius = float(em.radius)
    else:
        raise InputError("radius: give a number (no error model to take it from)")
    return Spec(
        measure=opts.measure, beta=math.inf if opts.beta is None else float(opts.beta),
        state_scale=tuple(em.state_scale) if em is not None else ONES,
        error_scale=tuple(opts.error_scale), radius=radius, window=opts.T,
        risk=opts.outlier_risk, H=None if opts.H is None else tuple(tuple(r) for r in opts.H),
    )  # fmt: skip


def _outliers(opts: PremiseSettings, meas: Measured | None) -> tuple[int, float]:
    """``(m, eps_o)``: the outlier count per window and the bound on one outlier (given, or
    ``2 V - beta`` from a velocity gate ``V``); ``(0, 0)`` without an outlier channel."""
    outlier_ch = opts.measure == "full" and opts.beta is not None
    if opts.gate is not None and not outlier_ch:
        raise InputError("gate: a velocity gate needs measure: full and beta (it bounds outliers)")
    if opts.gate is not None and opts.eps_o is not None:
        raise InputError("give gate or eps_o, not both: the gate sets eps_o = 2 gate - beta")
    if not outlier_ch:
        return 0, 0.0
    if opts.eps_o is None and opts.gate is None:
        raise InputError(
            "beta clips the velocity errors, so what it clips off is an outlier: give eps_o, a "
            "bound on one outlier from the estimator's physics, or a velocity gate (never the "
            "sample maximum)"
        )
    auto = meas.outliers.m if meas is not None else 0
    m = auto if opts.m == "auto" else int(opts.m)
    if opts.gate is None:
        return m, float(opts.eps_o or 0.0)
    assert opts.beta is not None
    if 2 * opts.gate <= opts.beta:
        raise InputError(f"gate {opts.gate:g} must exceed beta / 2 = {opts.beta / 2:g}")
    return m, 2 * opts.gate - opts.beta


def _delta(opts: PremiseSettings, em: ErrorModel | None) -> float:
    """``Delta``: a number, or the error model's."""
    if opts.delta is None:
        return float(em.delta) if em is not None else 0.0
    if isinstance(opts.delta, int | float):
        return float(opts.delta)
    if opts.delta == "delta" and em is not None:
        return float(em.delta)
    raise InputError(f"delta = '{opts.delta}': give a number (or omit it to use the error model's)")


def _how_chosen(
    opts: PremiseSettings, em: ErrorModel | None, grouped: bool, how_w: str
) -> dict[str, str]:
    from_em = "error model" if em is not None else "default"
    return {
        "eps_e": _how(opts.eps_e) if not grouped else "groups", "S": _how(opts.S), "eps_w": how_w,
        "m": "binomial" if opts.m == "auto" else "number",
        "eps_o": "gate (2V - beta)" if opts.gate is not None else "given",
        "r": from_em if opts.radius is None else "number",
        "Delta": from_em if opts.delta is None else _how(opts.delta),
    }  # fmt: skip


def choose_premise(
    error_model: ErrorModel | None, training: TrainingStates | None, options: PremiseSettings
) -> tuple[PremiseNumbers, Premise]:
    """The premise's numbers for every setting of ``options``, names (``max``, ``lofo``,
    ``p95``...) looked up on the error model and its training states, and the premise they form
    with the norms it is stated in and its violated shares (pure: no file is read)."""
    em, opts = error_model, options
    spec = _spec(opts, em)
    _check_setting(opts, em)
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
    m, eps_o = _outliers(opts, meas)
    delta = _delta(opts, em)
    # R0: the error bound in use unless set, so that gamma_strict <= gamma
    R0 = eps_e if opts.R0 is None else (
        float(opts.R0) if isinstance(opts.R0, int | float) else lookup_eps_e(em, opts.R0)  # type: ignore[arg-type]
    )  # fmt: skip
    how = _how_chosen(opts, em, bool(bounds), how_w)
    numbers = PremiseNumbers(
        eps_e, S, spec.radius, eps_w, delta, eps_o, m, R0, opts.gate, opts.eps_b
    )
    premise = premise_record(numbers, how, spec, meas, em, where, group_record(groups_at, bounds))
    return numbers, premise


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
