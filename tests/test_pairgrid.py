"""The fit grid's neighbour links (issue 37): written once into their CSR array, equal to the
sorted list of every ``(cell, forward neighbour)`` pair the grid had before."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.errormodel.pairgrid import cell_grid


def _links_by_sorting(uk: np.ndarray, okey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The previous construction: every link as an int64 pair, then a lexsort."""
    ca, cb = [], []
    for o in okey:
        target = uk + o
        pos = np.searchsorted(uk, target)
        pos[pos >= len(uk)] = 0
        hit = np.flatnonzero(uk[pos] == target)
        ca.append(hit)
        cb.append(pos[hit])
    a = np.concatenate(ca) if ca else np.zeros(0, np.int64)
    b = np.concatenate(cb) if cb else np.zeros(0, np.int64)
    srt = np.lexsort((b, a))
    a, b = a[srt], b[srt]
    return np.searchsorted(a, np.arange(len(uk) + 1)), b


@pytest.mark.parametrize(("n", "dim", "radius"), [(4000, 6, 0.25), (3000, 3, 0.05), (50, 2, 10.0)])
def test_links_equal_the_sorted_pairs(n: int, dim: int, radius: float) -> None:
    from qsls.pipeline.errormodel import pairgrid

    xs = np.random.default_rng(n).random((n, dim))
    seen = {}

    def spy(uk: np.ndarray, okey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        seen["args"] = (uk, okey)
        return real(uk, okey)

    real = pairgrid._links
    pairgrid._links = spy
    try:
        g = cell_grid(xs, radius)
    finally:
        pairgrid._links = real
    ptr, nb = _links_by_sorting(*seen["args"])
    np.testing.assert_array_equal(g.nb_ptr, ptr)
    np.testing.assert_array_equal(g.nb_cell, nb)
    assert len(nb) > 0 or n < 100
