"""The premise with a vector of bounds, one per channel group (docs/guarantee.md, Channel groups):
the scalar premise in per-group weights imposes exactly the row-wise vector condition, and a
synthesis with ``eps_groups`` certifies against it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qsls.pipeline.control.guarantee import system_norms
from qsls.pipeline.control.synth import SynthOptions, synthesize
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.model import ErrorModel, SlopeStats
from qsls.pipeline.premise.choose import ModelInput
from qsls.pipeline.premise.measure import TrainingStates
from qsls.pipeline.premise.numbers import grouped_premise

W_X = (1.0, 1.0, 1.0, 0.5, 0.5, 0.5)
W_E = (1.0, 1.0, 1.0, 0.5, 0.5, 0.5)


def _worst_deviation(phi_xy: np.ndarray, bounds: dict[int, float]) -> float:
    """The largest ``|x_k|_x`` that errors with ``|d_j| <= bounds[j]`` can force through
    ``x = Phi_xy * d``, by construction: for each row the sign-matched error sequence, convolved
    tap by tap (independent of the norms' code)."""
    taps = phi_xy.shape[0]
    best = 0.0
    for i in range(phi_xy.shape[1]):
        d = np.zeros((taps, phi_xy.shape[2]))  # d[k]: the error k ticks before the end
        for t in range(taps):
            for j, b in bounds.items():
                d[t, j] = np.sign(phi_xy[t, i, j]) * b
        x_i = sum(phi_xy[t, i, :] @ d[t] for t in range(taps))
        best = max(best, W_X[i] * abs(x_i))
    return best


def test_the_scalar_premise_in_group_weights_is_the_vector_condition():
    rng = np.random.default_rng(3)
    phi = rng.normal(0, 0.3, (9, 6, 6))
    bounds = {"position": 0.15, "velocity": 0.05}
    eps, S, scale = grouped_premise(W_E, bounds, 0.0)
    assert eps == 0.15 and S == 0.0
    assert scale == pytest.approx((1, 1, 1, 0.5 * 3, 0.5 * 3, 0.5 * 3))
    # |d_j| <= eps_g / w_e,j, per group
    per_channel = {j: (0.15 if j < 3 else 0.05) / W_E[j] for j in range(6)}
    worst = _worst_deviation(phi, per_channel)
    grouped = eps * system_norms(phi, phi, state_scale=W_X, error_scale=scale).N
    scalar = eps * system_norms(phi, phi, state_scale=W_X, error_scale=W_E).N
    assert grouped == pytest.approx(worst, rel=1e-12)
    assert grouped < 0.8 * scalar  # the scalar premise charges velocities at eps, three times more


def test_the_slope_cover_is_sound():
    eps, S, scale = grouped_premise(W_E, {"position": 0.2, "velocity": 0.05}, 0.1)
    assert pytest.approx(0.1 * 0.2 / 0.05) == S
    rng = np.random.default_rng(0)
    dist = rng.uniform(0, 2, 1000)
    for g, b, ch in (("position", 0.2, 0), ("velocity", 0.05, 3)):
        d = (b + 0.1 * dist) / W_E[ch]  # a group's error at its vector bound
        assert np.all(scale[ch] * d <= eps + S * dist + 1e-12), g


def _training(n=600, seed=1):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, 6))
    flight = np.repeat(np.arange(3), n // 3)
    e = np.hstack([0.03 * np.sin(2 * x[:, :3]), 0.15 * np.sin(3 * x[:, 3:])])
    e[::50, 3] = 0.6  # a few velocity outliers beyond beta
    return TrainingStates(x, e, flight, rng.uniform(-0.005, 0.005, x.shape))


def _em(tr: TrainingStates) -> ErrorModel:
    return ErrorModel(eps_e=0.2, radius=1.5, s_slope=SlopeStats(max=1.0), R0=0.0, delta=0.05,
                      n_samples=len(tr.x), n_pairs=0)  # fmt: skip


def test_a_synthesis_with_group_bounds_certifies_on_the_vector_condition():
    tr = _training()
    base = dict(T=15, S=0.0, eps_e=0.06, controllers="single", measure="full", beta=0.2, gate=0.6,
                error_scale=W_E, eps_w=0.005, radius=1.5, m=2)  # fmt: skip
    plain = (
        synthesize(ModelInput(_em(tr), training=tr), SynthOptions(**base))
        .controllers["l1_robust"]
        .certificate
    )
    opts = SynthOptions(**base, eps_groups={"velocity": "clip"})
    cert = synthesize(ModelInput(_em(tr), training=tr), opts).controllers["l1_robust"].certificate
    p = cert.premise
    assert p is not None and p.groups is not None
    assert p.groups["velocity"]["bound"] == pytest.approx(0.5 * 0.2)  # w_e,v beta
    assert p.groups["position"]["bound"] == pytest.approx(0.06)
    # eps = max_g eps_g, each group's channels weighted by eps / eps_g
    assert p.eps_e.value == pytest.approx(0.1) and p.eps_e.chosen == "groups"
    # position bound 0.06 < clip level 0.1: positions weighted 0.1 / 0.06, velocities keep 0.5
    assert p.error_scale == pytest.approx([0.1 / 0.06] * 3 + [0.5] * 3)
    # d = clip_beta(e) never exceeds the clip level: no training sample violates the group bound
    assert p.eps_e.violated == 0.0
    # the scalar premise had to take eps >= 0.1 too (or be violated): with eps 0.06 it is
    assert plain.premise is not None and plain.premise.eps_e.violated > 0
    assert cert.rho_star is not None and math.isfinite(cert.rho_star)


def test_group_bounds_that_cannot_hold_are_refused():
    tr = _training()
    with pytest.raises(InputError, match="needs beta"):
        synthesize(ModelInput(_em(tr), training=tr), SynthOptions(T=6, S=0.0, eps_e=0.1, eps_w=0.005, radius=1.5,
                                             controllers="single",
                                             eps_groups={"velocity": "clip"}))  # fmt: skip
    with pytest.raises(InputError, match="not measured"):
        synthesize(ModelInput(_em(tr), training=tr), SynthOptions(T=6, S=0.0, eps_e=0.1, eps_w=0.005, radius=1.5,
                                             controllers="single", measure="position",
                                             eps_groups={"velocity": 0.1}))  # fmt: skip
