"""The IMU lever arm: a sensor at r in the body frame reads R (alpha x r + w x (w x r)) on top of the
reference point's acceleration (docs/imu.md). The generator's term against an independent second
derivative of the sensor point's track, and the calibration's recovery of a lever arm put into
synthetic data, within tolerances from the sample size."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from physynth.calibrate.imu_fit import fit_imu
from physynth.calibrate.lever_arm import fit_lever_arm, lever_arm_design
from physynth.models.attitude import body_rates
from physynth.models.imu import ImuParams, VibrationParams, simulate_imu
from physynth.models.motion import Kinematics
from physynth.records import Anchors, Imu, Trace, Truth, Uwb

FS, DURATION_S, UP = 200.0, 120.0, 10
SIGMA = 0.05  # white IMU noise per sample [m/s^2]
R_TRUE = np.array([0.02, -0.03, 0.05])


def _motion(seed: int):
    """A tumbling, translating body on a grid UP times finer than the IMU: sums of sinusoids of
    0.2-1.2 Hz (positions 0.2 m, rotation vector 0.5 rad per component)."""
    rng = np.random.default_rng(seed)
    tf = np.arange(int(DURATION_S * FS * UP)) / (FS * UP)
    fp, pp = rng.uniform(0.2, 1.2, (3, 3)), rng.uniform(0, 2 * np.pi, (3, 3))
    pos = (0.2 * np.sin(2 * np.pi * fp[None] * tf[:, None, None] + pp[None])).sum(2)
    fr, pr = rng.uniform(0.2, 1.2, (3, 3)), rng.uniform(0, 2 * np.pi, (3, 3))
    rot = Rotation.from_rotvec((0.5 * np.sin(2 * np.pi * fr[None] * tf[:, None, None] + pr[None])).sum(2))
    return tf, pos, rot


def _point_acc(tf, pos, rot, r):
    """Acceleration of the body point r (body frame): the track pos + R r differentiated twice on the fine grid."""
    dt = tf[1] - tf[0]
    return np.gradient(np.gradient(pos + rot.apply(r), dt, axis=0), dt, axis=0)[::UP]


def _trace(r, seed=3, noise_seed=7) -> Trace:
    tf, pos, rot = _motion(seed)
    t, p, rr = tf[::UP], pos[::UP], rot[::UP]
    acc = _point_acc(tf, pos, rot, r) + np.random.default_rng(noise_seed).standard_normal((t.size, 3)) * SIGMA
    truth = Truth(t_s=t, pos_enu_m=p, vel_enu_mps=np.gradient(p, t, axis=0), quat_wxyz=rr.as_quat(scalar_first=True),
                  omega_body_radps=body_rates(rr, t))
    return Trace(truth=truth, imu=Imu(t_s=t, acc_mps2=acc),
                 uwb=Uwb(t_s=np.zeros(0), anchor=np.zeros(0, np.int16), range_m=np.zeros(0)),
                 anchors=Anchors(ids=(), pos_enu_m=np.zeros((0, 3))))


def _white_se(tr: Trace) -> np.ndarray:
    """Least-squares standard error of each lever-arm component under white noise SIGMA."""
    d, ok = lever_arm_design(tr, 10.0, 0.0)
    return SIGMA / np.sqrt(np.sum(d[ok] ** 2, axis=(0, 1)))


def test_generator_lever_arm_is_the_sensor_points_acceleration():
    tf, pos, rot = _motion(3)
    t, rr = tf[::UP], rot[::UP]
    a_ref, a_point = _point_acc(tf, pos, rot, np.zeros(3)), _point_acc(tf, pos, rot, R_TRUE)
    kin = Kinematics(t_s=t, s_m=np.zeros(t.size), pos_enu_m=pos[::UP], vel_enu_mps=np.zeros((t.size, 3)),
                     acc_enu_mps2=a_ref)
    params = ImuParams(rate_hz=FS, white_noise_density_mps2_per_sqrt_hz=[0.0, 0.0, 0.0], bias_rw_mps2_per_sqrt_s=0.0,
                       vibration=VibrationParams(amplitude_mps2=0.0), lever_arm_m=R_TRUE.tolist())
    imu = simulate_imu(kin, params, rng=np.random.default_rng(1), omega_body_radps=body_rates(rr, t), attitude=rr)
    term = a_point - a_ref  # about 1.1-1.3 m/s^2 RMS per axis
    diff = (imu.acc_mps2 - a_point[:-1])[5:-5]
    # the model's rate is the mean of two step rates and alpha a central difference: O(dt^2) errors,
    # measured 3-4e-4 of the term's RMS (a sign or frame error would be of order 1)
    assert np.all(np.sqrt(np.mean(diff**2, axis=0)) < 1e-3 * np.sqrt(np.mean(term**2, axis=0)))


def test_default_imu_has_no_lever_arm_and_ignores_the_attitude():
    tf, pos, rot = _motion(4)
    t = tf[::UP]
    kin = Kinematics(t_s=t, s_m=np.zeros(t.size), pos_enu_m=pos[::UP], vel_enu_mps=np.zeros((t.size, 3)),
                     acc_enu_mps2=_point_acc(tf, pos, rot, np.zeros(3)))
    params = ImuParams(rate_hz=FS)
    assert params.lever_arm_m == [0.0, 0.0, 0.0]
    w = body_rates(rot[::UP], t)
    a = simulate_imu(kin, params, rng=np.random.default_rng(2), omega_body_radps=w).acc_mps2
    b = simulate_imu(kin, params, rng=np.random.default_rng(2), omega_body_radps=w, attitude=rot[::UP]).acc_mps2
    np.testing.assert_array_equal(a, b)


def test_fit_recovers_a_lever_arm_put_into_synthetic_data():
    tr = _trace(R_TRUE)
    r_hat, diag = fit_lever_arm([tr], 10.0, 0.0)
    se = _white_se(tr)  # about 1e-5 m from 24 000 samples
    assert np.all(np.abs(r_hat - R_TRUE) < 5.0 * se), (r_hat, se)
    # the block (sandwich) standard error agrees with the white-noise one when the noise is white
    assert np.all(np.abs(np.asarray(diag["std_error_m"]) / se - 1.0) < 0.3)
    fit = fit_imu([tr], lever_arm=True)
    assert fit.diagnostics["lever_arm"]["kept"]
    assert np.all(np.abs(np.asarray(fit.params.lever_arm_m) - R_TRUE) < 5.0 * se + 5e-6)  # 4 significant digits


def test_fit_finds_no_lever_arm_where_there_is_none():
    tr = _trace(np.zeros(3))
    r_hat, _ = fit_lever_arm([tr], 10.0, 0.0)
    assert np.all(np.abs(r_hat) < 5.0 * _white_se(tr))
    fit = fit_imu([tr], lever_arm=True)
    assert not fit.diagnostics["lever_arm"]["kept"]
    assert fit.params.lever_arm_m == [0.0, 0.0, 0.0]


def test_body_imu_reads_the_specific_force_of_the_sensor_point():
    from physynth.constants import G0_MPS2
    from physynth.models.imu import AccelerometerParams, BodyImuParams, GyroscopeParams, simulate_body_imu

    tf, pos, rot = _motion(5)
    t, rr = tf[::UP], rot[::UP]
    a_ref, a_point = _point_acc(tf, pos, rot, np.zeros(3)), _point_acc(tf, pos, rot, R_TRUE)
    quiet = {"noise_density_mps2_per_sqrt_hz": 0.0, "bias_rw_mps2_per_sqrt_s": 0.0}
    params = BodyImuParams(rate_hz=FS, lever_arm_m=R_TRUE.tolist(), accelerometer=AccelerometerParams(**quiet),
                           gyroscope=GyroscopeParams(noise_density_radps_per_sqrt_hz=0.0, bias_rw_radps_per_sqrt_s=0.0))
    _, acc, _ = simulate_body_imu(t, a_ref, rr, body_rates(rr, t), params, rng=np.random.default_rng(3))
    f_point = rr.inv().apply(a_point + np.array([0.0, 0.0, G0_MPS2]))[:-1]
    term = rr.inv().apply(a_point - a_ref)
    diff = (acc - f_point)[5:-5]
    # as for the ENU sensor: O(dt^2) discretisation, well below 1e-3 of the term (a frame error: order 1)
    assert np.all(np.sqrt(np.mean(diff**2, axis=0)) < 1e-3 * np.sqrt(np.mean(term**2, axis=0)))
    params0 = params.model_copy(update={"lever_arm_m": [0.0, 0.0, 0.0]})
    _, acc0, _ = simulate_body_imu(t, a_ref, rr, body_rates(rr, t), params0, rng=np.random.default_rng(3))
    assert np.sqrt(np.mean((acc0 - f_point)[5:-5] ** 2)) > 0.3  # without it, the sensor point is missed
