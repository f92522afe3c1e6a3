"""The polynomial path evaluated as one matrix product (physynth.models.path._products_cf): the values of
Horner's steps (polyval_cf) to rounding, and Horner's own where the product does not apply."""

from __future__ import annotations

import numpy as np
from numpy.polynomial import polynomial as P

from physynth.io.scenario_file import load_scenario
from physynth.models.path import compile_path, polyval_cf


def _coeffs(geo):
    """The path's coefficients and those of its first and second derivatives (as PathGeometry derives them)."""
    return geo.coeffs_s, P.polyder(geo.coeffs_s, 1, axis=0), P.polyder(geo.coeffs_s, 2, axis=0)


def _horner(geo, s):
    return [polyval_cf(s, c, True) for c in _coeffs(geo)]


def test_products_match_horner_to_rounding():
    geo = compile_path(load_scenario("cablecar-descending").path)
    s = np.sort(np.random.default_rng(1).uniform(0.0, geo.length_m, 10_001))
    for got, ref in zip(geo.evaluate_cf(s), _horner(geo, s), strict=True):
        assert got.shape == ref.shape == (3, s.size)
        scale = np.abs(ref).max(axis=1, keepdims=True)
        assert np.all(np.abs(got - ref) <= 4e-15 * scale)


def test_non_finite_and_huge_arguments_take_horners_steps():
    geo = compile_path(load_scenario("cablecar-descending").path)
    for s in (np.array([0.0, np.nan, 10.0]), np.array([0.0, 1e40])):  # a NaN; s^10 beyond 1e300
        with np.errstate(over="ignore"):  # Horner's steps overflow to inf on the huge argument
            got = geo.evaluate_cf(s)
            ref = [polyval_cf(s, c, bool(np.isfinite(s.sum()))) for c in _coeffs(geo)]
        for g, r in zip(got, ref, strict=True):
            assert np.array_equal(g, r, equal_nan=True)
