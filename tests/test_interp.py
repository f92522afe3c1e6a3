"""interp_many returns numpy.interp's values bit for bit."""

from __future__ import annotations

import warnings

import numpy as np

from physynth.models._interp import interp_many


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
