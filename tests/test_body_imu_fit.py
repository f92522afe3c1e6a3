"""Body-frame IMU calibration (issue 11 item 5): recovers what generated the data, and reads BROAD."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import simple_scenario_dict

from physynth.calibrate.imu_only import fit_body_imu
from physynth.generate import compile_scenario, generate_trace
from physynth.models.imu import draw_imu_device
from physynth.rng import component_rng
from physynth.scenario import scenario_from_dict

BROAD21 = (Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad-imu" / "data_mat"
           / "21_undisturbed_fast_combined.mat")


def test_fit_recovers_scale_misalignment_and_bias_of_a_simulated_device():
    d = simple_scenario_dict()
    d["attitude"] = {"kind": "tumble", "tumble_rate_std_radps": 1.0, "tumble_correlation_s": 2.0}
    d["imu_frames"] = ["body-flu"]
    d["body_imu"] = {"rate_hz": 400.0,
                     "accelerometer": {"noise_density_mps2_per_sqrt_hz": 0.002, "bias_rw_mps2_per_sqrt_s": 0.0,
                                       "scale_factor_std": 0.01, "misalignment_std_rad": 0.005,
                                       "turn_on_bias_std_mps2": 0.05},
                     "gyroscope": {"noise_density_radps_per_sqrt_hz": 0.0002, "bias_rw_radps_per_sqrt_s": 0.0,
                                   "scale_factor_std": 0.01, "misalignment_std_rad": 0.005,
                                   "turn_on_bias_std_radps": 0.01}}
    d["motion"]["dwell_start_s"] = 20.0  # a rest at the start: the calm span for the noise
    scn = scenario_from_dict(d, "test")
    tr = generate_trace(compile_scenario(scn), 0, 9)
    dev = draw_imu_device(scn.body_imu, rng=component_rng(9, 0, "imu_body"))  # the device: drawn first
    fit = fit_body_imu([tr], cutoff_hz=10.0).diagnostics
    # matrices to 1e-3 (the prior of 1 % pulls little with this much excitation), biases to a few mm/s^2
    np.testing.assert_allclose(fit["gyroscope_matrix"], dev.gyro_matrix, atol=1e-3)
    np.testing.assert_allclose(fit["gyroscope_bias_radps"], dev.gyro_turn_on_bias_radps, atol=1e-3)
    np.testing.assert_allclose(fit["accelerometer_matrix"], dev.acc_matrix, atol=2e-3)
    np.testing.assert_allclose(fit["accelerometer_bias_mps2"], dev.acc_turn_on_bias_mps2, atol=0.01)
    # white noise from the Allan deviation over the rest of a non-tumbling unit (20 s at 400 Hz: the
    # Allan deviation at 0.05 s has ~400 independent clusters, relative error ~5 %)
    d["attitude"] = {"kind": "fixed"}
    still = generate_trace(compile_scenario(scenario_from_dict(d, "test")), 0, 9)
    fit = fit_body_imu([still], cutoff_hz=10.0).diagnostics
    np.testing.assert_allclose(fit["gyroscope_white_per_axis"], 0.0002, rtol=0.2)
    np.testing.assert_allclose(fit["accelerometer_white_per_axis"], 0.002, rtol=0.2)


@pytest.mark.skipif(not BROAD21.is_file(), reason="real BROAD data not found")
def test_broad_gyro_and_accelerometer_fit():
    from physynth.io.importers import import_broad

    tr, _ = import_broad(BROAD21)
    fit = fit_body_imu([tr], cutoff_hz=10.0, offset_s=0.0025)
    d = fit.diagnostics
    # a calibrated lab IMU against optical attitude: gains within 2 %, axes within ~1.5 degrees
    np.testing.assert_allclose(np.diag(d["gyroscope_matrix"]), 1.0, atol=0.02)
    np.testing.assert_allclose(np.diag(d["accelerometer_matrix"]), 1.0, atol=0.02)
    assert np.max(np.abs(np.array(d["gyroscope_matrix"]) - np.diag(np.diag(d["gyroscope_matrix"])))) < 0.03
    # gravity is 9.82-9.90 at rest in BROAD (SOURCE.md): bias plus scale show it, of order 0.1 m/s^2
    assert np.max(np.abs(d["accelerometer_bias_mps2"])) < 0.3
    # MEMS noise: 1e-4 .. 1e-2 rad/s/sqrt(Hz) and 1e-3 .. 3e-2 m/s^2/sqrt(Hz)
    assert 1e-4 < fit.params.gyroscope.noise_density_radps_per_sqrt_hz < 1e-2
    assert 1e-3 < fit.params.accelerometer.noise_density_mps2_per_sqrt_hz < 3e-2
