"""The networks' uncertainty and their fall-back where the geometry cannot tell the vertical; the set network."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from track_helpers import site_scenario

from physynth.generate import generate_trace
from physynth.track.fallback import fuse_vertical, geometry_vertical_var
from physynth.track.height import HeightPrior
from physynth.track.inputs import track_input
from physynth.track.scoring import error_stats

FLAT = [{"id": f"F{i}", "pos_enu_m": p} for i, p in
        enumerate([[0, -1.5, 2.0], [4, -1.5, 2.0], [4, 1.5, 2.05], [0, 1.5, 1.95]])]
"""Four anchors at about 2 m over 4 m x 3 m: the vertical of a tag tens of metres away is not observable."""
NET = {"hidden": 16, "heads": 2, "window_steps": 16, "stride_steps": 8, "burn_in_steps": 2, "seed": 0}


def test_geometry_vertical_variance_grows_with_distance_from_coplanar_anchors():
    anchors = np.array([a["pos_enu_m"] for a in FLAT], float) - [2.0, 0.0, 2.0]
    d = np.array([5.0, 10.0, 20.0, 40.0])
    pos = np.stack([d, np.zeros_like(d), np.full_like(d, -1.0)], axis=1)
    var = geometry_vertical_var(pos, anchors, np.ones((4, 4), bool), range_std_m=0.1)
    assert np.all(np.diff(var) > 0) and var[-1] > 1.0  # metres of vertical spread at 40 m
    spread = anchors.copy()
    spread[:, 2] = [-1.5, 1.5, -1.5, 1.5]  # anchors 3 m apart in height
    assert geometry_vertical_var(pos, spread, np.ones((4, 4), bool))[-1] < var[-1] / 4
    few = geometry_vertical_var(pos[:1], anchors, np.array([[True, True, False, False]]))
    assert few[0] > 1e3  # two ranges cannot place a point in 3-D


def test_fuse_vertical_is_the_inverse_variance_combination():
    z, v = fuse_vertical(np.array([3.0, 3.0, 3.0]), np.array([1.0, 100.0, 1.0]), np.array([1.0, 1.0, np.nan]), 1.0)
    assert z[0] == pytest.approx(2.0) and v[0] == pytest.approx(0.5)
    assert z[1] == pytest.approx((3.0 / 100 + 1.0) / (1 / 100 + 1.0))  # an unsure estimate falls to the known value
    assert z[2] == 3.0 and v[2] == 1.0  # no known value there: unchanged


@pytest.fixture(scope="module")
def flat_site():
    scn = site_scenario(noise_m=0.05, anchors=FLAT, **{"path.waypoints_enu_m": [[6, 0, 1], [25, 5, 1], [45, 2, 1]]})
    return scn, [generate_trace(scn, i, 41) for i in range(3)]


def _vertical_rmse(est, inp):
    st = error_stats(est, inp.pos_enu_m, inp.eval_mask())
    return st["rmse_v_m"], st["rmse_2d_m"]


def test_networks_fall_back_to_the_known_height_where_the_vertical_is_unobservable(flat_site):
    pytest.importorskip("torch")
    from physynth.track.trackers.nets import NetTracker

    _, traces = flat_site
    prior = HeightPrior(1.0, 0.1)
    train = [track_input(t, height=prior) for t in traces[:2]]
    test = track_input(traces[2], height=prior)
    net = NetTracker("aoi-fusion", epochs=3, lr=3e-3, ekf_prior="residual", **NET).fit(train)
    v_with, h_with = _vertical_rmse(net.predict(test), test)
    pos, var = net.predict_dist(test)
    assert np.all(np.isfinite(var[test.eval_mask()])) and np.all(var[test.eval_mask()] >= 0)
    blind = replace(test, height=None)
    plain = NetTracker("aoi-fusion", epochs=3, lr=3e-3, ekf_prior="residual", likelihood=False, **NET).fit(
        [replace(i, height=None) for i in train])
    v_plain, _ = _vertical_rmse(plain.predict(blind), blind)
    assert v_with < 0.25, v_with  # the tag walks at 1 m; the prior says 1.0 +- 0.1 m
    assert v_with < 0.5 * v_plain, (v_with, v_plain)
    assert np.isfinite(h_with)


def test_the_set_network_ignores_the_order_of_the_anchors_and_takes_3_to_8(flat_site):
    pytest.importorskip("torch")
    from physynth.track.trackers.nets import NetTracker

    scn, traces = flat_site
    # no ekf anywhere (its sequential range updates depend on the anchors' order): no ekf input, and the
    # vertical falls back to a known height, not to the ekf's
    inputs = [track_input(t, height=HeightPrior(1.0, 0.3)) for t in traces]
    net = NetTracker("aoi-fusion", epochs=1, ekf_prior="none", random_isometry=False, **NET).fit(inputs[:2])
    inp = inputs[2]
    order = np.array([2, 0, 3, 1])
    perm = replace(inp, range_m=inp.range_m[:, order], fresh=inp.fresh[:, order], aoi_s=inp.aoi_s[:, order],
                   anchor_pos_rel_m=inp.anchor_pos_rel_m[order])
    a, va = net.predict_dist(inp)
    b, vb = net.predict_dist(perm)
    ok = inp.eval_mask()
    assert np.max(np.abs(a[ok] - b[ok])) < 1e-4 and np.max(np.abs(va[ok] - vb[ok])) < 1e-4
    for n in (3, 8):  # anchor counts it never saw in training
        anchors = [{"id": f"N{i}", "pos_enu_m": [8.0 * np.cos(k), 8.0 * np.sin(k), 0.5 + 0.3 * i]}
                   for i, k in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False))]
        other = track_input(generate_trace(site_scenario(noise_m=0.05, anchors=anchors), 0, 3))
        assert other.n_anchors == n and np.all(np.isfinite(net.predict(other)[other.eval_mask()]))


@pytest.mark.parametrize("name", ["ls", "ekf"])
def test_classical_trackers_take_the_known_height_as_a_measurement(flat_site, name):
    from physynth.track.trackers import make_tracker

    _, traces = flat_site
    blind = track_input(traces[2])
    known = track_input(traces[2], height=HeightPrior(1.0, 0.1))
    v_blind, h_blind = _vertical_rmse(make_tracker(name).predict(blind), blind)
    v_known, h_known = _vertical_rmse(make_tracker(name).predict(known), known)
    assert v_known < 0.2 and v_known < v_blind / 3, (v_known, v_blind)
    assert h_known < h_blind + 0.05  # the horizontal does not suffer from it


def test_ekf_vertical_variance(flat_site):
    from physynth.track.trackers.ekf import EkfTracker

    _, traces = flat_site
    blind = track_input(traces[2])
    known = track_input(traces[2], height=HeightPrior(1.0, 0.1))
    pos, var_blind = EkfTracker().predict_rel_var(blind)
    assert np.array_equal(pos, EkfTracker().predict_rel(blind), equal_nan=True)
    _, var_known = EkfTracker().predict_rel_var(known)
    ok = np.isfinite(pos).all(axis=1)
    assert np.all(np.isfinite(var_blind[ok])) and np.all(var_blind[ok] > 0) and np.all(np.isnan(var_blind[~ok]))
    far = ok & (np.linalg.norm(blind.pos_rel_m[:, :2], axis=1) > 30)  # tens of metres from flat anchors
    assert np.median(var_blind[far]) > 1.0  # metres of vertical spread the ranges leave
    assert np.all(var_known[ok] < 2 * 0.1 ** 2)  # the prior's 0.1 m, and the growth between updates


def test_ekf_restarts_where_it_lost_the_path_and_the_ranges_say_so(flat_site):
    from physynth.track.trackers.ekf import EkfTracker

    _, traces = flat_site
    inp = track_input(traces[2], height=HeightPrior(1.0, 0.1))
    ekf = EkfTracker(fit_range_std=False)
    upd = np.flatnonzero(inp.fresh.any(axis=1) & (inp.t_s >= inp.first_range_s))
    truth = inp.pos_rel_m[upd]
    start = truth[0] * [-1.0, -1.0, 1.0]  # the mirror image of the start through the anchors' centroid
    lost, _ = ekf.filter_updates(inp, int(upd[0]), start, upd)
    kept, _ = ekf.filter_updates(inp, int(upd[0]), start, upd, ls=truth)  # a multilateration that is right
    tail = slice(len(upd) // 2, None)
    err_lost = np.linalg.norm(lost[tail, :3] - truth[tail], axis=1).mean()
    err_kept = np.linalg.norm(kept[tail, :3] - truth[tail], axis=1).mean()
    assert err_kept < 0.5 and err_lost > 2.0, (err_kept, err_lost)
