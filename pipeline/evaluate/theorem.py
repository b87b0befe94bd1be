"""The guarantee checked the way the theorem states it, on a flight flown by the certified
controller (docs/evaluation.md, docs/guarantee.md#the-closed-loop-split-in-two; paper, Bounded
Perception Error Guarantee).

With the controller in the loop the state splits into what the vehicle would have done
without perception error and the controller's response to that error::

    x = x_hat + Phi_xy * e,      x_hat_k = x_k - sum_{t=0}^{T} Phi_xy(t) e_{k-t}

(``e_j = 0`` before the flight starts: the controller starts from rest). If the premise
``||e(x)|| <= eps_e + S min_d ||W (x - x_d)||`` holds within the radius ``r`` of the training
states ``x_d`` (``W = diag(state_scale)``, errors unweighted, infinity norms, as the S-slope is
fitted), then with ``a = max_k min_d ||W (x_hat_k - x_d)||``::

    ||e_k|| <= eps_e + S (||W (x_hat_k - x_d)|| + ||W (Phi_xy * e)_k||)
            <= eps_e + S a + S ||W Phi_xy|| ||e||
    =>  ||e|| <= gamma_nominal = (eps_e + S a) / (1 - S ||W Phi_xy||)

``a`` here is ``a_nominal``, measured on the flight (the certificate bounds it a priori by
``eps_w ||Phi_xx H|| + Delta``). The verdict ``bound_holds = max_k ||e_k|| <= gamma_nominal`` is a
test of the controller: unlike a per-sample bound with the *flown* state's distance ``d_k``
(which holds wherever the premise holds), it can fail while the premise holds, when the
controller's response to the error is larger than its certified ``||Phi_xy||`` allows.

On the linear plant the split is exact. On the RotorPy vehicle, ``x_hat`` is what the
linear closed loop attributes to the reference and the disturbances; the model mismatch is
part of that disturbance, as it is in the certificate's ``eps_w``.

The theorem applies to a flight only when the certified controller flew it; for a recorded
log or another controller's flight only the premise is checked (how well the error model
generalizes), and the theorem columns are empty.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from qsls.pipeline.control import guarantee
from qsls.pipeline.control.taps import l1_norm
from qsls.pipeline.premise.numbers import PremiseNumbers

THEOREM_COLUMNS: tuple[str, ...] = (
    "theorem_applies",
    "a_nominal",
    "a_nominal_t",
    "a_certificate",
    "norm_phi_xy_weighted",
    "gamma_nominal",
    "nominal_ratio",
    "nominal_within_radius",
    "n_nominal_undefined",
)
"""The columns :func:`theorem_check` adds to a bound-check row (NaN / NA where it does not
apply); ``bound_holds`` is the verdict itself."""


def nominal_states(x: np.ndarray, e: np.ndarray, phi_xy: np.ndarray) -> np.ndarray:
    """``x_hat_k = x_k - sum_{t=0}^{T} Phi_xy(t) e_{k-t}`` with ``e_j = 0`` for ``j < 0``.

    ``x`` and ``e`` are ``(n, nx)`` and ``(n, ny)`` samples on the controller's own time grid,
    ``phi_xy`` the ``(T+1, nx, ny)`` taps. A non-finite ``e_j`` makes ``x_hat_k`` NaN for
    ``k = j .. j+T`` (the convolution is undefined there).
    """
    x = np.asarray(x, dtype=float)
    e = np.asarray(e, dtype=float)
    phi = np.asarray(phi_xy, dtype=float)
    if x.ndim != 2 or e.ndim != 2 or len(x) != len(e):
        raise ValueError("x and e must be (n, nx) and (n, ny) arrays of the same length")
    out = x.copy()
    n = len(x)
    for t in range(min(phi.shape[0], n)):
        if np.any(phi[t]):
            out[t:] -= e[: n - t] @ phi[t].T
    return out


def weighted_l1_norm(phi_xy: np.ndarray, scale: Sequence[float] | np.ndarray) -> float:
    """``||W Phi_xy||``: the induced infinity norm from unweighted errors to weighted states."""
    w = np.asarray(scale, dtype=float)
    return l1_norm(w[None, :, None] * np.asarray(phi_xy, dtype=float))


def uniform_grid(t: np.ndarray, dt: float, rel: float = 1e-3) -> bool:
    """Samples at every ``dt`` without gaps (the convolution's premise)."""
    if len(t) < 2:
        return True
    return bool(np.all(np.abs(np.diff(t) - dt) <= rel * dt))


@dataclass(frozen=True)
class TheoremNumbers:
    """The certificate's numbers the theorem uses: its premise's (``eps`` is ``eps_e``; the
    premise as the certificate states it is :class:`qsls.pipeline.premise.record.Premise`)
    and its a-priori ``a``."""

    numbers: PremiseNumbers
    a_certificate: float
    norm_tail: float = 0.0
    """Bound on ``||Phi_xy||`` beyond the taps given (a closed loop's tail; 0 for a FIR)."""


def theorem_check(
    x: np.ndarray,
    e: np.ndarray,
    t: np.ndarray,
    phi_xy: np.ndarray,
    certified: TheoremNumbers,
    scale: np.ndarray,
    distance: Any,
) -> tuple[dict[str, Any], np.ndarray]:
    """The theorem on one flight flown by the controller: ``(row columns, d(x_hat_k))``.

    ``distance(q)`` returns the weighted infinity-norm distance of states ``q`` to the
    nearest training state. ``bound_holds`` is ``max_k ||e_k|| <= gamma_nominal`` (False
    when ``S ||W Phi_xy|| >= 1``: the theorem gives no bound).
    """
    x_hat = nominal_states(x, e, phi_xy)
    defined = np.isfinite(x_hat).all(axis=1)
    d_hat = np.full(len(x_hat), np.nan)
    if defined.any():
        d_hat[defined] = distance(x_hat[defined])
    norm_w = weighted_l1_norm(phi_xy, scale) + float(np.max(scale)) * certified.norm_tail
    e_norm = np.abs(e).max(axis=1)
    finite_e = np.isfinite(e_norm)
    max_e = float(e_norm[finite_e].max()) if finite_e.any() else math.nan
    if defined.any():
        k = int(np.nanargmax(d_hat))
        a, a_t = float(d_hat[k]), float(t[k])
    else:
        a, a_t = math.nan, math.nan
    p = certified.numbers
    gamma = float(guarantee.gamma_of(p.eps, p.S, norm_w, a))
    holds = bool(math.isfinite(gamma) and max_e <= gamma)
    cols: dict[str, Any] = {
        "theorem_applies": True,
        "a_nominal": a,
        "a_nominal_t": a_t,
        "a_certificate": certified.a_certificate,
        "norm_phi_xy_weighted": norm_w,
        "gamma_nominal": gamma,
        "nominal_ratio": max_e / gamma if math.isfinite(gamma) else math.nan,
        "nominal_within_radius": bool(a < p.radius),
        "n_nominal_undefined": int((~defined).sum()),
        "bound_holds": holds,
    }
    return cols, d_hat


def premise_only(a_certificate: float) -> dict[str, Any]:
    """The theorem columns of a row where the theorem does not apply."""
    return {
        "theorem_applies": False,
        "a_nominal": math.nan,
        "a_nominal_t": math.nan,
        "a_certificate": a_certificate,
        "norm_phi_xy_weighted": math.nan,
        "gamma_nominal": math.nan,
        "nominal_ratio": math.nan,
        "nominal_within_radius": None,
        "n_nominal_undefined": 0,
        "bound_holds": None,
    }


def theorem_verdict(cols: dict[str, Any], max_error: float, certified: TheoremNumbers) -> str:
    """The head of the verdict for a row where the theorem applies."""
    g = cols["gamma_nominal"]
    if not math.isfinite(g):
        s_norm = certified.numbers.S * cols["norm_phi_xy_weighted"]
        return f"no bound: S*||W Phi_xy|| = {s_norm:.3g} >= 1 (the theorem gives none)"
    word = "holds" if cols["bound_holds"] else "FAILS"
    text = (
        f"{word}: max ||e|| {max_error:.3g} {'<=' if cols['bound_holds'] else '>'} "
        f"gamma_nominal {g:.3g} (a_nominal {cols['a_nominal']:.3g} at "
        f"t={cols['a_nominal_t']:.2f}s, certificate's a {cols['a_certificate']:.3g})"
    )
    if not cols["nominal_within_radius"]:
        text += f"; x_hat leaves the radius r={certified.numbers.radius:.3g} (a_nominal >= r)"
    if cols["n_nominal_undefined"]:
        text += f"; x_hat undefined at {cols['n_nominal_undefined']} samples (non-finite errors)"
    return text
