"""Every achievable FIR response as an affine map of free taps (issue 27; docs/synthesis.md,
FIR responses and achievability).

With ``C = I`` and ``B`` of full column rank the achievability equations (paper eq.
sls_constraints) determine everything from the taps ``Phi_xx(2..T)``::

    Phi_ux(k) = B^+ (Phi_xx(k+1) - A Phi_xx(k))           k = 1..T   (left, x rows)
    Phi_xy(k) = Phi_xx(k+1) - Phi_xx(k) A                  k = 1..T   (right, x rows)
    Phi_uy(k) = Phi_ux(k+1) - Phi_ux(k) A                  k = 0..T   (right, u rows)

with ``Phi_xx(1) = I`` and ``Phi_xx(T+1) = Phi_ux(0) = Phi_ux(T+1) = 0`` (FIR). What is left
of the equations is that ``Phi_xx(k+1) - A Phi_xx(k)`` lies in the range of ``B``:
``N^T (Phi_xx(k+1) - A Phi_xx(k)) = 0`` with ``N`` a basis of ``null(B^T)`` (``nx - nu``
rows per column and tap, the FIR end at ``k = T`` included). The left equations of
``Phi_xy`` follow (:mod:`qsls.pipeline.control.sls`'s former comment: ``A Phi_xy(k) + B
Phi_uy(k) = Phi_xx(k+2) - Phi_xx(k+1) A = Phi_xy(k+1)``). Each map reaches back at most
three taps, so the problem data stay as sparse as the taps themselves, unlike eliminating
``Phi_xx`` by its recursion from ``Phi_ux`` (every tap then depends on all earlier ones;
measured at T = 50: Clarabel 1.35 s against 0.3 s with no elimination at all).

Decoupled blocks: when ``A``, ``B`` and ``H`` couple the states and inputs only within
groups (the quadrotor's three axes), the responses between two groups satisfy homogeneous
equations, and zeroing them keeps a response achievable and lowers every norm of this
package (all are monotone in the absolute values of the entries under diagonal weights),
so the optimum restricted to the block pattern is the optimum. ``pattern`` says which
entries may be nonzero.

Mirrored groups (issue 37): a signed permutation ``sigma`` (``d`` the signs) mapping one
group onto another with ``A``, ``B``, ``H`` invariant (:func:`find_mirrors`) maps achievable
responses to achievable ones, ``Phi(t)_sigma(i)sigma(j) = d_i d_j Phi(t)_ij``; with weights
invariant too, a problem may be solved over responses equal to their image
(:func:`mirror_maps`, docs/synthesis.md#fir-responses-and-achievability).

Vectors: each map gives a response's taps stacked, each tap a column-major (Fortran)
``vec``, so ``reshape(M z + f, (rows, taps * cols), order="F")`` is the side-by-side matrix
``[Phi(k0) Phi(k0+1) ...]``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from qsls.pipeline.control.taps import Taps
from qsls.pipeline.core.plant import NX, LinearModel


@dataclass(frozen=True)
class Affine:
    """``M z + f``: the taps ``first .. first + taps - 1`` of a ``rows x cols`` response."""

    M: sp.csr_matrix
    f: np.ndarray
    rows: int
    cols: int
    first: int

    @property
    def taps(self) -> int:
        return self.M.shape[0] // (self.rows * self.cols)

    def value(self, z: np.ndarray, zero: np.ndarray | None = None) -> np.ndarray:
        """The taps ``0 .. first + taps - 1`` at ``z``, ``(taps, rows, cols)`` (the ones before
        ``first`` are 0, and so are the elements ``zero`` marks)."""
        v = self.M @ z + self.f
        if zero is not None:
            v[zero] = 0.0
        t = np.transpose(v.reshape(self.taps, self.cols, self.rows), (0, 2, 1))
        return np.concatenate([np.zeros((self.first, self.rows, self.cols)), t])

    def entry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tap - first, row, col)`` of every element of the vector."""
        idx = np.arange(self.M.shape[0])
        return idx // (self.rows * self.cols), idx % self.rows, (idx // self.rows) % self.cols


@dataclass(frozen=True)
class Maps:
    """The four responses as affine maps of ``z`` (``n_free`` free entries of
    ``Phi_xx(2..T)``), ``Phi_xx H`` and ``Phi_ux H`` (the cost's and norms' operators), and
    the equations ``E z + e = 0`` left over."""

    Phi_xx: Affine
    Phi_ux: Affine
    Phi_xy: Affine
    Phi_uy: Affine
    Phi_xx_H: Affine
    Phi_ux_H: Affine
    E: sp.csr_matrix
    e: np.ndarray
    n_free: int


def axis_groups(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """Group label of every state and every input: the connected components of the graph
    with an edge for every nonzero of ``A``, ``B`` and ``H``."""
    nx, nu = model.nx, model.nu
    adj = np.zeros((nx + nu, nx + nu), dtype=bool)
    adj[:nx, :nx] = (model.A != 0) | (model.H != 0)
    adj[:nx, nx:] = model.B != 0
    _, labels = connected_components(sp.csr_matrix(adj | adj.T), directed=False)
    return labels[:nx], labels[nx:]


def block_pattern(model: LinearModel, decoupled: bool) -> dict[str, np.ndarray]:
    """Which entries of each response may be nonzero (``C = I``: output ``j`` is state ``j``)."""
    gx, gu = axis_groups(model) if decoupled else (np.zeros(model.nx), np.zeros(model.nu))
    return {
        "Phi_xx": gx[:, None] == gx[None, :],
        "Phi_ux": gu[:, None] == gx[None, :],
        "Phi_xy": gx[:, None] == gx[None, :],
        "Phi_uy": gu[:, None] == gx[None, :],
    }


def _range_operators(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """``B^+`` and ``N^T`` (rows spanning ``null(B^T)``), both built group by group so they
    keep the groups' block structure."""
    from scipy.linalg import null_space

    b = model.B
    nx, nu = b.shape
    if np.linalg.matrix_rank(b) < nu:
        raise ValueError("the SLS elimination needs B of full column rank")
    gx, gu = axis_groups(model)
    pinv = np.zeros((nu, nx))
    perp = []
    for g in np.unique(gx):
        s, u = np.flatnonzero(gx == g), np.flatnonzero(gu == g)
        blk = b[np.ix_(s, u)]
        pinv[np.ix_(u, s)] = np.linalg.pinv(blk)
        basis = null_space(blk.T) if len(u) else np.eye(len(s))
        for col in basis.T:
            row = np.zeros(nx)
            row[s] = col
            perp.append(row)
    return pinv, np.array(perp).reshape(-1, nx)


def _left(m: np.ndarray, cols: int, taps: int) -> sp.csr_matrix:
    """``vec(M Phi(k))`` for every tap (column-major vec)."""
    return sp.kron(sp.eye(taps), sp.kron(sp.eye(cols), sp.csr_matrix(m)), format="csr")


def _right(m: np.ndarray, rows: int, taps: int) -> sp.csr_matrix:
    """``vec(Phi(k) M)`` for every tap (column-major vec)."""
    return sp.kron(sp.eye(taps), sp.kron(sp.csr_matrix(m.T), sp.eye(rows)), format="csr")


def eliminate(model: LinearModel, T: int, pattern: dict[str, np.ndarray]) -> Maps:
    """The maps of the module docstring for horizon ``T`` on ``pattern``."""
    nx, nu = model.nx, model.nu
    if model.ny != nx or not np.array_equal(model.C, np.eye(nx)):
        raise ValueError("the SLS elimination needs C = I")
    pinv, perp = _range_operators(model)
    a, h = model.A, model.H
    sq = nx * nx
    # z: the pattern's entries of Phi_xx(2..T); X stacks Phi_xx(1..T)
    sel = np.flatnonzero(pattern["Phi_xx"].ravel(order="F"))
    n_free = (T - 1) * len(sel)
    rows = (np.arange(1, T)[:, None] * sq + sel[None, :]).ravel()
    embed = sp.csr_matrix((np.ones(n_free), (rows, np.arange(n_free))), shape=(T * sq, n_free))
    x0 = np.zeros(T * sq)
    x0[:sq] = np.eye(nx).ravel(order="F")
    nxt = sp.kron(sp.eye(T, k=1), sp.eye(sq), format="csr")  # Phi_xx(k+1), Phi_xx(T+1) = 0
    step = nxt - _left(a, nx, T)  # Phi_xx(k+1) - A Phi_xx(k)
    ux = _left(pinv, nx, T) @ step
    nu_sq = nu * nx
    after = sp.kron(sp.eye(T + 1, T), sp.eye(nu_sq))  # Phi_ux(k+1), k = 0..T
    before = sp.kron(sp.eye(T + 1, T, k=-1), sp.eye(nu_sq))  # Phi_ux(k), k = 0..T
    uy = (after - _right(a, nu, T + 1) @ before) @ ux
    ops = {
        "Phi_xx": (sp.eye(T * sq, format="csr"), nx, nx, 1),
        "Phi_ux": (ux, nu, nx, 1),
        "Phi_xy": (nxt - _right(a, nx, T), nx, nx, 1),
        "Phi_uy": (uy, nu, nx, 0),
        "Phi_xx_H": (_right(h, nx, T), nx, nx, 1),
        "Phi_ux_H": (_right(h, nu, T) @ ux, nu, nx, 1),
        "range": (_left(perp, nx, T) @ step, perp.shape[0], nx, 1),
    }
    maps = {}
    for name, (op, r, c, first) in ops.items():
        m = sp.csr_matrix(op @ embed)
        m.eliminate_zeros()
        maps[name] = Affine(m, op @ x0, r, c, first)
    rng = maps.pop("range")
    keep = np.diff(rng.M.indptr) > 0
    if np.any(rng.f[~keep] != 0):  # pragma: no cover - the pattern is closed under the equations
        raise ValueError("the block pattern contradicts the achievability equations")
    return Maps(**maps, E=rng.M[keep], e=rng.f[keep], n_free=n_free)


def implied_zero_taps(model: LinearModel, pattern: dict[str, np.ndarray]) -> np.ndarray:
    """Per error channel ``j``: how many of ``Phi_uy``'s last taps are zero on column ``j``
    as soon as all the earlier ones are (so fixing them too would repeat equations).

    Column ``j`` of ``Phi_xy`` obeys ``y(k+1) = A y(k) + B u(k)`` (``u`` column ``j`` of
    ``Phi_uy``) and ends at ``y(T+1) = 0``, which every response of :func:`eliminate`
    meets. With ``u(k) = 0`` before the last ``c`` taps that end reads ``[A^(c-1) B ... A B
    B] [u(T-c+1); ...; u(T)] = 0``, so those taps vanish too whenever that matrix (on the
    pattern's rows and inputs) has full column rank; ``c`` is the largest such count. The
    attitude plant's extra channels get 0: their end condition is ill-conditioned (its
    smallest singular value 0.007 of the largest), and the taps it would imply came out of
    the solver at 3e-5 instead of 0."""
    a, b = model.A, model.B
    out = np.zeros(model.ny, dtype=int)
    for j in range(min(model.ny, NX)):  # the attitude plant's extra channels: every tap fixed
        s = np.flatnonzero(pattern["Phi_xy"][:, j])
        u = np.flatnonzero(pattern["Phi_uy"][:, j])
        blocks: list[np.ndarray] = []
        power = np.eye(model.nx)
        while len(u) and (len(blocks) + 1) * len(u) <= len(s):
            blocks.insert(0, (power @ b)[np.ix_(s, u)])
            if np.linalg.matrix_rank(np.hstack(blocks)) < len(blocks) * len(u):
                break
            out[j] = len(blocks)
            power = a @ power
    return out


# --------------------------------------------------------------------------- mirrored axes
@dataclass(frozen=True)
class Mirror:
    """A signed permutation ``sigma`` of states and inputs that maps group ``source`` onto group
    ``image`` and leaves the plant invariant: ``A[s(i), s(j)] = d_i d_j A[i, j]``,
    ``B[s(i), s(k)] = d_i d_k B[i, k]``, ``H`` as ``A`` (``C = I``). ``state`` and ``input``
    give ``s(i)`` on the source group's states and inputs (-1 elsewhere), ``d`` the signs."""

    source: int
    image: int
    state: np.ndarray
    input: np.ndarray
    d_state: np.ndarray
    d_input: np.ndarray


def _signs(
    model: LinearModel, st: np.ndarray, si: np.ndarray, ui: np.ndarray, su: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The signs ``d`` of a candidate map (source states ``st`` onto ``si``, inputs ``ui`` onto
    ``su``), propagated along the nonzeros of ``A`` and ``B``; None where one is not reached.
    :func:`find_mirrors` then checks them on every entry."""
    n = len(st) + len(ui)
    idx = np.concatenate([st, ui + model.nx])
    img = np.concatenate([si, su + model.nx])
    full = np.zeros((model.nx + model.nu, model.nx + model.nu))
    full[: model.nx, : model.nx], full[: model.nx, model.nx :] = model.A, model.B
    d = np.zeros(n)
    d[0] = 1.0
    stack = [0]
    while stack:
        a = stack.pop()
        for b in range(n):
            pair = (full[idx[a], idx[b]], full[img[a], img[b]])
            rev = (full[idx[b], idx[a]], full[img[b], img[a]])
            for x, y in (pair, rev):
                if x != 0 and d[b] == 0:
                    d[b] = d[a] * np.sign(y) * np.sign(x)
                    stack.append(b)
    if np.any(d == 0):
        return None
    return d[: len(st)], d[len(st) :]


def find_mirrors(
    model: LinearModel, state_keys: np.ndarray, input_keys: np.ndarray
) -> tuple[Mirror, ...]:
    """Pairs of the plant's groups (:func:`axis_groups`) that a signed permutation maps onto each
    other (the quadrotor's x and y axes), states and inputs in index order, with equal
    ``state_keys`` / ``input_keys`` rows (the problem's weights on each state and input, which
    the map must leave invariant too). Each group is the image of at most one source."""
    gx, gu = axis_groups(model)
    out: list[Mirror] = []
    used: set[int] = set()
    groups = np.unique(gx)
    for a in groups:
        for b in groups:
            if b <= a or a in used or b in used:
                continue
            st, si = np.flatnonzero(gx == a), np.flatnonzero(gx == b)
            ui, su = np.flatnonzero(gu == a), np.flatnonzero(gu == b)
            if len(st) != len(si) or len(ui) != len(su):
                continue
            if not (
                np.array_equal(state_keys[st], state_keys[si])
                and np.array_equal(input_keys[ui], input_keys[su])
            ):
                continue
            signs = _signs(model, st, si, ui, su)
            if signs is None:
                continue
            ds, du = signs
            ok = all(
                np.array_equal(m[np.ix_(si, si)], np.outer(ds, ds) * m[np.ix_(st, st)])
                for m in (model.A, model.H)
            ) and np.array_equal(
                model.B[np.ix_(si, su)], np.outer(ds, du) * model.B[np.ix_(st, ui)]
            )
            if not ok:
                continue
            state, inp = -np.ones(model.nx, int), -np.ones(model.nu, int)
            state[st], inp[ui] = si, su
            d_state, d_input = np.zeros(model.nx), np.zeros(model.nu)
            d_state[st], d_input[ui] = ds, du
            out.append(Mirror(int(a), int(b), state, inp, d_state, d_input))
            used |= {int(a), int(b)}
    return tuple(out)


def mirrored_free_taps(
    model: LinearModel, T: int, pattern: dict[str, np.ndarray], mirrors: tuple[Mirror, ...]
) -> tuple[sp.csr_matrix, np.ndarray]:
    """``z = P z_kept``: the free taps of :func:`eliminate` (``Phi_xx(2..T)`` on ``pattern``)
    with every image group's entries the signed copies ``d_i d_j Phi_xx(t)_ij`` of their
    source's; and which of ``z``'s entries are kept."""
    nx = model.nx
    sel = np.flatnonzero(pattern["Phi_xx"].ravel(order="F"))
    pos = -np.ones(nx * nx, int)
    pos[sel] = np.arange(len(sel))
    i, j = sel % nx, sel // nx
    src = np.arange(len(sel))
    sign = np.ones(len(sel))
    gx, _ = axis_groups(model)
    for m in mirrors:
        inv = -np.ones(nx, int)
        inv[m.state[m.state >= 0]] = np.flatnonzero(m.state >= 0)
        img = gx[i] == m.image
        si, sj = inv[i[img]], inv[j[img]]
        src[img] = pos[si + nx * sj]
        sign[img] = m.d_state[si] * m.d_state[sj]
    kept = src == np.arange(len(sel))
    col = np.cumsum(kept) - 1
    per_tap = sp.csr_matrix(
        (sign, (np.arange(len(sel)), col[src])), shape=(len(sel), int(kept.sum()))
    )
    return sp.kron(sp.eye(T - 1), per_tap, format="csr"), np.tile(kept, T - 1)


def mirror_maps(
    maps: Maps,
    model: LinearModel,
    T: int,
    pattern: dict[str, np.ndarray],
    mirrors: tuple[Mirror, ...],
) -> tuple[Maps, dict[str, np.ndarray]]:
    """The maps of ``z_kept`` (:func:`mirrored_free_taps`) and, per response, the entries in an
    image group (copies of their source's up to sign, so every row sum and every absolute
    value there equals the source's: a problem need not bound them twice). The range
    equations of the image groups are copies too and are left out.

    Exact: the problem (norms, costs, constraints, all functions of the entries' absolute
    values row by row, with weights the mirror leaves invariant) is invariant under the
    mirror, so the average of an optimum and its mirror image is an optimum too, and it is a
    symmetric response: restricting to symmetric responses keeps the optimal value."""
    P, _ = mirrored_free_taps(model, T, pattern, mirrors)
    gx, gu = axis_groups(model)
    images = [m.image for m in mirrors]
    in_image = {"x": np.isin(gx, images), "u": np.isin(gu, images)}
    out: dict[str, Affine] = {}
    dropped: dict[str, np.ndarray] = {}
    for name in ("Phi_xx", "Phi_ux", "Phi_xy", "Phi_uy", "Phi_xx_H", "Phi_ux_H"):
        aff: Affine = getattr(maps, name)
        out[name] = replace(aff, M=sp.csr_matrix(aff.M @ P))
        _, i, _ = aff.entry()
        dropped[name] = in_image["u" if name.startswith("Phi_u") else "x"][i]
    sel = np.flatnonzero(pattern["Phi_xx"].ravel(order="F"))
    z_group = np.tile(gx[sel % model.nx], T - 1)
    E = maps.E.tocsr()
    first = E.indices[E.indptr[:-1]]  # a range equation reads one group only
    keep = ~np.isin(z_group[first], images)
    reduced = Maps(**out, E=sp.csr_matrix(E[keep] @ P), e=maps.e[keep], n_free=P.shape[1])
    return reduced, dropped


def achievability_residuals(taps: Taps, model: LinearModel) -> dict[str, float]:
    """Max absolute residual of each group of achievability equations (all taps, FIR end
    included, the fixed zeros at tap 0 too)."""
    a, b, c = model.A, model.B, model.C
    xx, ux, xy, uy = taps.Phi_xx, taps.Phi_ux, taps.Phi_xy, taps.Phi_uy
    nx = a.shape[0]

    def nxt(p: np.ndarray) -> np.ndarray:  # Phi(k+1) for k = 0..T, Phi(T+1) = 0
        return np.concatenate([p[1:], np.zeros((1, *p.shape[1:]))])

    ident = np.zeros_like(xx)
    ident[0] = np.eye(nx)
    res = {
        "zero_taps": max(np.abs(xx[0]).max(), np.abs(ux[0]).max(), np.abs(xy[0]).max()),
        "left_x": np.abs(nxt(xx) - a @ xx - b @ ux - ident).max(),
        "left_y": np.abs(nxt(xy) - a @ xy - b @ uy).max(),
        "right_x": np.abs(nxt(xx) - xx @ a - xy @ c - ident).max(),
        "right_u": np.abs(nxt(ux) - ux @ a - uy @ c).max(),
    }
    return {k: float(v) for k, v in res.items()}
