"""Antenna sway: the generator's slow 3-D offset seen along each line of sight, and its calibration."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import simple_scenario

from physynth.calibrate import calibrate
from physynth.calibrate.antenna_sway import fit_antenna_sway
from physynth.generate import generate_trace, generate_traces
from physynth.models.uwb import antenna_sway


def test_sway_is_a_stationary_ou_process_with_its_std_and_correlation_time():
    std, tau, dt = 0.05, 2.0, 0.1
    t = np.arange(0.0, 4000.0, dt)
    x = antenna_sway(t, 0.0, float(t[-1]), std, tau, rng=np.random.default_rng(3))
    assert x.shape == (t.size, 3)
    n_indep = t[-1] / (2.0 * tau)  # independent stretches of an OU process for its variance
    assert np.std(x, axis=0) == pytest.approx(np.full(3, std), rel=4.0 / np.sqrt(2.0 * n_indep))
    k = int(round(tau / dt))
    rho = np.mean([np.corrcoef(x[:-k, i], x[k:, i])[0, 1] for i in range(3)])
    assert rho == pytest.approx(np.exp(-1.0), abs=4.0 / np.sqrt(3.0 * n_indep))
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < 4.0 / np.sqrt(n_indep)  # independent axes
    start = antenna_sway(np.zeros(1), 0.0, 10.0, std, tau, rng=np.random.default_rng(4))
    assert np.all(np.abs(start) < 6 * std)  # drawn from the stationary law, not from 0 or far out


def test_each_range_sees_the_offset_along_its_line_of_sight():
    """Anchors in one direction see the same error; an anchor on the other side sees it negated."""
    anchors = [{"id": "A1", "pos_enu_m": [-1000.0, 0.0, 1.0]}, {"id": "A2", "pos_enu_m": [-2000.0, 0.0, 1.0]},
               {"id": "A3", "pos_enu_m": [3000.0, 0.0, 1.0]}]
    line = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [300, 0, 1]],
            "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}}  # along x: every line of sight is +-x
    scn = simple_scenario(anchors=anchors, path=line, **{"uwb.antenna_sway_std_m": 0.1, "uwb.antenna_sway_tau_s": 1.0,
                                                         "uwb.slot_s": 0.0, "channel.los_std_m": 1e-9})
    tr = generate_trace(scn, 0, 5)
    u = tr.uwb
    err = u.range_m - u.true_range_m
    e = {a: err[u.anchor == a] for a in range(3)}  # one attempt per anchor and burst, same times
    n = min(x.size for x in e.values())
    assert np.std(e[0][:n]) > 0.03
    np.testing.assert_allclose(e[0][:n], e[1][:n], atol=1e-6)  # same direction (x), same error
    np.testing.assert_allclose(e[0][:n], -e[2][:n], atol=1e-6)  # opposite direction: opposite sign
    plain = generate_trace(simple_scenario(anchors=anchors, path=line,
                                           **{"uwb.slot_s": 0.0, "channel.los_std_m": 1e-9}), 0, 5)
    np.testing.assert_array_equal(plain.uwb.true_range_m, u.true_range_m)  # no other draw moved


def test_calibration_recovers_the_sway_and_keeps_the_white_rest():
    std, tau, white = 0.06, 2.0, 0.02
    scn = simple_scenario(**{"uwb.antenna_sway_std_m": std, "uwb.antenna_sway_tau_s": tau,
                             "channel.los_std_m": white, "motion.cruise_speed_mps": 1.0})
    traces = list(generate_traces(scn, 3, seed=7))
    fit = calibrate(traces)
    sc = fit.scenario
    span = sum(t.duration_s for t in traces)
    n_indep = span / (2.0 * tau)
    assert sc.uwb.antenna_sway_std_m == pytest.approx(std, rel=4.0 / np.sqrt(2.0 * n_indep))
    assert sc.uwb.antenna_sway_tau_s == pytest.approx(tau, rel=0.25)
    assert sc.channel.los_std_m == pytest.approx(white, rel=0.35)


def test_white_errors_give_no_sway():
    traces = list(generate_traces(simple_scenario(**{"channel.los_std_m": 0.06}), 2, seed=8))
    fit = calibrate(traces)
    assert fit.scenario.uwb.antenna_sway_std_m == 0.0
    assert not fit.report["antenna_sway"]["identifiable"]
    assert any(s.startswith("uwb.antenna_sway_") for s in fit.report["not_identifiable"])


def test_fit_on_a_known_sequence():
    """The estimator alone, on OU + white sequences of one anchor with gaps in time."""
    rng = np.random.default_rng(11)
    seqs = []
    for _ in range(6):
        t = np.sort(rng.uniform(0.0, 600.0, 5000))
        x = antenna_sway(t, 0.0, 600.0, 0.05, 1.5, rng=rng)[:, 0] + rng.normal(0.0, 0.02, t.size)
        seqs.append((x, t))
    fit = fit_antenna_sway(seqs)
    assert fit["identifiable"]
    assert fit["std_m"] == pytest.approx(0.05, rel=0.15) and fit["tau_s"] == pytest.approx(1.5, rel=0.25)
    assert fit["white_std_m"] == pytest.approx(0.02, rel=0.3)
