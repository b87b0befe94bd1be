"""The spatial index behind the S-slope engine (:mod:`qsls.pipeline.errormodel.slopes`).

States are binned into cells at least ``r`` wide, so every pair closer than ``r`` lies in
the same or a neighbouring cell; neighbouring cells are then visited in dense blocks of
bounded size, never as an all-pairs matrix (docs/errormodel.md#the-s-slope).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

_KEY_BITS = 62
"""Bits of the packed cell key (one int64 per cell)."""


@dataclass(frozen=True)
class CellGrid:
    order: np.ndarray  # sorted position -> input row
    start: np.ndarray  # per cell: first sorted position
    count: np.ndarray  # per cell: number of samples
    nb_ptr: np.ndarray  # CSR pointers into nb_cell, per cell
    nb_cell: np.ndarray  # forward neighbour cells (larger key), per cell


def cell_grid(xs: np.ndarray, radius: float) -> CellGrid:
    dim = xs.shape[1]
    lo = xs.min(axis=0)
    span = xs.max(axis=0) - lo
    # a cell side a hair above r: a pair with |dx| < r is never two cells apart
    h = np.full(dim, radius * (1.0 + 1e-9))
    ncell = np.floor(span / h).astype(np.int64) + 1
    # fit the cell key in 62 bits (with one padding cell each side): coarsen wide dimensions
    while np.sum(np.log2(ncell + 2.0)) > _KEY_BITS:
        k = int(np.argmax(ncell))
        h[k] *= 2.0
        ncell[k] = int(np.floor(span[k] / h[k])) + 1
    c = np.floor((xs - lo) / h).astype(np.int64)
    np.clip(c, 0, ncell - 1, out=c)
    c += 1
    size = ncell + 2
    mult = np.ones(dim, dtype=np.int64)
    for k in range(dim - 2, -1, -1):
        mult[k] = mult[k + 1] * size[k + 1]
    key = c @ mult
    order = np.argsort(key, kind="stable")
    skey = key[order]
    uk, start, count = np.unique(skey, return_index=True, return_counts=True)
    # forward neighbour offsets, only along dimensions that have more than one cell
    live = [k for k in range(dim) if ncell[k] > 1]
    offs = np.zeros((0, dim), dtype=np.int64)
    if live:
        prod = np.array(list(itertools.product((-1, 0, 1), repeat=len(live))), dtype=np.int64)
        offs = np.zeros((len(prod), dim), dtype=np.int64)
        offs[:, live] = prod
    okey = offs @ mult
    okey = np.sort(okey[okey > 0])
    ptr, nb = _links(uk, okey)
    return CellGrid(order=order, start=start, count=count, nb_ptr=ptr, nb_cell=nb)


def _links(uk: np.ndarray, okey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The forward neighbours of every cell as CSR ``(ptr, cells)``: cell ``a``'s are
    ``cells[ptr[a]:ptr[a + 1]]``, the cells whose key is ``uk[a] + o`` for an offset ``o`` of
    ``okey`` (increasing), in increasing order.

    Two passes over the offsets, a count per cell and then the fill, so the links are
    written once into the one array they end in (int32 while the cells fit): no list of
    ``(a, b)`` int64 pairs and no sort of them (1.27 GB of a 1.5 GB fit at 1e6 samples).
    The order is the sorted ``(a, b)`` one: for a cell, a larger offset gives a larger key,
    so a larger neighbour index.
    """
    n = len(uk)

    def hits(o: int) -> tuple[np.ndarray, np.ndarray]:
        target = uk + o
        pos = np.searchsorted(uk, target)
        pos[pos >= n] = 0
        hit = np.flatnonzero(uk[pos] == target)
        return hit, pos[hit]

    count = np.zeros(n, dtype=np.int64)
    for o in okey.tolist():
        count[hits(o)[0]] += 1  # a cell once per offset: no repeated index
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(count, out=ptr[1:])
    nb = np.empty(int(ptr[-1]), dtype=np.int32 if n < 2**31 else np.int64)
    fill = ptr[:-1].copy()
    for o in okey.tolist():
        a, b = hits(o)
        nb[fill[a]] = b
        fill[a] += 1
    return ptr, nb


def pair_blocks(g: CellGrid, block_elems: int, min_block: int = 8192, inflation: int = 4):
    """Yield (row_start, row_stop, column sorted positions) covering every pair once.

    Consecutive cells are grouped (fewer, larger numpy calls) while the block's candidate
    count stays within ``inflation`` times the cells' own candidate count (or ``min_block``)
    and ``block_elems``. Columns before the block's first row are dropped (they cannot be
    partners: a pair counts once, at its lower sorted position).
    """
    ncells = len(g.start)
    owner = np.repeat(np.arange(ncells), np.diff(g.nb_ptr))
    own_cols = g.count + np.bincount(owner, weights=g.count[g.nb_cell], minlength=ncells).astype(
        np.int64
    )
    count, oc = g.count.tolist(), own_cols.tolist()
    a = 0
    while a < ncells:
        rows, cols_u, work = count[a], oc[a], count[a] * oc[a]
        b = a + 1
        while b < ncells:
            nr, nc, nw = rows + count[b], cols_u + oc[b], work + count[b] * oc[b]
            if nr * nc > min(block_elems, max(min_block, inflation * nw)):
                break
            rows, cols_u, work = nr, nc, nw
            b += 1
        cells = np.unique(np.concatenate([np.arange(a, b), g.nb_cell[g.nb_ptr[a] : g.nb_ptr[b]]]))
        cols = cell_ranges(g.start[cells], g.count[cells])
        r0, r1 = int(g.start[a]), int(g.start[b - 1] + g.count[b - 1])
        s = r0
        while s < r1:
            live = cols[np.searchsorted(cols, s, side="right") :]
            if len(live) == 0:
                break
            if len(live) > block_elems:  # a huge neighbourhood: one row, columns in pieces
                for c0 in range(0, len(live), block_elems):
                    yield s, s + 1, live[c0 : c0 + block_elems]
                s += 1
                continue
            stop = min(r1, s + max(1, block_elems // len(live)))
            yield s, stop, live
            s = stop
        a = b


def cell_ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for every (s, c)."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.repeat(starts - np.concatenate(([0], np.cumsum(counts)[:-1])), counts)
    return offsets + np.arange(total, dtype=np.int64)
