"""The tag antenna pattern: a range bias that follows the anchor's bearing relative to the carrier's
heading (``uwb.tag_pattern_m``), in the generator and in calibration."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import simple_scenario, uwb_only_traces

from physynth.calibrate import calibrate
from physynth.calibrate.tag_pattern import WALD_MIN, fit_tag_pattern
from physynth.generate import generate_trace
from physynth.models.uwb import heading_unit, relative_bearing

ZIGZAG = {"kind": "waypoints", "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0},
          "waypoints_enu_m": [[0, 0, 1], [30, 0, 1], [30, 30, 1], [60, 30, 1], [60, 0, 1], [90, 0, 1], [90, 30, 1],
                              [120, 30, 1], [120, 0, 1], [150, 0, 1], [150, 30, 1]]}
"""Ten 30 m legs with a right angle between each: anchors seen ahead, behind and beside the carrier."""
ANCHORS = [{"id": "A1", "pos_enu_m": [-40, -60, 3]}, {"id": "A2", "pos_enu_m": [200, -60, 3]},
           {"id": "A3", "pos_enu_m": [80, 90, 3]}]


def test_heading_is_the_direction_of_travel_held_through_stops():
    vel = np.array([[0, 0, 0], [0.1, 0, 0], [2, 0, 0], [0, 0, 0], [0, -3, 1], [0.2, 0.1, 0], [np.nan, 0, 0]], float)
    h = heading_unit(vel)
    np.testing.assert_allclose(h, [[1, 0], [1, 0], [1, 0], [1, 0], [0, -1], [0, -1], [0, -1]])
    np.testing.assert_allclose(heading_unit(np.array([[0, 0.2, 0], [0, 0, 0]], float)), [[1, 0], [1, 0]])
    np.testing.assert_allclose(heading_unit(np.array([[0, 0, 0], [-1, 1, 0]], float)),
                               np.full((2, 2), [-1, 1]) / np.sqrt(2))


def test_relative_bearing_is_zero_ahead_and_a_quarter_turn_to_the_left():
    east = (np.array([1.0, 1.0, 1.0, 1.0]), np.zeros(4))
    cos_phi, sin_phi = relative_bearing(np.array([5.0, 0.0, -2.0, 3.0]), np.array([0.0, 7.0, 0.0, -3.0]), *east)
    np.testing.assert_allclose(cos_phi, [1, 0, -1, np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(sin_phi, [0, 1, 0, -np.sqrt(0.5)], atol=1e-12)
    north = (np.zeros(1), np.ones(1))
    np.testing.assert_allclose(relative_bearing(np.array([-1.0]), np.array([0.0]), *north), [[0], [1]], atol=1e-12)


def test_every_range_carries_the_pattern_at_its_bearing():
    """No other error: measured - true range is c1 cos phi + ... + s2 sin 2 phi, phi computed here from
    the truth by atan2 (the anchor's bearing minus the direction of travel), wherever the carrier moves."""
    coef = [0.01, -0.02, 0.03, 0.015]
    scn = simple_scenario(path=ZIGZAG, anchors=ANCHORS, **{"uwb.tag_pattern_m": coef, "uwb.slot_s": 0.0,
                                                           "motion.cruise_speed_mps": 1.5})
    tr = generate_trace(scn, 0, 3)
    u, truth = tr.uwb, tr.truth
    ok = u.valid
    t = u.t_s[ok]
    pos = truth.position_at(t)
    vel = np.stack([np.interp(t, truth.t_s, truth.vel_enu_mps[:, k]) for k in range(2)], axis=1)
    moving = np.hypot(vel[:, 0], vel[:, 1]) > 0.5
    a = tr.anchors.pos_enu_m[u.anchor[ok]]
    phi = np.arctan2(a[:, 1] - pos[:, 1], a[:, 0] - pos[:, 0]) - np.arctan2(vel[:, 1], vel[:, 0])
    want = coef[0] * np.cos(phi) + coef[1] * np.sin(phi) + coef[2] * np.cos(2 * phi) + coef[3] * np.sin(2 * phi)
    err = (u.range_m - u.true_range_m)[ok]
    assert moving.sum() > 5000
    np.testing.assert_allclose(err[moving], want[moving], atol=1e-6)
    assert np.ptp(err[moving]) > 0.08  # the bearings vary enough to see every term
    plain = generate_trace(simple_scenario(path=ZIGZAG, anchors=ANCHORS, **{"uwb.slot_s": 0.0,
                                                                           "motion.cruise_speed_mps": 1.5}), 0, 3)
    np.testing.assert_array_equal(plain.uwb.true_range_m, u.true_range_m)  # deterministic: no draw moved


def _walk(**extra):
    return simple_scenario(path=ZIGZAG, anchors=ANCHORS, **{
        "uwb.antenna_sway_std_m": 0.05, "uwb.antenna_sway_clock": "motion", "uwb.antenna_sway_length_m": 20.0,
        "uwb.antenna_sway_turn_rad": 0.4, "channel.los_std_m": 0.03, "motion.cruise_speed_mps": 1.2,
        "attitude.kind": "tangent", "uwb.burst_rate_hz": 10.0, "channel.rate_hz": 10.0, **extra})


def test_calibration_recovers_the_pattern_through_the_sway():
    """A cos 2 phi pattern of 2.5 cm under a 5 cm sway on the motion clock and 3 cm of white error, four
    walks of the zigzag: the fitted term within 3 jackknife standard errors and kept; the absent terms
    within 4 standard errors of 0 and set to 0 (a term is kept beyond 3: on these walks the slow sway
    alone happens to give sin phi -12 mm, measured on the true errors, which a 2-standard-error rule kept)."""
    traces = uwb_only_traces(_walk(**{"uwb.tag_pattern_m": [0.0, 0.0, 0.025, 0.0]}), 4, 11)
    fit = calibrate(traces, tag_pattern=True)
    rep = fit.report["tag_pattern"]
    assert rep["kept"] and rep["applied"] and rep["wald"] > WALD_MIN
    se, got = np.asarray(rep["std_error_m"]), np.asarray(rep["fitted_coef_m"])
    assert got[2] == pytest.approx(0.025, abs=3 * se[2])
    assert se[2] < 0.008  # the estimate is informative, not just wide
    assert np.all(np.abs(got[[0, 1, 3]]) < 4 * se[[0, 1, 3]])
    assert rep["terms_kept"] == ["cos2"]
    assert fit.scenario.uwb.tag_pattern_m == [0.0, 0.0, pytest.approx(got[2], abs=1e-4), 0.0]
    # the sway is fitted on the residuals without the pattern: its std is the one drawn
    assert fit.scenario.uwb.antenna_sway_std_m == pytest.approx(0.05, rel=0.3)
    # by default the same fit is reported and nothing is generated
    plain = calibrate(traces)
    assert plain.report["tag_pattern"]["kept"] and not plain.report["tag_pattern"]["applied"]
    assert plain.report["tag_pattern"]["fitted_coef_m"] == pytest.approx(rep["fitted_coef_m"], abs=1e-9)
    assert plain.scenario.uwb.tag_pattern_m == [0.0, 0.0, 0.0, 0.0]


def test_no_pattern_is_found_where_there_is_none():
    """The same walks without a pattern: the Wald test (p = 0.001) keeps nothing, the slow sway on the
    motion clock notwithstanding (it changes at the turns, like a pattern would, but with no sign tied to
    the bearing)."""
    fit = calibrate(uwb_only_traces(_walk(), 4, 12), tag_pattern=True)
    rep = fit.report["tag_pattern"]
    assert rep["identifiable"] and not rep["kept"], rep["wald"]
    assert fit.scenario.uwb.tag_pattern_m == [0.0, 0.0, 0.0, 0.0]


def test_bearings_that_do_not_vary_leave_the_pattern_unidentified():
    """Anchors on the line of travel: every bearing is 0 or pi, the sine terms vanish and the normal
    equations are singular; the fit says why instead of failing, and keeps nothing."""
    rng = np.random.default_rng(5)
    seqs = []
    for run in range(3):
        t = np.arange(0.0, 300.0, 0.1)
        cos_phi = np.where(t < 150.0, 1.0, -1.0)  # towards the anchor, then away from it
        feats = np.stack([cos_phi, np.zeros_like(t), np.ones_like(t), np.zeros_like(t)], axis=1)
        g = 5.0 + np.abs(150.0 - t)
        seqs.append((0.02 * rng.standard_normal(t.size), g, feats, t, np.full(t.size, 1.0), run))
    rep = fit_tag_pattern(seqs)
    assert not rep["identifiable"] and not rep["kept"] and rep["coef_m"] == [0.0] * 4
    assert "barely vary" in rep["why"]
