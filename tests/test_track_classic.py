"""Classical trackers: multilateration recovers a known point; the EKF converges on noiseless ranges."""

from __future__ import annotations

import numpy as np
import pytest
from track_helpers import site_scenario

from physynth.errors import PhySynthError
from physynth.generate import generate_trace
from physynth.track.inputs import track_input
from physynth.track.scoring import error_stats
from physynth.track.trackers import make_tracker
from physynth.track.trackers.ls import multilaterate


def test_multilateration_recovers_a_known_point():
    anchors = np.array([[0.0, -8, 2], [40, -8, 0.5], [40, 8, 2.5], [0, 8, 1]])
    points = np.array([[12.0, 3.0, 1.2], [30.0, -5.0, 0.7]])
    r = np.linalg.norm(points[:, None, :] - anchors[None], axis=-1)
    est = multilaterate(r, np.ones_like(r, bool), anchors, np.array([20.0, 0.0, 1.0]), prior_weight=1e-6)
    np.testing.assert_allclose(est, points, atol=1e-3)


def test_multilateration_is_robust_to_one_outlier():
    anchors = np.array([[0.0, -8, 2], [40, -8, 0.5], [40, 8, 2.5], [0, 8, 1], [20, 12, 3], [20, -12, 0]])
    p = np.array([[15.0, 2.0, 1.0]])
    r = np.linalg.norm(p[:, None, :] - anchors[None], axis=-1)
    r[0, 2] += 5.0  # one NLOS range
    est = multilaterate(r, np.ones_like(r, bool), anchors, np.array([20.0, 0.0, 1.0]), prior_weight=1e-6,
                        f_scale_m=0.1)
    assert np.linalg.norm(est[0] - p[0]) < 0.3


@pytest.fixture(scope="module")
def noiseless():
    scn = site_scenario(noise_m=1e-9)
    return track_input(generate_trace(scn, 0, 3))


def test_ekf_on_noiseless_ranges_converges_within_1cm(noiseless):
    est = make_tracker("ekf", range_std_m=0.01, fit_range_std=False, use_imu=False,
                       accel_psd_m2ps3=5.0).predict(noiseless)
    late = noiseless.t_s > noiseless.t_s[0] + 3.0  # after convergence
    err = np.linalg.norm(est - noiseless.pos_enu_m, axis=1)[late & noiseless.eval_mask()]
    assert np.percentile(err, 95) < 0.01
    assert err[-1] < 0.01


def test_ekf_imu_driven_and_ls_track_the_walk(noiseless):
    est = make_tracker("ekf", use_imu=True).predict(noiseless)
    assert error_stats(est, noiseless.pos_enu_m, noiseless.eval_mask())["rmse_m"] < 0.05
    est = make_tracker("ls").predict(noiseless)  # holds each fix until the next burst (3 m/s x 0.1 s)
    assert error_stats(est, noiseless.pos_enu_m, noiseless.eval_mask())["rmse_m"] < 0.3
    all_fresh = noiseless.fresh.all(axis=1) & noiseless.eval_mask()
    assert error_stats(est, noiseless.pos_enu_m, all_fresh)["p95_m"] < 0.05


def test_ekf_fit_takes_the_training_range_spread():
    inp = track_input(generate_trace(site_scenario(noise_m=0.2), 0, 5))
    ekf = make_tracker("ekf").fit([inp])
    assert ekf.range_std_m == pytest.approx(0.2, rel=0.15)


def test_unknown_tracker_is_a_user_error():
    with pytest.raises(PhySynthError, match="unknown tracker"):
        make_tracker("kalman")
