"""The known tag height (:mod:`physynth.track.height`) as a pseudo-measurement of the classical trackers.

Two layouts whose vertical the ranges hardly tell: the site's four anchors all at 2.0 m around a walk at
about 1 m (a mirror fix 1 m above the anchors' plane fits the ranges as well), and a compact cluster of
four anchors at 2.0 m over 4 m x 3 m with the tag walking out to 45 m (the vertical extrapolated). The
prior is the true mean height: :func:`height_from_truth` of two other runs of the same scenario.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from track_helpers import ANCHORS, site_scenario

from physynth.errors import PhySynthError
from physynth.generate import generate_trace
from physynth.records import Uwb
from physynth.scenario import scenario_from_dict, scenario_to_dict
from physynth.track.features import ekf_prior_rel_m
from physynth.track.height import MIN_HEIGHT_STD_M, HeightPrior, height_from_heights, height_from_truth
from physynth.track.inputs import track_input
from physynth.track.scoring import error_stats
from physynth.track.trackers import make_tracker
from physynth.track.trackers.ekf import EkfTracker
from physynth.track.trackers.ls import LsTracker

WALK = [[2, 0, 0.8], [20, 4, 1.2], [38, 3, 1.0]]
"""The site walk, its height between 0.8 and 1.2 m."""
RING = [{"id": f"R{i}", "pos_enu_m": [*a["pos_enu_m"][:2], 2.0]} for i, a in enumerate(ANCHORS)]
"""The site's anchors (40 m x 16 m around the walk), all at 2.0 m."""
CLUSTER = [{"id": f"C{i}", "pos_enu_m": [x, y, 2.0]}
           for i, (x, y) in enumerate([(0, -1.5), (4, -1.5), (4, 1.5), (0, 1.5)])]
"""Four anchors at 2.0 m over 4 m x 3 m."""
AWAY = [[6, 0, 0.8], [25, 5, 1.2], [45, 2, 1.0]]
"""A walk from 6 m to 45 m away from :data:`CLUSTER`."""


def _coplanar(anchors: list[dict], waypoints: list[list[float]]):
    """The site scenario with its anchors replaced (through its dict form) and the walk ``waypoints``."""
    d = scenario_to_dict(site_scenario(noise_m=0.05))
    d["anchors"] = anchors
    d["path"]["waypoints_enu_m"] = waypoints
    scn = scenario_from_dict(d)
    assert np.ptp([a.pos_enu_m[2] for a in scn.anchors]) == 0.0  # one height
    return scn


def _site(anchors, waypoints):
    traces = [generate_trace(_coplanar(anchors, waypoints), i, 11) for i in range(3)]
    return traces[2], height_from_truth(traces[:2])  # the test run, the prior from two other runs


@pytest.fixture(scope="module")
def ring():
    return _site(RING, WALK)


@pytest.fixture(scope="module")
def cluster():
    return _site(CLUSTER, AWAY)


def _rmse(est_enu_m, inp):
    st = error_stats(est_enu_m, inp.pos_enu_m, inp.eval_mask())
    return st["rmse_v_m"], st["rmse_2d_m"]


@pytest.mark.parametrize("mean, std", [(math.nan, 0.1), (math.inf, 0.1), (1.0, 0.0), (1.0, -0.1),
                                       (1.0, math.nan), (1.0, math.inf)])
def test_height_prior_refuses_a_non_finite_mean_and_a_non_positive_spread(mean, std):
    with pytest.raises(PhySynthError):
        HeightPrior(mean, std)


def test_height_priors_from_data_are_the_mean_and_spread_of_the_data(ring):
    u = np.array([0.8, 1.0, np.nan, 1.3, 0.9])
    p = height_from_heights(u)
    assert p.mean_m == pytest.approx(1.0) and p.std_m == pytest.approx(np.std([0.8, 1.0, 1.3, 0.9]))
    assert height_from_heights(np.array([1.0, 1.0, 1.01])).std_m == MIN_HEIGHT_STD_M  # never to a centimetre
    with pytest.raises(PhySynthError):
        height_from_heights(np.array([1.0, np.nan]))
    trace, prior = ring
    other = generate_trace(_coplanar(RING, WALK), 0, 11)
    u = np.concatenate([other.truth.pos_enu_m[:, 2], trace.truth.pos_enu_m[:, 2]])
    p = height_from_truth([other, trace])
    assert p.mean_m == pytest.approx(u.mean()) and p.std_m == pytest.approx(u.std())
    assert 0.9 < prior.mean_m < 1.1 and 0.05 < prior.std_m < 0.2  # the walk rides at 0.8-1.2 m
    inp = track_input(trace, height=prior)
    assert inp.height_rel_m == pytest.approx(prior.mean_m - 2.0)  # the anchors' centroid is at 2.0 m
    assert track_input(trace).height_rel_m is None


@pytest.mark.parametrize("site", ["ring", "cluster"])
@pytest.mark.parametrize("name", ["ls", "ekf"])
def test_the_true_mean_height_fixes_the_vertical_and_keeps_the_horizontal(site, name, request):
    trace, prior = request.getfixturevalue(site)
    blind, known = track_input(trace), track_input(trace, height=prior)
    v_blind, h_blind = _rmse(make_tracker(name).predict(blind), blind)
    v_known, h_known = _rmse(make_tracker(name).predict(known), known)
    # measured: ring ls 0.94 -> 0.12 m, ekf 1.85 -> 0.12 m; cluster ls 0.94 -> 0.12 m, ekf 2.27 -> 0.12 m
    assert v_known < 0.25 and v_known < v_blind / 3, (v_known, v_blind)
    assert h_known < h_blind + 0.05, (h_known, h_blind)


def test_a_tight_prior_holds_the_vertical_at_the_known_height(ring):
    trace, prior = ring
    inp = track_input(trace, height=HeightPrior(prior.mean_m, 1e-3))
    ok = inp.eval_mask()
    z_ls = LsTracker().predict_rel(inp)[ok, 2]
    pos, var = EkfTracker().predict_rel_var(inp)
    upd = np.isfinite(pos).all(axis=1) & inp.fresh.any(axis=1)  # the ekf's update steps (the height's last)
    assert upd.sum() > 100
    assert np.max(np.abs(z_ls - inp.height_rel_m)) < 5e-3
    assert np.max(np.abs(pos[upd, 2] - inp.height_rel_m)) < 5e-3
    assert np.max(var[upd]) <= 1e-6  # P_zz after an update with variance 1e-6 m^2


def test_ls_single_step_and_prefix_equal_the_full_solution_with_a_height(ring):
    trace, prior = ring
    inp = track_input(trace, height=prior)
    ls = LsTracker(block_steps=32)
    full = ls.predict_rel(inp)
    k = inp.n_steps // 3
    np.testing.assert_allclose(ls.predict_rel(inp, k), full[:k], rtol=0, atol=1e-9)
    first = int(np.searchsorted(inp.t_s, inp.first_range_s))
    for j in (first, first + 1, k, inp.n_steps - 1):  # the ekf's first fix is solved this way
        np.testing.assert_allclose(ls.solve_step(inp, j), full[j], rtol=0, atol=1e-9)
    blind = ls.solve_step(track_input(trace), first)
    # the first fix: at the known height, where the ranges alone put it at the mirror image above the anchors
    assert abs(full[first, 2] - inp.height_rel_m) < 0.3 < abs(blind[2] - inp.height_rel_m)


def test_ekf_with_an_uninformative_prior_is_the_ekf_without_one():
    # the site's anchors at four heights (0.5-2.5 m): the height update of std 1e4 m must change nothing
    # the ranges tell (measured 2e-7 m)
    blind = track_input(generate_trace(site_scenario(noise_m=0.1), 0, 7))
    vague = replace(blind, height=HeightPrior(1.0, 1e4))
    a, b = EkfTracker().predict_rel(blind), EkfTracker().predict_rel(vague)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    np.testing.assert_allclose(a[ok], b[ok], rtol=0, atol=1e-5)
    pos, _ = EkfTracker().predict_rel_var(blind)
    np.testing.assert_array_equal(pos, a)  # predict_rel is predict_rel_var's positions


def test_ekf_vertical_variance(ring, cluster):
    for trace, prior in (ring, cluster):
        blind, known = track_input(trace), track_input(trace, height=prior)
        pos, var_blind = EkfTracker().predict_rel_var(blind)
        _, var_known = EkfTracker().predict_rel_var(known)
        ok = np.isfinite(pos).all(axis=1)
        assert ok.any() and not ok[0]
        assert np.all(np.isnan(var_blind[~ok])) and np.all(np.isnan(var_known[~ok]))  # NaN before the first fix
        assert np.all(np.isfinite(var_blind[ok]) & (var_blind[ok] > 0))
        assert np.all(np.isfinite(var_known[ok]) & (var_known[ok] > 0))
        assert np.all(var_known[ok] < var_blind[ok])
        assert np.max(var_known[ok]) < 2 * prior.std_m**2  # the prior's spread, and the growth between updates
    trace, _ = cluster
    blind = track_input(trace)
    pos, var = EkfTracker().predict_rel_var(blind)
    far = np.isfinite(pos).all(axis=1) & (np.linalg.norm(blind.pos_rel_m[:, :2], axis=1) > 30)
    assert far.sum() > 100 and np.median(var[far]) > 1.0  # measured 9.4 m^2


def test_ekf_vertical_variance_grows_through_a_gap_and_is_held_with_the_position():
    tr = generate_trace(site_scenario(noise_m=0.1), 0, 7)
    u = tr.uwb
    t0, t1 = u.t_s[0] + 0.3 * tr.duration_s, u.t_s[0] + 0.6 * tr.duration_s
    gap = (u.t_s > t0) & (u.t_s < t1)
    inp = track_input(replace(tr, uwb=Uwb(t_s=u.t_s, anchor=u.anchor, range_m=np.where(gap, np.nan, u.range_m))))
    last = np.flatnonzero(inp.fresh.any(axis=1) & (inp.t_s <= t0))[-1]
    nxt = np.flatnonzero(inp.fresh.any(axis=1) & (inp.t_s >= t1))[0]
    _, free = EkfTracker(fit_range_std=False).predict_rel_var(inp)
    assert np.all(np.diff(free[last + 10:nxt]) > 0)  # q T^3 / 3 dominates after a few steps
    assert free[nxt - 1] > 10 * free[last]
    _, held = EkfTracker(fit_range_std=False, max_coast_s=1.0).predict_rel_var(inp)
    k1 = last + int(round(inp.rate_hz))
    np.testing.assert_array_equal(held[:k1 + 1], free[:k1 + 1])
    np.testing.assert_array_equal(held[k1:nxt], np.full(nxt - k1, held[k1]))


def test_the_networks_ekf_input_carries_the_height(cluster):
    trace, prior = cluster
    blind, known = track_input(trace), track_input(trace, height=prior)
    steps = np.arange(0, blind.n_steps, 10)
    ok = blind.eval_mask()[steps]
    err = []
    for inp in (blind, known):
        pos = ekf_prior_rel_m(inp, use_imu=False, fallback_rel_m=np.zeros((steps.size, 3)), steps=steps)
        err.append(np.sqrt(np.mean((pos[ok, 2] - inp.pos_rel_m[steps[ok], 2]) ** 2)))
    assert err[1] < 0.25 and err[1] < err[0] / 3, err
