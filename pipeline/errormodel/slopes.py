"""The pair-slope engine behind the S-slope (docs/errormodel.md#the-s-slope).

For training samples ``(x_i, e_i)`` and a radius ``r``, the S-slope statistics are taken over
the pair slopes

    s_ij = ||e_i - e_j|| / ||W (x_i - x_j)||      over pairs i < j with  m <= ||W (x_i - x_j)|| < r

(every norm the infinity norm, ``W = diag(state_scale)``, ``m`` the minimum separation; a pair
at distance 0 never counts). The theory asks for their maximum (the paper's ``S_hat``); a few
noisy measurements set it, so the engine also returns percentiles over the pairs, each
sample's largest slope ``local_i = max_j s_ij`` and its percentiles, and the pairs with the
largest slopes.

How the pairs are found (never an all-pairs matrix): the scaled states are binned on a grid of
cells of side ``>= r`` in all six coordinates, so the partners of a sample lie in its own cell
or one of the (at most 3^6 - 1) neighbouring cells. The samples are sorted by cell; each cell
lists its "forward" neighbours (larger cell key), so every unordered pair of cells is visited
once. Consecutive cells are grouped into blocks of rows (a contiguous slice of the sorted
samples) against the union of their cells' forward neighbours (a gathered column set), and each
block is computed densely with numpy: the distance, the mask ``m <= d < r`` and ``col > row``
(in sorted order: each pair once), the error difference and the slope. Memory is bounded by
the block size (``block_elems`` candidate pairs), whatever the number of pairs.

Statistics and their accuracy:
- the maximum and the worst pairs are exact (float64 throughout);
- percentiles over pairs are exact (numpy's linear interpolation) while the number of pairs is
  at most ``exact_limit``; beyond it they come from a streaming histogram whose bins are the
  float64 bit patterns with the low 44 mantissa bits dropped: bins of relative width at most
  2^-8, so the bin midpoint (interpolated like numpy between the two order statistics) is
  within ``2^-9 = 0.195 %`` of the exact percentile (``HIST_REL_ERROR``);
- per-sample local maxima are exact, so are their percentiles.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.progress import NULL_PROGRESS, Progress
from qsls.pipeline.errormodel.pairgrid import cell_grid, pair_blocks

HIST_SHIFT = 44
"""Low mantissa bits dropped to form a histogram key (52 - 44 = 8 bits kept: 256 bins/octave)."""
HIST_REL_ERROR = 2.0 ** -(52 - HIST_SHIFT + 1)
"""Bound on the relative error of a histogram percentile: half a bin's relative width."""
DEFAULT_BLOCK = 1 << 21
DEFAULT_EXACT_LIMIT = 1 << 24


def pct_name(q: float) -> str:
    """The name of percentile ``q`` in the error model: ``p50``, ``p99.9``."""
    return f"p{float(q):g}"


def percentile_table(values: np.ndarray, qs: Sequence[float]) -> dict[str, float]:
    """``{pNN: value}`` of ``values`` at the percentiles ``qs`` (NaN when empty)."""
    if len(values) == 0:
        return {pct_name(q): float("nan") for q in qs}
    got = np.percentile(values, list(qs))
    return {pct_name(q): float(v) for q, v in zip(qs, got, strict=True)}


# --------------------------------------------------------------------------- histogram
class SlopeHistogram:
    """Counts of slopes by histogram key (float64 bits >> HIST_SHIFT), grown as needed."""

    def __init__(self) -> None:
        self.lo = 0
        self.counts = np.zeros(0, dtype=np.float64)

    def add(self, keys: np.ndarray, weights: np.ndarray | None = None) -> None:
        if len(keys) == 0:
            return
        kmin, kmax = int(keys.min()), int(keys.max())
        self._cover(kmin, kmax)
        c = np.bincount(keys - kmin, weights=weights, minlength=kmax - kmin + 1)
        off = kmin - self.lo
        self.counts[off : off + len(c)] += c

    def _cover(self, kmin: int, kmax: int) -> None:
        if len(self.counts) == 0:
            self.lo, self.counts = kmin, np.zeros(kmax - kmin + 1)
            return
        hi = self.lo + len(self.counts) - 1
        if kmin >= self.lo and kmax <= hi:
            return
        nlo, nhi = min(kmin, self.lo), max(kmax, hi)
        grown = np.zeros(nhi - nlo + 1)
        grown[self.lo - nlo : self.lo - nlo + len(self.counts)] = self.counts
        self.lo, self.counts = nlo, grown

    def merge(self, other: SlopeHistogram) -> None:
        if len(other.counts) == 0:
            return
        self._cover(other.lo, other.lo + len(other.counts) - 1)
        off = other.lo - self.lo
        self.counts[off : off + len(other.counts)] += other.counts

    @property
    def total(self) -> float:
        return float(self.counts.sum())

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper value of every bin."""
        keys = np.arange(self.lo, self.lo + len(self.counts) + 1, dtype=np.int64)
        vals = (keys << HIST_SHIFT).view(np.float64)
        return vals[:-1], vals[1:]

    def percentiles(self, qs: Sequence[float]) -> dict[str, float]:
        """Percentiles like ``np.percentile`` (linear), from bin midpoints (HIST_REL_ERROR)."""
        n = self.total
        if n <= 0:
            return {pct_name(q): float("nan") for q in qs}
        lo, hi = self.edges()
        mid = 0.5 * (lo + hi)
        cum = np.cumsum(self.counts)
        out = {}
        for q in qs:
            pos = float(q) / 100.0 * (n - 1)
            r0 = np.floor(pos)
            frac = pos - r0
            # value of the order statistic with 0-based rank k lies in the first bin whose
            # cumulative count exceeds k
            b0 = int(np.searchsorted(cum, r0, side="right"))
            b1 = int(np.searchsorted(cum, min(r0 + 1, n - 1), side="right"))
            out[pct_name(q)] = float(mid[b0] + frac * (mid[b1] - mid[b0]))
        return out


def hist_keys(s: np.ndarray) -> np.ndarray:
    """Histogram keys of non-negative float64 slopes (monotone in the value)."""
    return np.ascontiguousarray(s, dtype=np.float64).view(np.int64) >> HIST_SHIFT


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class WorstPairIdx:
    slope: float
    i: int
    j: int
    distance: float


@dataclass(frozen=True)
class BootstrapSlopes:
    """Per-replicate statistics (one entry per replicate)."""

    max: np.ndarray
    percentiles: dict[str, np.ndarray]
    local_max_percentiles: dict[str, np.ndarray]


@dataclass(frozen=True)
class PairSlopes:
    """What :func:`pair_slopes` found. Indices refer to the rows of the input arrays."""

    n_samples: int
    n_pairs: int
    """Pairs that count: ``min_separation <= d < radius`` and ``d > 0``."""
    n_in_radius: int
    """All pairs with ``d < radius`` (including those closer than ``min_separation``)."""
    n_below_min_separation: int
    n_coincident: int
    max: float
    percentiles: dict[str, float]
    percentile_rel_error: float
    local_max: np.ndarray
    """(n,) each sample's largest slope; NaN for a sample without partners."""
    local_max_percentiles: dict[str, float]
    n_with_partners: int
    worst: list[WorstPairIdx]
    histogram: SlopeHistogram
    n_candidates: int
    bootstrap: BootstrapSlopes | None = None
    radius: float = 0.0
    min_separation: float = 0.0
    extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- the engine
class _Acc:
    """Running statistics over the blocks of pairs (positions are sorted positions)."""

    def __init__(self, X, E, order, radius, min_separation, top_k, exact_limit, W):
        self.X, self.E, self.order = X, E, order
        self.radius, self.min_sep, self.top_k = radius, min_separation, top_k
        self.lo_sep = min_separation if min_separation > 0 else float(np.nextafter(0.0, 1.0))
        n = X.shape[1]
        self.hist = SlopeHistogram()
        self.local = np.full(n, -1.0)
        self.exact_limit = exact_limit
        self.exact: list[np.ndarray] | None = [] if exact_limit > 0 else None
        self.n_exact = 0
        self.n_pairs = self.n_in_radius = self.n_coincident = self.n_cand = 0
        self.ws = np.zeros(0)
        self.wi = np.zeros(0, dtype=np.int64)
        self.wj = np.zeros(0, dtype=np.int64)
        self.wd = np.zeros(0)
        self.thr = -np.inf
        self.W = W
        if W is not None:
            nb = len(W)
            self.bhist = [SlopeHistogram() for _ in range(nb)]
            self.bmax = np.full(nb, -1.0)
            self.blocal = np.full((nb, n), -1.0)

    def block(self, r0: int, r1: int, cols: np.ndarray) -> None:
        X, E = self.X, self.E
        rows = np.arange(r0, r1)
        xa, xb = X[:, r0:r1], X[:, cols]
        d = np.abs(xa[0][:, None] - xb[0][None, :])
        tmp = np.empty_like(d)
        for k in range(1, len(X)):
            np.subtract(xa[k][:, None], xb[k][None, :], out=tmp)
            np.abs(tmp, out=tmp)
            np.maximum(d, tmp, out=d)
        self.n_cand += d.size
        inr = d < self.radius
        inr &= cols[None, :] > rows[:, None]
        c_in = int(np.count_nonzero(inr))
        if c_in == 0:
            return
        self.n_in_radius += c_in
        m = d >= self.lo_sep
        m &= inr
        c_m = int(np.count_nonzero(m))
        if self.min_sep > 0:
            self.n_coincident += int(np.count_nonzero(inr & (d == 0)))
        else:
            self.n_coincident += c_in - c_m
        self.n_pairs += c_m
        if c_m == 0:
            return
        ea, eb = E[:, r0:r1], E[:, cols]
        S = np.abs(ea[0][:, None] - eb[0][None, :])
        for k in range(1, len(E)):
            np.subtract(ea[k][:, None], eb[k][None, :], out=tmp)
            np.abs(tmp, out=tmp)
            np.maximum(S, tmp, out=S)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.divide(S, d, out=S)
        np.logical_not(m, out=inr)
        np.putmask(S, inr, -1.0)
        s = S[m]
        keys = hist_keys(s)
        self.hist.add(keys)
        if self.exact is not None:
            self.n_exact += len(s)
            if self.n_exact <= self.exact_limit:
                self.exact.append(s)
            else:
                self.exact = None
        rmax = S.max(axis=1)
        np.maximum(self.local[r0:r1], rmax, out=self.local[r0:r1])
        self.local[cols] = np.maximum(self.local[cols], S.max(axis=0))
        if float(rmax.max()) >= self.thr:
            self._worst(S, d, rows, cols)
        if self.W is not None:
            self._boot(S, m, keys, r0, r1, cols)

    def _worst(self, S, d, rows, cols) -> None:
        """Keep the top_k pairs under the total order (slope desc, i asc, j asc)."""
        flat = S.ravel()
        sel = np.flatnonzero(flat >= max(self.thr, 0.0))
        k = self.top_k
        if len(sel) > k:
            kth = np.partition(flat[sel], len(sel) - k)[len(sel) - k]
            above = sel[flat[sel] > kth]
            ties = sel[flat[sel] == kth]
            if len(above) + len(ties) > k:
                # among equal slopes keep the smallest (i, j): a deterministic choice
                ti, tj = np.divmod(ties, S.shape[1])
                oi, oj = self.order[rows[ti]], self.order[cols[tj]]
                key = np.minimum(oi, oj) * len(self.order) + np.maximum(oi, oj)
                need = k - len(above)
                ties = ties[np.argpartition(key, need - 1)[:need]] if need > 0 else ties[:0]
            sel = np.concatenate([above, ties])
        ii, jj = np.divmod(sel, S.shape[1])
        oi, oj = self.order[rows[ii]], self.order[cols[jj]]
        ws = np.r_[self.ws, flat[sel]]
        wi = np.r_[self.wi, np.minimum(oi, oj)]
        wj = np.r_[self.wj, np.maximum(oi, oj)]
        wd = np.r_[self.wd, d[ii, jj]]
        keep = np.lexsort((wj, wi, -ws))[:k]
        self.ws, self.wi, self.wj, self.wd = ws[keep], wi[keep], wj[keep], wd[keep]
        if len(self.ws) >= k:
            self.thr = float(self.ws[-1])

    def merge(self, o: _Acc) -> None:
        """Fold another accumulator over the same samples into this one (order-independent)."""
        self.hist.merge(o.hist)
        np.maximum(self.local, o.local, out=self.local)
        if self.exact is not None and o.exact is not None:
            self.n_exact += o.n_exact
            self.exact = self.exact + o.exact if self.n_exact <= self.exact_limit else None
        else:
            self.exact = None
        self.n_pairs += o.n_pairs
        self.n_in_radius += o.n_in_radius
        self.n_coincident += o.n_coincident
        self.n_cand += o.n_cand
        ws, wi = np.r_[self.ws, o.ws], np.r_[self.wi, o.wi]
        wj, wd = np.r_[self.wj, o.wj], np.r_[self.wd, o.wd]
        keep = np.lexsort((wj, wi, -ws))[: self.top_k]
        self.ws, self.wi, self.wj, self.wd = ws[keep], wi[keep], wj[keep], wd[keep]
        if self.W is not None:
            for h, oh in zip(self.bhist, o.bhist, strict=True):
                h.merge(oh)
            np.maximum(self.bmax, o.bmax, out=self.bmax)
            np.maximum(self.blocal, o.blocal, out=self.blocal)

    def _boot(self, S, m, keys, r0, r1, cols) -> None:
        """Add the block's pairs to every bootstrap replicate (a pair counts w_i w_j times)."""
        W = self.W
        for b in range(len(W)):
            wr, wc = W[b, r0:r1], W[b, cols]
            w = wr[:, None] * wc[None, :]
            wm = w[m]
            pos = wm > 0
            self.bhist[b].add(keys[pos], wm[pos])
            self.bmax[b] = max(self.bmax[b], float(np.where(w > 0, S, -1.0).max()))
            if (wc > 0).any():
                rm = np.where(wc[None, :] > 0, S, -1.0).max(axis=1)
                np.maximum(self.blocal[b, r0:r1], rm, out=self.blocal[b, r0:r1])
            if (wr > 0).any():
                cm = np.where(wr[:, None] > 0, S, -1.0).max(axis=0)
                self.blocal[b, cols] = np.maximum(self.blocal[b, cols], cm)


def _run_blocks(accs: list[_Acc], blocks, progress: Progress) -> None:
    """Feed the blocks to the accumulators, one thread each (one: in this thread)."""
    lock = threading.Lock()
    done = [0]

    def worker(acc: _Acc) -> None:
        while True:
            with lock:
                item = next(blocks, None)
            if item is None:
                return
            r0, r1, cols = item
            acc.block(r0, r1, cols)
            with lock:
                if r1 > done[0]:
                    progress.advance(r1 - done[0])
                    done[0] = r1

    if len(accs) == 1:
        worker(accs[0])
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(len(accs)) as pool:
        for f in [pool.submit(worker, a) for a in accs]:
            f.result()


def _checked(
    x: np.ndarray,
    e: np.ndarray,
    radius: float,
    min_separation: float,
    state_scale: Sequence[float] | np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, e, scale)`` as float arrays, or a clear error for inputs the engine cannot take."""
    x = np.asarray(x, dtype=np.float64)
    e = np.asarray(e, dtype=np.float64)
    if x.ndim != 2 or e.ndim != 2 or len(x) != len(e):
        raise ValueError(f"x and e must be (n, d) and (n, k), got {x.shape}, {e.shape}")
    if not np.isfinite(radius) or radius <= 0:
        raise InputError(f"radius must be > 0, got {radius}")
    if not (0 <= min_separation < radius):
        raise InputError(
            f"min separation must be in [0, radius={radius:g}), got {min_separation:g}"
        )
    dim = x.shape[1]
    scale = np.ones(dim) if state_scale is None else np.asarray(state_scale, dtype=np.float64)
    if scale.shape != (dim,) or np.any(scale < 0) or not np.any(scale > 0):
        raise InputError(f"state scale must be {dim} non-negative weights, not all zero")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(e))):
        raise InputError("states and errors must be finite (drop NaN samples first)")
    return x, e, scale


def pair_slopes(
    x: np.ndarray,
    e: np.ndarray,
    radius: float,
    *,
    min_separation: float = 0.0,
    state_scale: Sequence[float] | np.ndarray | None = None,
    percentiles: Sequence[float] = (50, 90, 95, 99),
    top_k: int = 20,
    exact_limit: int = DEFAULT_EXACT_LIMIT,
    block_elems: int = DEFAULT_BLOCK,
    bootstrap_weights: np.ndarray | None = None,
    jobs: int = 1,
    progress: Progress = NULL_PROGRESS,
) -> PairSlopes:
    """S-slope statistics of samples ``x`` (n, d) with errors ``e`` (n, k); see the module doc.

    ``jobs`` threads share the blocks (numpy releases the GIL in its loops); every statistic
    is merged order-independently, so the result does not depend on ``jobs``.

    ``bootstrap_weights`` (B, n) of non-negative integers (multiplicities of each sample in B
    resampled data sets) adds per-replicate statistics: a pair counts ``w_i w_j`` times.
    """
    x, e, scale = _checked(x, e, radius, min_separation, state_scale)
    n = len(x)
    qs = [float(q) for q in percentiles]
    W = None if bootstrap_weights is None else np.asarray(bootstrap_weights, dtype=np.float64)
    if W is not None and (W.ndim != 2 or W.shape[1] != n):
        raise ValueError(f"bootstrap weights must be (B, {n}), got {W.shape}")

    order, acc = _accumulate(
        x, e, scale, radius, min_separation, top_k, exact_limit, block_elems, W, jobs, progress
    )
    return _summary(acc, order, n, qs, W, radius, min_separation)


def _accumulate(
    x: np.ndarray,
    e: np.ndarray,
    scale: np.ndarray,
    radius: float,
    min_separation: float,
    top_k: int,
    exact_limit: int,
    block_elems: int,
    W: np.ndarray | None,
    jobs: int,
    progress: Progress,
) -> tuple[np.ndarray, _Acc | None]:
    """The samples' order in the cell grid and every pair's statistics accumulated over the
    grid's blocks by ``jobs`` threads, merged (None with fewer than two samples)."""
    n = len(x)
    if n < 2:
        return np.arange(n), None
    xs = x[:, scale > 0] * scale[scale > 0]
    g = cell_grid(xs, float(radius))
    order = g.order
    args = (
        np.ascontiguousarray(xs[order].T),
        np.ascontiguousarray(e[order].T),
        order,
        float(radius),
        float(min_separation),
        int(top_k),
        int(exact_limit),
        None if W is None else W[:, order],
    )
    progress.start("pair slopes", total=n)
    accs = [_Acc(*args) for _ in range(max(1, int(jobs)))]
    _run_blocks(accs, pair_blocks(g, block_elems), progress)
    progress.finish()
    acc = accs[0]
    for other in accs[1:]:
        acc.merge(other)
    return order, acc


def _summary(
    acc: _Acc | None,
    order: np.ndarray,
    n: int,
    qs: list[float],
    W: np.ndarray | None,
    radius: float,
    min_separation: float,
) -> PairSlopes:
    """The statistics of the module doc from the accumulated pairs (exact percentiles while
    the slopes were kept, else the histogram's)."""
    loc = np.full(n, np.nan)
    if acc is not None:
        loc[order] = np.where(acc.local >= 0, acc.local, np.nan)
    has = np.isfinite(loc)
    n_pairs = acc.n_pairs if acc else 0
    if acc is not None and acc.exact is not None and n_pairs > 0:
        pcts, rel = percentile_table(np.concatenate(acc.exact), qs), 0.0
    elif acc is not None:
        pcts, rel = acc.hist.percentiles(qs), (HIST_REL_ERROR if n_pairs > 0 else 0.0)
    else:
        pcts, rel = percentile_table(np.zeros(0), qs), 0.0
    worst = []
    if acc is not None:
        worst = [
            WorstPairIdx(float(s_), int(i_), int(j_), float(d_))
            for s_, i_, j_, d_ in zip(acc.ws, acc.wi, acc.wj, acc.wd, strict=True)
        ]
    bres = None
    if acc is not None and W is not None:
        bres = _boot_finish(acc, W, qs)
    n_in = acc.n_in_radius if acc else 0
    return PairSlopes(
        n_samples=n,
        n_pairs=n_pairs,
        n_in_radius=n_in,
        n_below_min_separation=n_in - n_pairs,
        n_coincident=acc.n_coincident if acc else 0,
        max=worst[0].slope if worst else float("nan"),
        percentiles=pcts,
        percentile_rel_error=rel,
        local_max=loc,
        local_max_percentiles=percentile_table(loc[has], qs),
        n_with_partners=int(has.sum()),
        worst=worst,
        histogram=acc.hist if acc else SlopeHistogram(),
        n_candidates=acc.n_cand if acc else 0,
        bootstrap=bres,
        radius=float(radius),
        min_separation=float(min_separation),
    )


def _boot_finish(acc: _Acc, W: np.ndarray, qs: Sequence[float]) -> BootstrapSlopes:
    """Per-replicate statistics; W in input order, acc's arrays in sorted order."""
    nb = len(W)
    pct = {pct_name(q): np.zeros(nb) for q in qs}
    lpct = {pct_name(q): np.zeros(nb) for q in qs}
    Ws = W[:, acc.order]
    for b in range(nb):
        for k, v in acc.bhist[b].percentiles(qs).items():
            pct[k][b] = v
        has = (acc.blocal[b] >= 0) & (Ws[b] > 0)
        vals = np.repeat(acc.blocal[b][has], Ws[b][has].astype(np.int64))
        for k, v in percentile_table(vals, qs).items():
            lpct[k][b] = v
    mx = np.where(acc.bmax >= 0, acc.bmax, np.nan)
    return BootstrapSlopes(max=mx, percentiles=pct, local_max_percentiles=lpct)


# --------------------------------------------------------------------------- nearest distance
def nearest_distance(
    train_x: np.ndarray,
    query_x: np.ndarray,
    state_scale: Sequence[float] | np.ndarray | None = None,
    *,
    chunk: int = 65536,
) -> np.ndarray:
    """Distance ``min_i ||W (q - x_i)||_inf`` of each query state to the training states, (m,)."""
    from scipy.spatial import cKDTree

    train_x = np.asarray(train_x, dtype=np.float64)
    query_x = np.asarray(query_x, dtype=np.float64)
    if train_x.ndim != 2 or len(train_x) == 0:
        raise InputError("nearest_distance needs at least one training state")
    if query_x.ndim != 2 or query_x.shape[1] != train_x.shape[1]:
        raise ValueError(f"query states must be (m, {train_x.shape[1]}), got {query_x.shape}")
    dim = train_x.shape[1]
    scale = np.ones(dim) if state_scale is None else np.asarray(state_scale, dtype=np.float64)
    tree = cKDTree(train_x * scale)
    out = np.empty(len(query_x))
    for a in range(0, len(query_x), chunk):
        out[a : a + chunk], _ = tree.query(query_x[a : a + chunk] * scale, k=1, p=np.inf)
    return out
