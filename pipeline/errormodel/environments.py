"""Training flights of several environments (rooms, frames) in one state space: each
environment's positions laid apart (:func:`apart`), so that no pair search within a radius
pairs states of two environments (the fit's pair slopes; docs/errormodel.md)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

ENVIRONMENT_SEPARATION = 1e6
"""How far apart (in the weighted state norm) :func:`apart` lays two environments: farther than
any radius a premise uses, so no pair within ``r`` crosses environments."""


def apart(
    x: np.ndarray, environment: np.ndarray | None, state_scale: Sequence[float] | np.ndarray
) -> np.ndarray:
    """The states with environment ``k``'s positions shifted by ``k`` times
    :data:`ENVIRONMENT_SEPARATION` (weighted): a pair search within ``r`` then never pairs
    states of two environments (``x`` itself when there is one)."""
    x = np.asarray(x, float)
    if environment is None or not np.any(environment):
        return x
    w = np.asarray(state_scale, float)
    shift = np.asarray(environment, float)[:, None] * (ENVIRONMENT_SEPARATION / w[None, :3])
    out = x.copy()
    out[:, :3] += shift
    return out
