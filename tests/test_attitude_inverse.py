"""The recorded command back to the model's input (qsls.pipeline.core.attitude): the inverse of
the export's attitude map, against the forward map and hand-computed cases."""

from __future__ import annotations

import math

import numpy as np

from qsls.pipeline.core.attitude import (
    absolute_input,
    demanded_force,
    force_from_attitude,
    input_from_attitude,
    input_from_force,
    thrust_newtons,
)
from qsls.pipeline.core.plant import GRAVITY, feedforward_input
from qsls.pipeline.export.attitude import AttitudeLimits, limited, thrust_attitude

MASS = 0.256


def test_round_trip_through_the_forward_map_to_1e12() -> None:
    rng = np.random.default_rng(5)
    n = 500
    u = rng.normal(0, [0.08, 0.08, 0.4], (n, 3))
    acc = rng.normal(0, [1.5, 1.5, 1.0], (n, 3))
    yaw = rng.uniform(-math.pi, math.pi, n)
    lim = AttitudeLimits()
    free = ~limited(demanded_force(absolute_input(u, acc, MASS), MASS), MASS, lim)
    assert free.sum() > 400  # the test is about unlimited commands
    thrust, q = thrust_attitude(u, acc, MASS, lim, yaw=yaw)
    want = absolute_input(u, acc, MASS)
    back = input_from_force(force_from_attitude(q, thrust), MASS)
    assert np.max(np.abs(back[free] - want[free])) < 1e-12
    hover = 0.42
    normalized = hover * thrust / (MASS * GRAVITY)
    again = input_from_attitude(q, normalized, hover, MASS)
    assert np.max(np.abs(again[free] - want[free])) < 1e-12


def test_hand_cases() -> None:
    # hover: level attitude at the hover throttle is [0, 0, m g]
    u = input_from_attitude(np.array([[0, 0, 0, 1.0]]), np.array([0.5]), 0.5, MASS)
    assert np.allclose(u, [[0, 0, MASS * GRAVITY]], atol=1e-15)
    # a rotation of +0.1 rad about body y tilts the thrust toward +x (z-up world), which the
    # paper's B reads as pitch -f_x / (m g) < 0 (docs/model.md, signs)
    th = 0.1
    q = np.array([[0.0, math.sin(th / 2), 0.0, math.cos(th / 2)]])
    u = input_from_attitude(q, np.array([0.5]), 0.5, MASS)
    assert np.allclose(u, [[-math.sin(th), 0.0, MASS * GRAVITY * math.cos(th)]], atol=1e-15)
    # a rotation about body x by +0.1 tilts toward -y: roll f_y / (m g) < 0
    q = np.array([[math.sin(th / 2), 0.0, 0.0, math.cos(th / 2)]])
    u = input_from_attitude(q, np.array([0.5]), 0.5, MASS)
    assert np.allclose(u, [[0.0, -math.sin(th), MASS * GRAVITY * math.cos(th)]], atol=1e-15)
    # a 90 deg yaw does not change the input: R(q) e3 is yaw-free
    qz = np.array([[0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]])
    u = input_from_attitude(qz, np.array([0.6]), 0.5, MASS)
    assert np.allclose(u, [[0, 0, 1.2 * MASS * GRAVITY]], atol=1e-14)
    assert np.allclose(thrust_newtons(np.array([0.25]), 0.5, MASS), [MASS * GRAVITY / 2])


def test_feedforward_is_the_inverse_of_b_on_the_velocity_rows() -> None:
    a = np.array([[0.3, -1.2, 0.7]])
    assert np.allclose(feedforward_input(a, MASS), [[-0.3 / GRAVITY, -1.2 / GRAVITY, MASS * 0.7]])
