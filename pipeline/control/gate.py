"""The velocity gate a gated controller reads through (docs/guarantee.md#velocity-gate).

``y'_v = clip(y_v - v_ref, -V, V)``: the measured velocity deviation clipped to ``[-V, V]``
before the filter bank sees it. One rule for every place that runs a controller: the
simulator (:class:`qsls.pipeline.sim.controllers.LinearController`), the export's check of
its generated code against the Python realization (:mod:`qsls.pipeline.export.stage`), and
the generated step itself (docs/export.md#the-velocity-gate-inside-the-step). Only numpy:
the simulator imports it without the synthesis stack.
"""

from __future__ import annotations

import numpy as np


def gated_deviation(dev: np.ndarray, gate: float | None) -> np.ndarray:
    """The deviation a gated controller reads (docs/guarantee.md, Velocity gate): the velocity
    deviation clipped to ``[-V, V]``, ``clip(y_v - v_ref, -V, V)``; a copy, rows or one tick."""
    dev = np.array(dev, dtype=float)
    if gate is not None:
        dev[..., 3:] = np.clip(dev[..., 3:], -gate, gate)
    return dev
