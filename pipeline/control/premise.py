"""The premise a certificate rests on, and how much of the training data violates it.

The guarantee (DESIGN.md, Robust synthesis) holds where ``||e|| <= eps_e + S ||x - x_d||``
within radius ``r`` of the training states ``x_d``, with ``||w|| <= eps_w`` and the reference
within ``Delta`` of the training data. With ``eps_e`` or ``S`` set to a percentile, part of the
training data itself lies outside that premise (DESIGN.md, Premise status); this module records,
for each number, its value, how it was chosen and, for the error-model ones, the violated share:

- ``eps_e``: the share of training samples with ``||e_k|| > eps_e``;
- ``S``: the share of training pairs with ``||e_i - e_j|| / ||W (x_i - x_j)|| > S`` over the
  pairs the S-slope estimator counts (``min_separation <= ||W (x_i - x_j)|| < r``, the
  certificate's ``r``), found on the same cell grid (:mod:`qsls.pipeline.errormodel.pairgrid`).

A certificate is plainly ``certified`` only when both shares are zero (:attr:`Premise.holds`).
Without the training states beside the error model a share is known only when the value is at
least the error model's maximum (then 0); otherwise it is unknown and the premise not shown to hold.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.model import TRAINING_FILE, ErrorModel
from qsls.pipeline.errormodel.pairgrid import cell_grid, pair_blocks

BLOCK_ELEMS = 1 << 21


def check_unweighted(em: ErrorModel | None, to: str = "synthesize") -> None:
    """Refuse an error model fitted with a ``state_scale`` W other than ones: its ``S`` and
    distances are in the weighted norm ``||W x||``, the guarantee then needs ``||W Phi_xy||``
    while synthesis constrains (and certificates state) the unweighted ``||Phi_xy||``
    (DESIGN.md, Weighted norms): the two are never mixed."""
    if em is None or all(v == 1.0 for v in em.state_scale):
        return
    raise InputError(
        f"the error model was fitted with state_scale {list(em.state_scale)}, so its S and "
        "distances are in a weighted norm, but synthesis bounds the unweighted ||Phi_xy|| and "
        f"the two must not be mixed; refit with the default state_scale (all ones) to {to}"
    )


class PremiseEntry(BaseModel):
    """One number of the premise: its value, how it was chosen and (error-model numbers only)
    the share of the training data violating it (``None``: not known)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    value: float
    chosen: str
    """``number`` (given), ``max``, ``pXX`` / ``local_pXX`` (the error model's), ``error model``
    (its radius or Delta) or ``default``."""
    violated: float | None = None
    n_violating: int | None = None
    n_total: int | None = None
    """Samples (``eps_e``) or pairs (``S``) checked."""


class Premise(BaseModel):
    """``certificate.yaml``'s ``premise``: ``eps_e``, ``S``, ``r``, ``Delta``, ``eps_w``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    eps_e: PremiseEntry
    S: PremiseEntry
    r: PremiseEntry
    Delta: PremiseEntry
    eps_w: PremiseEntry
    training_data: str | None = None
    """Where the shares were computed (the training states file), why they could not be, or
    None without an error model."""

    @property
    def holds(self) -> bool:
        """The premise holds on all training data: no share violated, none unknown. Without an
        error model the numbers are the user's assumption and no training data contradicts it."""
        if self.training_data is None:
            return True
        return all(e.violated == 0.0 for e in (self.eps_e, self.S))

    def shares(self) -> str:
        """``eps_e violated by 4.3% of samples, S by 51% of pairs`` (for one-line summaries)."""
        return (
            f"premise violated by {_pct(self.eps_e.violated)} of training samples (eps_e "
            f"{self.eps_e.chosen}), {_pct(self.S.violated)} of pairs (S {self.S.chosen})"
        )


def _pct(v: float | None) -> str:
    if v is None:
        return "an unknown share"
    return f"{100 * v:.3g}%"


# --------------------------------------------------------------------------- the shares
def eps_e_violations(e: np.ndarray, eps_e: float) -> tuple[int, int]:
    """``(samples with ||e_k||_inf > eps_e, samples)``."""
    norms = np.abs(np.asarray(e, dtype=float)).max(axis=1)
    return int(np.count_nonzero(norms > eps_e)), len(norms)


def slope_violations(
    x: np.ndarray,
    e: np.ndarray,
    S: float,
    radius: float,
    *,
    min_separation: float = 0.0,
    state_scale: np.ndarray | None = None,
    block_elems: int = BLOCK_ELEMS,
) -> tuple[int, int]:
    """``(pairs with slope > S, pairs)`` over ``min_separation <= ||W (x_i - x_j)|| < r``,
    ``d > 0`` (the pairs :func:`qsls.pipeline.errormodel.slopes.pair_slopes` counts)."""
    x = np.asarray(x, dtype=float)
    e = np.asarray(e, dtype=float)
    scale = np.ones(x.shape[1]) if state_scale is None else np.asarray(state_scale, float)
    if len(x) < 2:
        return 0, 0
    xs = x[:, scale > 0] * scale[scale > 0]
    g = cell_grid(xs, float(radius))
    X = np.ascontiguousarray(xs[g.order].T)  # (dim, n): one row per coordinate
    E = np.ascontiguousarray(e[g.order].T)
    lo = min_separation if min_separation > 0 else float(np.nextafter(0.0, 1.0))
    bad = total = 0
    for r0, r1, cols in pair_blocks(g, block_elems):
        d = _cheb(X[:, r0:r1], X[:, cols])
        m = (d < radius) & (d >= lo) & (cols[None, :] > np.arange(r0, r1)[:, None])
        if not m.any():
            continue
        s = _cheb(E[:, r0:r1], E[:, cols])[m] / d[m]
        total += len(s)
        bad += int(np.count_nonzero(s > S))
    return bad, total


def _cheb(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``max_k |a[k, i] - b[k, j]|`` (rows x cols), one coordinate at a time (2-D memory)."""
    d = np.abs(a[0][:, None] - b[0][None, :])
    for k in range(1, len(a)):
        np.maximum(d, np.abs(a[k][:, None] - b[k][None, :]), out=d)
    return d


# --------------------------------------------------------------------------- the record
def _chosen(value: Any) -> str:
    return "number" if isinstance(value, int | float) else str(value)


def _entry(
    value: float, chosen: str, top: float | None, counted: tuple[int, int] | None
) -> PremiseEntry:
    """``violated``: counted on the training data when it is at hand; else 0 when ``value`` is
    at least the error model's maximum ``top``, and unknown (None) otherwise."""
    if counted is not None and counted[1] > 0:
        bad, n = counted
        return PremiseEntry(
            value=value, chosen=chosen, violated=bad / n, n_violating=bad, n_total=n
        )
    if top is not None and value >= top:
        return PremiseEntry(value=value, chosen=chosen, violated=0.0)
    return PremiseEntry(value=value, chosen=chosen)


def premise_of(
    opts: Any, values: dict[str, float], em: ErrorModel | None, em_file: Path | None
) -> Premise:
    """The premise of a synthesis: ``values`` the resolved ``S, eps_e, radius, delta, eps_w``,
    ``opts`` the options they came from (how each was chosen), the shares from the training
    states beside ``em_file`` when present."""
    import pandas as pd

    from qsls.pipeline.ingest.flight import E_COLS, X_COLS

    S, eps_e, radius = values["S"], values["eps_e"], values["radius"]
    counted_e = counted_s = None
    where = None
    if em is not None and em_file is not None:
        f = Path(em_file).parent / TRAINING_FILE
        if f.is_file():
            df = pd.read_parquet(f, columns=[*X_COLS, *E_COLS])
            x, e = df[list(X_COLS)].to_numpy(float), df[list(E_COLS)].to_numpy(float)
            counted_e = eps_e_violations(e, eps_e)
            counted_s = slope_violations(
                x, e, S, radius, min_separation=em.min_separation,
                state_scale=np.asarray(em.state_scale, float),
            )  # fmt: skip
            where = f"{TRAINING_FILE} beside the error model"
        else:
            where = f"no {TRAINING_FILE} beside the error model: shares not computed"
    elif em is not None:
        where = "error model given as a file without its fit folder: shares not computed"
    top_e = em.eps_e if em is not None else None
    top_s = em.s_slope.max if em is not None else None
    from_em = "error model" if em is not None else "default"
    return Premise(
        eps_e=_entry(eps_e, _chosen(opts.eps_e), top_e, counted_e),
        S=_entry(S, _chosen(opts.S), top_s, counted_s),
        r=PremiseEntry(value=radius, chosen=from_em if opts.radius is None else "number"),
        Delta=PremiseEntry(
            value=values["delta"], chosen=from_em if opts.delta is None else _chosen(opts.delta)
        ),
        eps_w=PremiseEntry(value=values["eps_w"], chosen="number"),
        training_data=where,
    )


PREMISE_COLUMNS = ("premise_holds", "eps_e_violated", "S_violated")
"""The premise's columns of a sweep table (one row per grid point)."""


def premise_fields(
    opts: Any,
    values: dict[str, float],
    em: ErrorModel | None,
    em_file: Path | None,
    cache: dict[tuple[float, ...], dict[str, Any]],
) -> dict[str, Any]:
    """:func:`premise_of` as the :data:`PREMISE_COLUMNS` of a sweep row (NaN: share unknown);
    ``cache`` keeps one count per distinct ``(S, eps_e, radius)``."""
    key = (values["S"], values["eps_e"], values["radius"])
    if key not in cache:
        p = premise_of(opts, values, em, em_file)
        nan = float("nan")
        cache[key] = {
            "premise_holds": p.holds,
            "eps_e_violated": nan if p.eps_e.violated is None else p.eps_e.violated,
            "S_violated": nan if p.S.violated is None else p.S.violated,
        }
    return cache[key]
