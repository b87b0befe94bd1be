"""The premise's numbers, the one numeric form every stage reads (docs/guarantee.md, The
premise): ``|d_k|_e <= eps + S dist(x_k)`` within ``r``, at most ``m`` outliers
``||o_k||_inf <= eps_o`` in any ``T`` steps, ``||w'_k||_inf <= eps_w`` beside a constant bias
``||beta||_inf <= eps_b``, ``dist(x_ref,k) <= Delta``; and the vector premise of channel groups
written as that scalar one (:func:`grouped_premise`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from qsls.pipeline.core.plant import GROUPS


@dataclass(frozen=True)
class PremiseNumbers:
    """The numbers of the premise (docs/guarantee.md), the one numeric form every stage reads."""

    eps: float
    """The dense error bound: ``eps`` of docs/guarantee.md, which the options, the certificate
    file and the paper call ``eps_e`` (one number, two spellings)."""
    S: float
    radius: float
    eps_w: float
    delta: float
    eps_o: float = 0.0
    m: int = 0
    R0: float | None = None
    """The paper's error bound for ``gamma_strict`` (``eps`` when unset)."""
    gate: float | None = None
    """Velocity gate ``V`` (None: no gate)."""
    eps_b: float = 0.0
    """The bound on a constant acceleration bias (m/s^2 per axis, docs/guarantee.md#the-bias-term):
    a stated design number, like ``Delta``; 0: no bias term."""

    @property
    def slope_ratio(self) -> float:
        """``S + eps/r``: what the premise charges per unit of ``N`` in the robustness condition
        ``(S + eps/r) N + (a + eps_o G_m)/r <= 1`` (the ratio ``largest_s.max_ratio`` bounds)."""
        return self.S + self.eps / self.radius


def grouped_premise(
    error_scale: Sequence[float], bounds: Mapping[str, float], S: float
) -> tuple[float, float, tuple[float, ...]]:
    """The premise with a vector of bounds as the scalar premise in per-group weights
    (docs/guarantee.md, Channel groups). The vector premise, one bound per channel group ``g``
    (:data:`~qsls.pipeline.core.plant.GROUPS`), is ``|d_k,g|_e <= eps_g + S dist(x_k)``;
    returned are ``(eps, S', W_e')``::

        eps = max_g eps_g      w'_e,j = w_e,j eps / eps_g(j)      S' = S eps / min_g eps_g

    so that ``|d_k|_e' = max_g (eps / eps_g) |d_k,g|_e <= eps + S' dist(x_k)``. With ``S = 0``
    the two premises are one set and the robustness condition in ``W_e'`` is the row-wise
    vector condition ``max_i sum_g N_ig eps_g / r + (a + eps_o G_m) / r <= 1`` with
    ``N_ig = sum_t sum_{j in g} w_x,i |Phi_xy(t)_ij| / w_e,j``; with ``S > 0`` it is a sound
    cover of it. Channels of no named group keep their weight."""
    if not bounds:
        return float("nan"), S, tuple(float(w) for w in error_scale)
    eps = max(bounds.values())
    out = [float(w) for w in error_scale]
    for g, b in bounds.items():
        for j in GROUPS[g]:
            out[j] = out[j] * eps / b
    return float(eps), float(S * eps / min(bounds.values())), tuple(out)
