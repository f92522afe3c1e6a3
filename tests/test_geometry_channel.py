"""The geometry-aware channel: obstacles make NLOS exactly while they cut the line of sight; the link
budget makes detection fall with distance as configured; antenna orientation and ground reflection."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import binomial_tol, simple_scenario
from scipy.special import ndtr

from physynth.errors import ScenarioError
from physynth.generate import compile_scenario, generate_trace
from physynth.models.obstacles import (
    TerrainGrid,
    points_in_polygon,
    segment_below_terrain,
    segment_hits_box,
    segment_hits_prism,
)
from physynth.models.uwb import ground_gain_db, received_power_dbm
from physynth.records import Reason

STRAIGHT = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [300, 0, 1]],
            "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}}


def _trace(scn, i=0, seed=3):
    return generate_trace(compile_scenario(scn), i, seed)


def test_a_wall_makes_the_anchor_nlos_exactly_while_the_segment_crosses_it():
    wall = {"kind": "wall", "vertices_en_m": [[100, 10], [140, 10]], "base_m": 0.0, "top_m": 10.0}
    scn = simple_scenario(**{"path": STRAIGHT, "uwb.obstacles": [wall]})
    tr = _trace(scn)
    u = tr.uwb
    assert u.nlos_known
    tag = tr.truth.position_at(u.t_s)
    anchor = tr.anchors.pos_enu_m[u.anchor]
    # oracle: where the segment tag -> anchor meets the plane N = 10, is it on the wall (E in [100, 140],
    # U in [0, 10])? Rows whose crossing sits within 1 mm of the wall's edge are left out.
    t = (10.0 - tag[:, 1]) / (anchor[:, 1] - tag[:, 1])
    e = tag[:, 0] + t * (anchor[:, 0] - tag[:, 0])
    z = tag[:, 2] + t * (anchor[:, 2] - tag[:, 2])
    crosses = (t >= 0) & (t <= 1) & (e >= 100) & (e <= 140) & (z >= 0) & (z <= 10)
    clear = (np.abs(e - 100) > 1e-3) & (np.abs(e - 140) > 1e-3)
    assert crosses.sum() > 50 and (~crosses).sum() > 50
    np.testing.assert_array_equal(u.nlos[clear], crosses[clear])
    # blocked rows carry the NLOS offset (default mixture mean 1 m), LOS rows the (zero) LOS error
    err = u.range_m - u.true_range_m
    assert np.all(np.abs(err[~u.nlos]) < 1e-6)
    assert np.mean(err[u.nlos]) == pytest.approx(1.0, abs=5 * 0.5 / np.sqrt(u.nlos.sum()))


def test_obstacles_off_by_default_and_a_box_over_the_route_blocks_everyone():
    base = simple_scenario(**{"path": STRAIGHT})
    assert not _trace(base).uwb.nlos.any()
    box = {"kind": "box", "min_enu_m": [140, -50, -5], "max_enu_m": [160, 50, 50]}
    tr = _trace(simple_scenario(**{"path": STRAIGHT, "uwb.obstacles": [box]}))
    pos = tr.truth.position_at(tr.uwb.t_s)
    inside = (pos[:, 0] > 140) & (pos[:, 0] < 160)
    assert np.all(tr.uwb.nlos[inside])


def test_segment_tests_agree_with_dense_sampling():
    rng = np.random.default_rng(0)
    p = rng.uniform(-10, 10, (1500, 3))
    q = rng.uniform(-10, 10, (1500, 3))
    s = np.linspace(0, 1, 1001)[None, :, None]
    pts = p[:, None, :] + s * (q - p)[:, None, :]
    lo, hi = np.array([-2.0, -3.0, -1.0]), np.array([3.0, 2.0, 4.0])

    def sampled_box(lo_, hi_):
        return np.any(np.all((pts >= lo_) & (pts <= hi_), axis=2), axis=1)

    hit = segment_hits_box(p, q, lo, hi)
    # exact test vs sampling: a sampled hit of the box is an exact hit; an exact hit is a sampled hit of
    # the box grown by the sampling step (<= 0.035 m here)
    assert np.all(hit[sampled_box(lo, hi)])
    assert np.all(sampled_box(lo - 0.04, hi + 0.04)[hit])
    assert 0.1 < hit.mean() < 0.9

    poly = np.array([[-4.0, -4.0], [4.0, -4.0], [4.0, 4.0], [0.0, 0.0], [-4.0, 4.0]])  # non-convex
    hitp = segment_hits_prism(p, q, poly, -1.0, 3.0)
    flat = pts.reshape(-1, 3)
    in_fp = points_in_polygon(flat[:, 0], flat[:, 1], poly).reshape(pts.shape[:2])
    sampled = np.any(in_fp & (pts[..., 2] >= -1.0) & (pts[..., 2] <= 3.0), axis=1)
    assert np.all(hitp[sampled])
    assert (hitp & ~sampled).mean() < 0.02  # grazing hits between samples only
    assert 0.1 < hitp.mean() < 0.9


def test_terrain_ridge_blocks_low_links_only():
    ridge = TerrainGrid(origin_en_m=[0.0, -10.0], spacing_m=1.0,
                        heights_m=[[5.0 if 9 <= k <= 11 else 0.0 for k in range(21)] for _ in range(21)])
    p = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 12.0]])
    q = np.array([[20.0, 0.0, 1.0], [20.0, 0.0, 12.0], [20.0, 0.0, 12.0]])
    # at E = 10 the segments are at U = 1, 6.5, 12: only the first is below the 5 m ridge
    np.testing.assert_array_equal(segment_below_terrain(p, q, ridge), [True, False, False])


def _link_scenario(**over):
    lb = {"ref_power_dbm": -40.0, "path_loss_exponent": 2.0, "sensitivity_dbm": -80.0, "shadowing_std_db": 3.0}
    path = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [400, 0, 1]],
            "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}}
    return simple_scenario(**{"path": path, "anchors": [{"id": "A1", "pos_enu_m": [0, 0, 1]}],
                              "channel.link_budget": lb, **over})


def test_detection_probability_falls_with_distance_as_configured():
    scn = _link_scenario()
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 11) for i in range(6)]
    r = np.concatenate([t.uwb.true_range_m for t in traces])
    det = np.concatenate([t.uwb.reason != Reason.NO_LINK for t in traces])
    rates = []
    for lo in (40.0, 80.0, 100.0, 120.0, 180.0):
        sel = (r >= lo) & (r < lo + 10)
        expect = np.mean(ndtr((-40.0 - 20 * np.log10(r[sel]) + 80.0) / 3.0))  # oracle: the configured law
        assert det[sel].mean() == pytest.approx(expect, abs=binomial_tol(max(expect, 0.01), int(sel.sum())) + 1e-3)
        rates.append(det[sel].mean())
    assert rates == sorted(rates, reverse=True) and rates[0] > 0.95 and rates[-1] < 0.05


def test_link_budget_is_off_by_default_and_numbers_do_not_move():
    base = simple_scenario()
    a = _trace(base)
    b = _trace(simple_scenario(**{"uwb.obstacles": []}))
    np.testing.assert_array_equal(a.uwb.range_m, b.uwb.range_m)
    assert np.all(a.uwb.reason == Reason.OK)


def test_antenna_front_back_and_ground_reflection():
    scn = _link_scenario(anchors=[{"id": "A1", "pos_enu_m": [0, 0, 1], "boresight_enu": [1, 0, 0],
                                   "front_back_db": 12.0}])
    ch = compile_scenario(scn).channel
    tag = np.array([[50.0, 0.0, 1.0], [-50.0, 0.0, 1.0], [0.0, 50.0, 1.0]])
    p = received_power_dbm(tag, np.zeros(3, dtype=np.int64), ch)
    assert p[0] - p[1] == pytest.approx(12.0)  # behind: -front_back_db
    assert p[0] - p[2] == pytest.approx(6.0)  # side: half of it
    assert p[0] == pytest.approx(-40.0 - 20 * np.log10(50.0))
    # two-ray: a null where the ground path is one wavelength longer, |1 - rho| there
    lam, ha, ht = 0.0462, 0.5, 1.0
    d = np.linspace(5, 60, 20000)
    g = ground_gain_db(d, np.full_like(d, ha), np.full_like(d, ht), np.full_like(d, 0.6), np.full_like(d, lam))
    d_null = d[np.argmin(g)]
    assert np.hypot(d_null, ha + ht) - np.hypot(d_null, ha - ht) == pytest.approx(lam, rel=1e-3)
    assert g.min() == pytest.approx(20 * np.log10(0.4), abs=0.01)


def test_bad_obstacles_are_one_line_scenario_errors():
    with pytest.raises(ScenarioError, match="top_m must be above base_m"):
        simple_scenario(**{"uwb.obstacles": [{"kind": "wall", "vertices_en_m": [[0, 0], [1, 0]], "base_m": 3,
                                              "top_m": 1}]})
    with pytest.raises(ScenarioError):
        simple_scenario(**{"uwb.obstacles": [{"kind": "dome", "top_m": 1}]})


def test_obstacle_losses_prefilter_changes_nothing():
    from physynth.models.obstacles import (
        BoxObstacle,
        PrismObstacle,
        WallObstacle,
        obstacle_losses,
        segment_hits_vertical_rect,
    )

    rng = np.random.default_rng(2)
    p = rng.uniform(0, 100, (5000, 3)) * [1, 1, 0.3]
    q = rng.uniform(0, 100, (5000, 3)) * [1, 1, 0.3]
    obs = [BoxObstacle(min_enu_m=[10, 10, 0], max_enu_m=[20, 30, 8], loss_db=5.0),
           WallObstacle(vertices_en_m=[[40, 0], [40, 50], [60, 60]], top_m=12.0, loss_db=7.0),
           PrismObstacle(vertices_en_m=[[70, 70], [90, 70], [80, 95]], base_m=2.0, top_m=20.0, loss_db=11.0)]
    blocked, loss = obstacle_losses(p, q, obs)
    h_box = segment_hits_box(p, q, np.array([10.0, 10, 0]), np.array([20.0, 30, 8]))
    h_wall = (segment_hits_vertical_rect(p, q, np.array([40.0, 0]), np.array([40.0, 50]), 0.0, 12.0)
              | segment_hits_vertical_rect(p, q, np.array([40.0, 50]), np.array([60.0, 60]), 0.0, 12.0))
    h_prism = segment_hits_prism(p, q, np.array([[70.0, 70], [90, 70], [80, 95]]), 2.0, 20.0)
    np.testing.assert_array_equal(blocked, h_box | h_wall | h_prism)
    np.testing.assert_allclose(loss, 5.0 * h_box + 7.0 * h_wall + 11.0 * h_prism)
    assert h_box.any() and h_wall.any() and h_prism.any()
