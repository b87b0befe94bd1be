"""The four closed-loop responses as FIR taps, and their norms (docs/synthesis.md#norms).

Taps ``k = 0..T`` of ``x = Phi_xx (H w) + Phi_xy e``, ``u = Phi_ux (H w) + Phi_uy e``. The
induced inf-to-inf norm of an FIR operator is the largest row sum of absolute values over all
its taps side by side (:func:`l1_norm`); H2 is the Frobenius norm over all taps
(:func:`h2_norm`). Kept apart from the synthesis (:mod:`qsls.pipeline.control.sls`) so the
guarantee's arithmetic (:mod:`qsls.pipeline.control.guarantee`) reads the norms without
importing the solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RESPONSES = ("Phi_xx", "Phi_ux", "Phi_xy", "Phi_uy")


@dataclass(frozen=True)
class Taps:
    """The four responses, each ``(T+1, rows, cols)`` with tap ``k`` at index ``k``."""

    Phi_xx: np.ndarray
    Phi_ux: np.ndarray
    Phi_xy: np.ndarray
    Phi_uy: np.ndarray

    @property
    def T(self) -> int:
        return self.Phi_xx.shape[0] - 1

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in RESPONSES}

    def truncated(self, T: int) -> Taps:
        """The first ``T+1`` taps (zero-padded when shorter)."""
        out = {}
        for name, a in self.arrays().items():
            b = np.zeros((T + 1, *a.shape[1:]))
            n = min(T + 1, a.shape[0])
            b[:n] = a[:n]
            out[name] = b
        return Taps(**out)


def side_by_side(taps: np.ndarray) -> np.ndarray:
    """``(K, r, c)`` taps -> ``(r, K c)``: ``[Phi(0) Phi(1) ... ]``."""
    k, r, c = taps.shape
    return np.transpose(taps, (1, 0, 2)).reshape(r, k * c)


def l1_norm(taps: np.ndarray, right: np.ndarray | None = None) -> float:
    """Induced inf-to-inf norm of an FIR operator: the largest absolute row sum over all
    taps side by side (of ``Phi(k) @ right`` when ``right`` is given)."""
    t = taps if right is None else taps @ right
    return float(np.abs(t).sum(axis=(0, 2)).max())


def h2_norm(taps: np.ndarray) -> float:
    """H2 norm of an FIR operator: the Frobenius norm over all taps."""
    return float(np.sqrt(np.sum(taps * taps)))
