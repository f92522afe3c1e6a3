"""The path model: arc-length parameterisation, waypoints, polynomial rows, the perturbation shape."""

from __future__ import annotations

import numpy as np
import pytest

from physynth.models.path import PathParams, PathPerturbation, PerturbationParams, compile_path, perturbed


def test_waypoint_spline_is_parameterised_by_arc_length_and_passes_the_waypoints():
    w = [[0.0, 0.0, 0.0], [40.0, 30.0, 2.0], [100.0, 10.0, 5.0], [160.0, 60.0, 3.0]]
    geo = compile_path(PathParams(kind="waypoints", waypoints_enu_m=w))
    s = np.linspace(0.0, geo.length_m, 2001)
    p, d1, _ = geo.evaluate(s)
    assert np.abs(np.linalg.norm(d1, axis=1) - 1.0).max() < 0.01  # unit speed along s
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
    assert seg == pytest.approx(geo.length_m, rel=1e-4)
    assert np.linalg.norm(p[0] - w[0]) < 1e-9 and np.linalg.norm(p[-1] - w[-1]) < 1e-6
    # the spline passes near every interior waypoint (it interpolates a dense resampling of them)
    for q in w[1:-1]:
        assert np.linalg.norm(p - q, axis=1).min() < 0.2


def test_two_waypoints_give_a_straight_line_of_the_chord_length():
    geo = compile_path(PathParams(kind="waypoints", waypoints_enu_m=[[0, 0, 0], [30, 40, 0]]))
    assert geo.length_m == pytest.approx(50.0)
    p, _, d2 = geo.evaluate(np.array([0.0, 25.0, 50.0]))
    np.testing.assert_allclose(p[1], [15.0, 20.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(d2, 0.0, atol=1e-9)


def test_polynomial_derivatives_match_finite_differences():
    geo = compile_path(PathParams(kind="polynomial", length_m=200.0,
                                  coeffs_enu_m=[[0, 200, 5, -3], [0, 10, -20], [0, 50, 30, -10, 2]]))
    s = np.linspace(1.0, 199.0, 500)
    p, d1, d2 = geo.evaluate(s)
    h = 1e-3
    pp, _, _ = geo.evaluate(s + h)
    pm, _, _ = geo.evaluate(s - h)
    np.testing.assert_allclose((pp - pm) / (2 * h), d1, atol=1e-6)
    np.testing.assert_allclose((pp - 2 * p + pm) / h**2, d2, atol=1e-3)


def test_perturbation_is_a_half_sine_that_keeps_both_stations():
    geo = compile_path(PathParams(kind="waypoints", waypoints_enu_m=[[0, 0, 0], [100, 0, 0]]))
    pert = PathPerturbation(lateral_m=2.0, sag_m=-1.0)
    s = np.array([0.0, 25.0, 50.0, 100.0])
    p0, _, _ = geo.evaluate(s)
    p1, d1, _ = perturbed(geo, pert, s)
    off = p1 - p0
    np.testing.assert_allclose(off[[0, 3]], 0.0, atol=1e-12)  # stations fixed
    np.testing.assert_allclose(off[2], [0.0, 2.0, -1.0], atol=1e-12)  # full offset at mid-span (lateral = +N)
    np.testing.assert_allclose(off[1], np.sin(np.pi / 4) * np.array([0.0, 2.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(d1[2], [1.0, 0.0, 0.0], atol=1e-12)  # slope of the sine is zero at its top


def test_bad_paths_are_refused():
    with pytest.raises(ValueError, match="identical waypoints"):
        PathParams(kind="waypoints", waypoints_enu_m=[[0, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="needs length_m"):
        PathParams(kind="polynomial", coeffs_enu_m=[[0, 1], [0, 1], [0, 1]])
    with pytest.raises(ValueError):
        PerturbationParams(lateral_std_m=-1.0)


def test_polynomial_evaluation_matches_numpy_polyval_bit_for_bit():
    from numpy.polynomial import polynomial as P

    from physynth.models.path import polyval_cf

    rng = np.random.default_rng(11)
    x = np.concatenate([rng.uniform(-800.0, 800.0, 997), [0.0, -0.0, 1e-300, -5e300, 5e300]])
    coeffs = [rng.standard_normal((11, 3)) * 10.0 ** -np.arange(11)[:, None],  # a degree-10 path, E N U
              np.array([[1.0, 0.0, -0.0], [2.0, 0.0, 0.0], [0.0, 3.0, -0.0]]),  # zero leading terms
              np.array([[0.5, -1.5], [-0.0, 0.0]]), np.array([[7.0, -2.0]])]
    with np.errstate(over="ignore", invalid="ignore"):  # the extreme x overflow, as in numpy
        for c in coeffs:
            want = P.polyval(x, c)
            for finite in (False, True):
                got = polyval_cf(x, c, finite)
                assert np.array_equal(np.signbit(got), np.signbit(want))
                assert np.array_equal(got, want)
        bad = np.array([np.nan, np.inf, -np.inf, 1.0])
        got = polyval_cf(bad, coeffs[0], False)
        assert np.array_equal(got, P.polyval(bad, coeffs[0]), equal_nan=True)
