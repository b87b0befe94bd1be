"""A synthesis problem: the premise chosen (:func:`qsls.pipeline.premise.choose.choose_premise`)
with the plant it is posed on, the cost's weights and the premise's norms as the problem reads
them (:class:`~qsls.pipeline.control.sls.Shape`). Pure (:func:`resolve`); the error model and
its training states arrive as one :class:`~qsls.pipeline.premise.choose.ModelInput`, which
control hands to the premise unopened."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.options import ProblemOptions
from qsls.pipeline.core.plant import LinearModel, plant_model
from qsls.pipeline.premise.choose import ModelInput, choose_premise
from qsls.pipeline.premise.numbers import PremiseNumbers
from qsls.pipeline.premise.record import Premise

NO_MODEL = ModelInput()
"""No error model: the premise is the options' numbers alone, which no data tested."""


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


def premise_shape(
    numbers: PremiseNumbers, premise: Premise | None, measure: str, nx: int
) -> sls.Shape:
    """The premise's norms as an ``nx``-state problem reads them: ``W_x``, ``W_e`` (the
    attitude plant's extra states unweighted and unmeasured), the channels, ``m``, the gate and
    the bias term."""
    wx = premise.state_scale if premise is not None else (1.0,) * 6
    we = premise.error_scale if premise is not None else (1.0,) * 6
    extra = nx - len(wx)
    return sls.Shape(
        (*wx, *(0.0,) * extra), (*we, *(1.0,) * extra), measure, numbers.m,
        numbers.gate is not None, numbers.eps_b > 0,
    )  # fmt: skip


def resolve(opts: ProblemOptions, source: ModelInput = NO_MODEL) -> Resolved:
    """The problem of ``opts``: its premise chosen from ``source``'s error model and training
    states (:func:`~qsls.pipeline.premise.choose.choose_premise`), the plant, ``Q``, ``R`` and
    the premise's norms (pure: no file is read)."""
    numbers, premise = choose_premise(source.model, source.training, opts)
    H = None if opts.H is None else np.asarray(opts.H)
    model = plant_model(opts.plant, dt=opts.dt, mass=opts.mass, H=H)
    shape = premise_shape(numbers, premise, opts.measure, model.nx)
    Q = pad_weight(np.asarray(opts.Q), model.nx)
    return Resolved(model, Q, np.asarray(opts.R), numbers, shape, premise)


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
