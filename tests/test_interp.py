"""interp_many returns numpy.interp's values bit for bit."""

from __future__ import annotations

import warnings

import numpy as np

from physynth.models.interp import interp_many


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_interp_many_matches_numpy_interp_bit_for_bit():
    rng = np.random.default_rng(1)
    t = np.arange(2000) / 100.0  # truth times
    xp_uneven = np.sort(rng.uniform(0.0, 10.0, 500))
    knots = np.arange(100) / 7.0
    x_edges = np.concatenate([knots, [-1.0, 200.0, knots[-1], np.nextafter(knots[-1], 0.0)], rng.uniform(0, 15, 100)])
    signed_zeros = np.where(rng.random(100) < 0.5, -0.0, 0.0)
    with_inf = rng.standard_normal(100)
    with_inf[[3, 50]] = np.inf
    with_inf[7] = np.nan
    x_nan = x_edges.copy()
    x_nan[5] = np.nan
    cases = [
        (np.sort(rng.uniform(0.0, t[-1], 3000)), t, [np.cumsum(rng.standard_normal(2000)) for _ in range(4)]),
        (np.clip(t / 15.0, 0.0, 1.0), np.linspace(0.0, 1.0, 401), [rng.standard_normal(401)]),
        (rng.uniform(-1.0, 11.0, 3000), xp_uneven, [rng.standard_normal(500), np.zeros(500)]),
        (x_edges, knots, [rng.standard_normal(100), signed_zeros, with_inf, -with_inf]),
        (x_nan, knots, [rng.standard_normal(100)]),
        (np.zeros(0), knots, [rng.standard_normal(100)]),
        (np.array([0.5]), np.array([1.0]), [np.array([2.0])]),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy.interp warns about nothing: neither may this
        for x, xp, fps in cases:
            got = interp_many(x, xp, fps)
            assert len(got) == len(fps)
            for g, fp in zip(got, fps, strict=True):
                assert _same(g, np.interp(x, xp, fp))


def test_interp_many_blocks_are_their_rows_interpolated():
    """A 2-D entry (a block of series, C-contiguous or a transposed view) gives the stacked numpy.interp of
    its rows, bit for bit, whatever the other entries, also with NaN and inf in some rows and on edge points."""
    rng = np.random.default_rng(4)
    t = np.arange(1500) / 100.0
    block = np.cumsum(rng.standard_normal((3, t.size)), axis=1)
    odd = block.copy()
    odd[1, 40] = np.nan
    odd[2, [7, 900]] = np.inf
    x_cases = [np.sort(rng.uniform(0.0, t[-1], 2000)),
               np.concatenate([t[:50], [-3.0, 99.0, t[-1]], rng.uniform(-1.0, 16.0, 300)]),
               np.array([np.nan, 1.0])]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for x in x_cases:
            for b in (block, odd, np.ascontiguousarray(block.T).T, np.zeros((0, t.size))):
                got_block, got_one = interp_many(x, t, [b, block[0]])
                want = np.stack([np.interp(x, t, row) for row in b]) if b.shape[0] else np.empty((0, x.size))
                assert _same(got_block, want)
                assert _same(got_one, np.interp(x, t, block[0]))
