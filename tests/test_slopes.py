"""The pair-slope engine against brute force: exact max, percentiles, local maxima, worst pairs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qsls.pipeline.core.errors import InputError
from qsls.pipeline.errormodel.slopes import (
    HIST_REL_ERROR,
    nearest_distance,
    pair_slopes,
)
from tests.reference_impl import brute_force_slopes

QS = (0, 10, 50, 90, 95, 99, 100)


def _all_pairs(x, e, radius, min_sep=0.0, scale=None):
    """Independent reference: the full matrix (small n only)."""
    scale = np.ones(x.shape[1]) if scale is None else np.asarray(scale, float)
    xs = x * scale
    dist = np.abs(xs[:, None, :] - xs[None, :, :]).max(axis=2)
    derr = np.abs(e[:, None, :] - e[None, :, :]).max(axis=2)
    n = len(x)
    iu = np.triu(np.ones((n, n), bool), 1)
    m = iu & (dist < radius) & (dist >= min_sep) & (dist > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        S = np.where(m, derr / np.where(dist > 0, dist, 1), -1.0)
    local = np.maximum(S.max(axis=1, initial=-1), S.max(axis=0, initial=-1))
    ii, jj = np.nonzero(m)
    return S[ii, jj], ii, jj, np.where(local >= 0, local, np.nan), int((iu & (dist < radius)).sum())


@st.composite
def sample_sets(draw):
    n = draw(st.integers(2, 40))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 6)) * rng.uniform(0.05, 2.0, 6)
    if draw(st.booleans()):  # coarse grid: ties and coincident states
        x = np.round(x, 1)
        x[rng.integers(0, n)] = x[0]
    e = rng.normal(size=(n, 6)) * draw(st.sampled_from([0.0, 0.01, 1.0]))
    radius = draw(st.floats(0.05, 5.0))
    min_sep = draw(st.sampled_from([0.0, 0.0, 0.1])) * radius
    block = draw(st.sampled_from([7, 64, 1 << 21]))
    return x, e, radius, min_sep, block


@settings(max_examples=80, deadline=None)
@given(sample_sets())
def test_exact_max_percentiles_local_and_worst_match_brute_force(case):
    x, e, radius, min_sep, block = case
    res = pair_slopes(
        x, e, radius, min_separation=min_sep, percentiles=QS, top_k=5, block_elems=block
    )
    s, _, _, local, n_in = _all_pairs(x, e, radius, min_sep)
    assert res.n_pairs == len(s)
    assert res.n_in_radius == n_in
    np.testing.assert_array_equal(np.isnan(res.local_max), np.isnan(local))
    np.testing.assert_array_equal(res.local_max[~np.isnan(local)], local[~np.isnan(local)])
    if len(s) == 0:
        assert np.isnan(res.max) and res.worst == []
        return
    assert res.max == s.max()  # exact, not approximately
    assert res.percentile_rel_error == 0.0
    want = np.percentile(s, QS)
    np.testing.assert_array_equal(list(res.percentiles.values()), want)
    # worst pairs: the top slopes in order, each a real pair with its distance
    top = np.sort(s)[::-1][: len(res.worst)]
    np.testing.assert_array_equal([w.slope for w in res.worst], top)
    for w in res.worst:
        assert w.i < w.j
        d = np.abs(x[w.i] - x[w.j]).max()
        assert w.distance == d
        assert w.slope == np.abs(e[w.i] - e[w.j]).max() / d


@settings(max_examples=60, deadline=None)
@given(sample_sets())
def test_histogram_percentiles_within_stated_error(case):
    x, e, radius, min_sep, block = case
    res = pair_slopes(
        x, e, radius, min_separation=min_sep, percentiles=QS, exact_limit=0, block_elems=block
    )
    s = _all_pairs(x, e, radius, min_sep)[0]
    if len(s) == 0:
        return
    assert res.percentile_rel_error == HIST_REL_ERROR <= 0.005
    assert res.max == s.max()
    want = np.percentile(s, QS)
    got = np.array(list(res.percentiles.values()))
    assert np.all(np.abs(got - want) <= HIST_REL_ERROR * want + 1e-300)


def _laps(n, seed=0, dev=0.05):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    w = 2 * np.pi / 5.0
    x = np.c_[np.cos(w * t), np.sin(w * t), 1 + 0 * t, -w * np.sin(w * t), w * np.cos(w * t), 0 * t]
    x += rng.normal(0, dev, x.shape)
    e = 0.05 * np.sin(3 * x) + rng.normal(0, 0.01, x.shape)
    return x, e


def test_repeated_laps_against_chunked_brute_force():
    x, e = _laps(3000)
    scale = (1.0, 1.0, 2.0, 0.5, 0.5, 1.0)
    kw = {"min_separation": 0.02, "state_scale": scale}
    allv, mx, cnt = brute_force_slopes(x, e, 0.3, **kw)
    exact = pair_slopes(x, e, 0.3, **kw, percentiles=QS)
    hist = pair_slopes(x, e, 0.3, **kw, percentiles=QS, exact_limit=1000, block_elems=5000, jobs=2)
    assert cnt > 100_000
    assert exact.n_pairs == hist.n_pairs == cnt
    assert exact.max == hist.max == mx
    want = np.percentile(allv, QS)
    np.testing.assert_array_equal(list(exact.percentiles.values()), want)
    got = np.array(list(hist.percentiles.values()))
    assert hist.percentile_rel_error > 0
    assert np.all(np.abs(got - want) <= HIST_REL_ERROR * want)
    # block size and threads change nothing else either
    assert [(w.slope, w.i, w.j) for w in exact.worst] == [(w.slope, w.i, w.j) for w in hist.worst]
    np.testing.assert_array_equal(exact.local_max, hist.local_max)
    np.testing.assert_array_equal(exact.histogram.counts, hist.histogram.counts)


def test_coincident_and_close_pairs_are_counted_not_used():
    x = np.zeros((4, 6))
    x[1, 0] = 1e-9  # closer than any noise floor
    x[3, 0] = 0.2
    e = np.array([[0.0] * 6, [0.01] + [0] * 5, [0.5] + [0] * 5, [0.02] + [0] * 5])
    res = pair_slopes(x, e, 1.0)
    # (0,2) coincident: never a slope; (1,2) is 0.49 / 1e-9 without a minimum separation
    assert res.n_coincident == 1 and res.n_pairs == 5
    assert res.max == pytest.approx(0.49e9)
    res = pair_slopes(x, e, 1.0, min_separation=0.01)
    assert res.n_pairs == 3 and res.n_below_min_separation == 3
    assert res.max == pytest.approx(0.48 / 0.2)
    assert np.all(np.isfinite(res.local_max))


def test_bootstrap_weights_equal_duplicated_samples():
    x, e = _laps(400, seed=3)
    rng = np.random.default_rng(0)
    w = rng.integers(0, 3, size=len(x)).astype(float)
    res = pair_slopes(x, e, 0.3, bootstrap_weights=np.vstack([np.ones(len(x)), w]))
    base = res.bootstrap
    # all-ones weights reproduce the plain statistics (histogram form)
    assert base.max[0] == res.max
    plain = pair_slopes(x, e, 0.3, exact_limit=0)
    for k, v in plain.percentiles.items():
        assert base.percentiles[k][0] == v
    for k, v in plain.local_max_percentiles.items():
        assert base.local_max_percentiles[k][0] == v
    # weights equal physically repeating the samples (a repeat pairs with itself at d = 0)
    rep = np.repeat(np.arange(len(x)), w.astype(int))
    dup = pair_slopes(x[rep], e[rep], 0.3, exact_limit=0)
    assert base.max[1] == dup.max
    for k, v in dup.percentiles.items():
        assert base.percentiles[k][1] == v
    for k, v in dup.local_max_percentiles.items():
        assert base.local_max_percentiles[k][1] == v


def test_nearest_distance_matches_brute_force():
    rng = np.random.default_rng(5)
    train, query = rng.normal(size=(300, 6)), rng.normal(size=(50, 6))
    scale = np.array([1, 2, 1, 0.5, 0.5, 3.0])
    got = nearest_distance(train, query, scale)
    want = (np.abs(query[:, None, :] - train[None, :, :]) * scale).max(axis=2).min(axis=1)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    assert nearest_distance(train, train[:10]).max() == 0.0


def test_bad_arguments_are_clear():
    x = np.zeros((3, 6))
    with pytest.raises(InputError, match="radius must be > 0"):
        pair_slopes(x, x, 0.0)
    with pytest.raises(InputError, match="min separation"):
        pair_slopes(x, x, 1.0, min_separation=2.0)
    with pytest.raises(InputError, match="finite"):
        pair_slopes(np.full((3, 6), np.nan), x, 1.0)


def test_wide_state_range_coarsens_the_grid_and_stays_exact():
    # a range of 1e6 radii per axis does not fit a 62-bit cell key: wide axes get coarser cells
    rng = np.random.default_rng(11)
    centres = rng.uniform(-1e5, 1e5, size=(30, 6))
    x = np.repeat(centres, 8, axis=0) + rng.normal(0, 0.05, size=(240, 6))
    e = rng.normal(0, 0.1, size=x.shape)
    res = pair_slopes(x, e, 0.2, percentiles=QS)
    s = _all_pairs(x, e, 0.2)[0]
    assert res.n_pairs == len(s) > 100
    assert res.max == s.max()
    np.testing.assert_array_equal(list(res.percentiles.values()), np.percentile(s, QS))
