"""The controller as a filter bank (Anderson, Doyle, Low, Matni 2019, output feedback).

From FIR responses ``Phi_xx, Phi_ux, Phi_xy, Phi_uy`` (taps ``0..T``) the controller
``u = K y`` is realized with an internal state ``beta``::

    z beta = Phi~_xx beta + Phi~_xy y,     u = Phi~_ux beta + Phi_uy y,
    Phi~_xx = z (I - z Phi_xx),  Phi~_ux = z Phi_ux,  Phi~_xy = -z Phi_xy,

which, tap by tap (``Phi_xx(1) = I``), is::

    beta[k+1] = - sum_{j=0}^{T-2} Phi_xx(j+2) beta[k-j] - sum_{j=0}^{T-1} Phi_xy(j+1) y[k-j]
    u[k]      =   sum_{j=0}^{T-1} Phi_ux(j+1) beta[k-j] + sum_{j=0}^{T}   Phi_uy(j)   y[k-j]

a finite memory of ``T`` past ``beta`` and ``T+1`` past ``y``. Unlike the compact form
``(I + Phi_ux B)^-1 Phi_uy`` (poles at z = 1 on this plant), every internal signal of this
realization is stable: a perturbation of its memory dies out.

Units and signs (docs/conventions.md#state-input-and-measurement): ``y`` is the measurement minus the reference state,
``u`` the deviation of ``[pitch, roll, thrust]`` from hover plus feedforward, paper signs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control.sls import Taps, side_by_side


@dataclass(frozen=True)
class FilterBank:
    """The realization's matrices, taps side by side, newest first.

    ``K_bb`` ``(nx, (T-1) nx)`` = ``-[Phi_xx(2) .. Phi_xx(T)]``,
    ``K_by`` ``(nx, T ny)`` = ``-[Phi_xy(1) .. Phi_xy(T)]``,
    ``K_ub`` ``(nu, T nx)`` = ``[Phi_ux(1) .. Phi_ux(T)]``,
    ``K_uy`` ``(nu, (T+1) ny)`` = ``[Phi_uy(0) .. Phi_uy(T)]``.
    """

    K_bb: np.ndarray
    K_by: np.ndarray
    K_ub: np.ndarray
    K_uy: np.ndarray

    @property
    def nx(self) -> int:
        return self.K_bb.shape[0]

    @property
    def nu(self) -> int:
        return self.K_ub.shape[0]

    @property
    def ny(self) -> int:
        return self.K_uy.shape[1] // (self.T + 1)

    @property
    def T(self) -> int:
        return self.K_ub.shape[1] // self.K_bb.shape[0]

    def arrays(self) -> dict[str, np.ndarray]:
        return {"K_bb": self.K_bb, "K_by": self.K_by, "K_ub": self.K_ub, "K_uy": self.K_uy}


def filter_bank(taps: Taps) -> FilterBank:
    """The realization's matrices from the responses (see the module docstring)."""
    return FilterBank(
        K_bb=-side_by_side(taps.Phi_xx[2:]),
        K_by=-side_by_side(taps.Phi_xy[1:]),
        K_ub=side_by_side(taps.Phi_ux[1:]),
        K_uy=side_by_side(taps.Phi_uy),
    )


class RealizedController:
    """The filter bank as a runtime: ``reset()``, then ``step(y) -> u`` once per ``dt``.

    ``step`` also takes ``(ny, m)`` arrays to run ``m`` independent copies at once (the
    certificate's impulse tests); the memory is then ``m`` columns wide.
    """

    def __init__(
        self,
        bank: FilterBank,
        dt: float,
        *,
        certificate: dict[str, Any] | None = None,
        strictly_proper: bool | None = None,
        name: str = "",
    ) -> None:
        self.bank = bank
        self.dt = float(dt)
        self.certificate = dict(certificate or {})
        self.name = name
        nu, ny = bank.nu, bank.ny
        if strictly_proper is None:
            strictly_proper = bool(np.all(bank.K_uy[:, :ny] == 0))
        self.strictly_proper = bool(strictly_proper)
        self._nx, self._nu, self._ny, self._T = bank.nx, nu, ny, bank.T
        self.reset()

    def reset(self, batch: int = 1) -> None:
        """Zero memory (``beta = 0``, past ``y = 0``)."""
        T, nx, ny = self._T, self._nx, self._ny
        self.beta = np.zeros((T * nx, batch))  # beta[k], beta[k-1], .., beta[k-T+1]
        self.ys = np.zeros(((T + 1) * ny, batch))  # y[k], y[k-1], .., y[k-T]

    def step(self, y: np.ndarray) -> np.ndarray:
        """``u[k]`` from ``y[k]`` (and the memory); then advance ``beta``."""
        y = pad_measurement(np.asarray(y, dtype=float), self._ny)
        single = y.ndim == 1
        col = y.reshape(self._ny, -1)
        if col.shape[1] != self.beta.shape[1]:
            self.reset(col.shape[1])
        nx, ny, b = self._nx, self._ny, self.bank
        self.ys[ny:] = self.ys[:-ny]
        self.ys[:ny] = col
        u = b.K_ub @ self.beta + b.K_uy @ self.ys
        nxt = b.K_bb @ self.beta[:-nx] + b.K_by @ self.ys[:-ny]
        self.beta[nx:] = self.beta[:-nx]
        self.beta[:nx] = nxt
        return u[:, 0] if single else u


class StaticGainController:
    """``u = K y`` (the PD reference controller), with the same interface."""

    def __init__(
        self, K: np.ndarray, dt: float, *, certificate: dict | None = None, name: str = "pd"
    ) -> None:
        self.K = np.asarray(K, dtype=float)
        self.dt = float(dt)
        self.certificate = dict(certificate or {})
        self.strictly_proper = False
        self.name = name

    def reset(self, batch: int = 1) -> None:
        pass

    def step(self, y: np.ndarray) -> np.ndarray:
        return self.K @ pad_measurement(np.asarray(y, dtype=float), self.K.shape[1])


def pad_measurement(y: np.ndarray, ny: int) -> np.ndarray:
    """``y`` with zeros for the channels past its own: a controller of the attitude plant has
    ``ny`` channels, the physical ones first, and never reads the others (docs/model.md)."""
    if y.shape[0] >= ny:
        return y
    pad = np.zeros((ny - y.shape[0], *y.shape[1:]))
    return np.concatenate([y, pad], axis=0)
