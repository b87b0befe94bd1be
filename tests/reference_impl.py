"""Naive reference computations the tests and benchmarks check the library against; no
stage uses them, so they live here rather than in ``pipeline/`` (issue 49)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from qsls.pipeline.core.rotations import matrix_to_quat


def brute_force_slopes(
    x: np.ndarray,
    e: np.ndarray,
    radius: float,
    *,
    min_separation: float = 0.0,
    state_scale: Sequence[float] | np.ndarray | None = None,
    chunk: int = 256,
    keep: bool = True,
) -> tuple[np.ndarray | None, float, int]:
    """Chunked all-pairs computation (the naive way, against which the pair engine
    :func:`qsls.pipeline.errormodel.slopes.pair_slopes` is checked and timed).

    Returns (all counted slopes in row-major pair order if ``keep``, their max, their count).
    """
    x = np.asarray(x, dtype=np.float64)
    e = np.asarray(e, dtype=np.float64)
    scale = np.ones(x.shape[1]) if state_scale is None else np.asarray(state_scale, float)
    xs = x * scale
    lo_sep = float(min_separation) if min_separation > 0 else float(np.nextafter(0.0, 1.0))
    out, mx, cnt = [], -np.inf, 0
    n = len(x)
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        d = np.abs(xs[a:b, None, :] - xs[None, a + 1 :, :]).max(axis=2)
        de = np.abs(e[a:b, None, :] - e[None, a + 1 :, :]).max(axis=2)
        # only j > i
        tri = np.arange(a + 1, n)[None, :] > np.arange(a, b)[:, None]
        m = tri & (d < radius) & (d >= lo_sep)
        s = de[m] / d[m]
        cnt += len(s)
        if len(s):
            mx = max(mx, float(s.max()))
            if keep:
                out.append(s)
    allv = np.concatenate(out) if (keep and out) else (np.zeros(0) if keep else None)
    return allv, (mx if cnt else float("nan")), cnt


def thrust_attitudes(acc: np.ndarray, gravity: float = 9.81) -> np.ndarray:
    """Quaternions (n, 4) xyzw of a multirotor with zero yaw whose thrust axis (body z)
    points along ``acc + g e_z`` (what it must to fly accelerations ``acc`` (n, 3))."""
    zb = acc + np.array([0.0, 0.0, gravity])
    zb /= np.linalg.norm(zb, axis=1, keepdims=True)
    yb = np.cross(zb, np.array([1.0, 0.0, 0.0]))
    yb /= np.linalg.norm(yb, axis=1, keepdims=True)
    xb = np.cross(yb, zb)
    return matrix_to_quat(np.stack([xb, yb, zb], axis=2))
