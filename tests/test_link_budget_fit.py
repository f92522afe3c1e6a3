"""Link-budget calibration: recovers known parameters from simulated powers and detections; on the
Hanyang static sweeps it finds the receiver's saturation and the ground-reflection nulls."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

from physynth.calibrate.link_budget import (
    fit_detection_vs_distance,
    fit_link_budget_hanyang_static,
    fit_path_loss,
    path_loss_model,
)
from physynth.errors import PhySynthError

STATIC = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Static_measurements"


def test_path_loss_fit_recovers_the_law():
    rng = np.random.default_rng(4)
    d = np.tile(np.arange(2.0, 62.0, 2.0), 6)
    h = np.repeat([0.5, 0.75, 1.0, 1.5, 1.75, 2.0], 30)
    truth = np.array([-45.0, 2.2, 0.5, -70.0])
    p = path_loss_model(truth, d, h, 1.0, 0.0462) + 0.5 * rng.standard_normal(d.size)
    fit = fit_path_loss(d, h, p)
    assert fit.path_loss_exponent == pytest.approx(2.2, abs=0.1)
    assert fit.ref_power_dbm == pytest.approx(-45.0, abs=1.5)
    assert fit.ground_reflection == pytest.approx(0.5, abs=0.1)
    assert fit.saturation_dbm == pytest.approx(-70.0, abs=0.5)
    assert fit.shadowing_std_db == pytest.approx(0.5, rel=0.3)
    with pytest.raises(PhySynthError, match="at least 6 positions"):
        fit_path_loss(d[:3], h[:3], p[:3])


def test_detection_fit_recovers_the_sensitivity_and_bounds_it_without_losses():
    rng = np.random.default_rng(5)
    power = np.linspace(-70.0, -100.0, 31)
    m = np.full(power.size, 400)
    k = rng.binomial(m, ndtr((power + 90.0) / 3.0))
    fit = fit_detection_vs_distance(power, k, m, shadowing_std_db=3.0)
    assert fit.sensitivity_dbm == pytest.approx(-90.0, abs=0.5)
    assert fit.sensitivity_upper_95_dbm > fit.sensitivity_dbm
    none_lost = fit_detection_vs_distance(power[:5], m[:5], m[:5], shadowing_std_db=3.0)
    assert none_lost.sensitivity_dbm is None
    # every position detected at p >= 0.95 is compatible with the bound
    assert ndtr((power[4] - none_lost.sensitivity_upper_95_dbm) / 3.0) > 0.95


@pytest.mark.skipif(not STATIC.is_dir(), reason=f"real Hanyang static sweeps not found at {STATIC}")
def test_hanyang_static_link_budget():
    params, rep = fit_link_budget_hanyang_static(STATIC / "LOS", environment="LOS")  # LOS files only
    pl = rep["path_loss"]
    assert -82.0 < pl["saturation_dbm"] < -79.0  # the DW1000 first-path power tops out near -80 dBm
    assert 0.1 < pl["ground_reflection"] < 0.9  # the interference nulls of the two-ray term are real
    assert pl["shadowing_std_db"] < 3.0
    assert rep["detection"]["n_detected"] / rep["detection"]["n_attempts"] > 0.99  # no weak-link loss <= 60 m
    assert params.sensitivity_dbm <= rep["weakest_mean_power_dbm"]


def test_sensitivity_from_detection_rate_against_distance_of_a_recording():
    """Without received power: detections per distance bin of generated traces give back the sensitivity."""
    from helpers import simple_scenario

    from physynth.calibrate.link_budget import detection_counts_vs_distance
    from physynth.generate import compile_scenario, generate_trace

    lb = {"ref_power_dbm": -40.0, "path_loss_exponent": 2.0, "sensitivity_dbm": -80.0, "shadowing_std_db": 3.0}
    scn = simple_scenario(**{"path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [400, 0, 1]],
                                      "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}},
                             "anchors": [{"id": "A1", "pos_enu_m": [0, 0, 1]}], "channel.link_budget": lb})
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 21) for i in range(4)]
    centre, det, exp = detection_counts_vs_distance(traces, "A1", nominal_rate_hz=20.0, bin_m=10.0)
    assert det[0] / exp[0] > 0.9 and det[-1] / exp[-1] < 0.1
    fit = fit_detection_vs_distance(-40.0 - 20 * np.log10(np.maximum(centre, 1.0)), det, exp, shadowing_std_db=3.0)
    assert fit.sensitivity_dbm == pytest.approx(-80.0, abs=1.0)
