"""Body-frame IMU and attitude against physics: strapdown integration, Allan slopes, gravity at rest.

Oracles independent of the model code: a strapdown integrator written here with plain quaternion
algebra (not the model's scipy calls), the analytic Allan deviation of white noise (N / sqrt(tau))
and of a rate random walk (K sqrt(tau / 3)).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physynth.constants import G0_MPS2
from physynth.evaluate.stats import allan_deviation
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.models.attitude import AttitudeParams, simulate_attitude
from physynth.models.imu import BodyImuParams, ImuParams, simulate_body_imu, simulate_imu
from physynth.models.motion import Kinematics
from physynth.scenario import scenario_from_dict, scenario_to_dict

NOISELESS = {"accelerometer": {"noise_density_mps2_per_sqrt_hz": 0.0, "bias_rw_mps2_per_sqrt_s": 0.0},
             "gyroscope": {"noise_density_radps_per_sqrt_hz": 0.0, "bias_rw_radps_per_sqrt_s": 0.0}}


def _body_scenario(preset: str, attitude: dict, body_imu: dict | None = None):
    d = scenario_to_dict(load_scenario(preset))
    d["attitude"] = attitude
    d["imu_frames"] = ["enu-gravity-free", "body-flu"]
    d["body_imu"] = {**d["body_imu"], **(body_imu or {})}
    return scenario_from_dict(d, "test")


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-first quaternions (test oracle, independent of scipy)."""
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    qv = np.concatenate([[0.0], v])
    return _qmul(_qmul(q, qv), q * np.array([1.0, -1.0, -1.0, -1.0]))[1:]


def _strapdown(t_imu, acc_b, gyro_b, q0, v0, p0):
    """Attitude, velocity, position at every IMU sample: exact rotation per constant-rate step,
    trapezoidal velocity and position."""
    n = t_imu.size
    dt = t_imu[1] - t_imu[0]
    q = np.empty((n, 4))
    q[0] = q0
    for j in range(n - 1):  # the oracle integrates sample by sample, as a navigation filter does
        w = gyro_b[j]
        ang = np.linalg.norm(w) * dt
        axis = w / np.linalg.norm(w) if ang > 0 else np.zeros(3)
        dq = np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis])
        q[j + 1] = _qmul(q[j], dq)
    a_w = np.array([_rotate(q[j], acc_b[j]) for j in range(n)]) + np.array([0.0, 0.0, -G0_MPS2])
    v = v0 + np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (a_w[1:] + a_w[:-1]) * dt, axis=0)])
    p = p0 + np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
    return q, v, p


@pytest.mark.parametrize("attitude", [{"kind": "pendulum", "pendulum_period_s": 3.0},
                                      {"kind": "tumble", "tumble_rate_std_radps": 0.5}])
def test_strapdown_of_noiseless_imu_reproduces_the_truth_path(attitude):
    """A full cable-car trace (~110 s, 400 Hz): attitude to 1e-9 rad, velocity to 5 mm/s, position
    to 0.1 m. The bounds are set by the linear interpolation of the specific force between the
    100 Hz truth samples (second order in the step), integrated over the trace. Integration starts at
    the second truth sample: the preset's speed profile starts with a step in acceleration, which the
    sample at t = 0 (at rest) cannot carry."""
    scn = _body_scenario("cablecar-descending", attitude, NOISELESS)
    tr = generate_trace(compile_scenario(scn), 0, 3)
    truth, imu = tr.truth, tr.imu
    q, v, p = _strapdown(imu.t_s[4:], imu.acc_body_mps2[4:], imu.gyro_body_radps[4:], truth.quat_wxyz[1],
                         truth.vel_enu_mps[1], truth.pos_enu_m[1])
    at_truth = np.arange(0, imu.t_s.size - 4, 4)  # 400 Hz IMU, 100 Hz truth: every 4th sample
    k = np.arange(at_truth.size) + 1
    rel = Rotation.from_quat(q[at_truth], scalar_first=True).inv() * Rotation.from_quat(truth.quat_wxyz[k],
                                                                                       scalar_first=True)
    assert np.max(rel.magnitude()) < 1e-9
    assert np.max(np.abs(v[at_truth] - truth.vel_enu_mps[k])) < 5e-3
    assert np.max(np.abs(p[at_truth] - truth.pos_enu_m[k])) < 0.1
    assert truth.t_s[-1] - truth.t_s[0] > 90.0  # a full trace, not a stub


def test_gyroscope_integrates_the_truth_attitude_exactly_for_every_kind():
    t = np.arange(0, 20.0, 0.01)
    vel = np.stack([np.cos(0.3 * t), np.sin(0.3 * t), 0.1 * np.ones_like(t)], axis=1)
    acc = np.stack([-0.3 * np.sin(0.3 * t), 0.3 * np.cos(0.3 * t), np.zeros_like(t)], axis=1)
    for kind, spectrum in (("tangent", "ou"), ("pendulum", "ou"), ("tumble", "ou"), ("tumble", "smooth"),
                           ("fixed", "ou")):
        att = simulate_attitude(t, vel, acc, AttitudeParams(kind=kind, tumble_spectrum=spectrum),
                                rng=np.random.default_rng(1))
        step = Rotation.from_rotvec(att.omega_body_radps[:-1] * 0.01)
        pred = att.rot[:-1] * step
        assert np.max((pred.inv() * att.rot[1:]).magnitude()) < 1e-12, kind
    # tangent: body x along the horizontal velocity, level
    att = simulate_attitude(t, vel, acc, AttitudeParams(kind="tangent"))
    x_b = att.rot.apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(x_b[:, :2], vel[:, :2] / np.linalg.norm(vel[:, :2], axis=1, keepdims=True), atol=1e-12)
    np.testing.assert_allclose(x_b[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(att.omega_body_radps[:-1, 2], 0.3, rtol=1e-9)


def test_smooth_tumble_has_its_spread_correlation_and_no_jumps():
    t = np.arange(0, 4000.0, 0.01)
    z = np.zeros((t.size, 3))
    tau, std = 0.5, 1.5
    params = AttitudeParams(kind="tumble", tumble_spectrum="smooth", tumble_rate_std_radps=std,
                            tumble_correlation_s=tau)
    smooth = simulate_attitude(t, z, z, params, rng=np.random.default_rng(4))
    w = smooth.omega_body_radps[:-1]
    # 4000 s hold ~4000 / (4 tau) = 2000 independent stretches: the variance within ~3 % (1 sigma)
    np.testing.assert_allclose(np.std(w, axis=0), std, rtol=0.1)
    k = int(round(tau / 0.01))
    acf = np.mean(w[:-k] * w[k:], axis=0) / np.var(w, axis=0)
    np.testing.assert_allclose(acf, 2.0 / np.e, atol=0.05)  # (1 + 1) exp(-1) at one tau
    # an Ornstein-Uhlenbeck rate steps by std sqrt(2 dt / tau) per sample (0.3 rad/s here); the smooth
    # one by about std dt / tau (0.03 rad/s): a rotation the 10 Hz truth band can follow
    ou = simulate_attitude(t, z, z, AttitudeParams(kind="tumble", tumble_rate_std_radps=std, tumble_correlation_s=tau),
                           rng=np.random.default_rng(4)).omega_body_radps[:-1]
    assert np.std(np.diff(w, axis=0)) < 0.05 and np.std(np.diff(ou, axis=0)) > 0.25


def test_pendulum_settles_at_the_tilt_of_a_steady_acceleration():
    t = np.arange(0, 120.0, 0.01)
    a = 1.5
    vel = np.stack([1.0 + a * t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    acc = np.tile([a, 0.0, 0.0], (t.size, 1))
    att = simulate_attitude(t, vel, acc, AttitudeParams(kind="pendulum", pendulum_period_s=4.0,
                                                         pendulum_damping_ratio=0.2))
    # steady state: the hanger (body z) along the apparent vertical, tilted forward by atan(a/g) (small angle)
    z_b = att.rot[-1].apply([0.0, 0.0, 1.0])
    assert np.arctan2(z_b[0], z_b[2]) == pytest.approx(a / G0_MPS2, rel=1e-6)
    # the swing oscillates at the configured period (damped): first overshoot after half a damped period
    pitch = np.arctan2(att.rot.apply([0.0, 0.0, 1.0])[:, 0], att.rot.apply([0.0, 0.0, 1.0])[:, 2])
    t_peak = t[np.argmax(pitch[: int(10 / 0.01)])]
    wd = 2 * np.pi / 4.0 * np.sqrt(1 - 0.2**2)
    assert t_peak == pytest.approx(np.pi / wd, abs=0.02)


def test_zero_motion_imu_measures_gravity_only():
    t = np.arange(0, 60.0, 0.01)
    z = np.zeros((t.size, 3))
    rot = Rotation.from_quat(np.tile(Rotation.from_euler("xyz", [0.3, -0.5, 1.0]).as_quat(), (t.size, 1)))
    params = BodyImuParams.model_validate(NOISELESS)
    _, acc, gyro = simulate_body_imu(t, z, rot, z, params, rng=np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), G0_MPS2, rtol=1e-12)
    np.testing.assert_allclose(rot[0].apply(acc[0]), [0.0, 0.0, G0_MPS2], atol=1e-12)
    assert np.all(gyro == 0.0)
    level = Rotation.identity(t.size)
    _, acc, _ = simulate_body_imu(t, z, level, z, params, rng=np.random.default_rng(0))
    np.testing.assert_allclose(acc, np.tile([0.0, 0.0, G0_MPS2], (acc.shape[0], 1)), atol=1e-12)


def test_allan_deviation_of_static_gyro_has_the_configured_slopes_and_values():
    n_d, k_rw, rate = 2e-3, 2e-4, 20.0  # N [rad/s/sqrt(Hz)], K [rad/s/sqrt(s)]: crossover 3 N^2 / K^2 = 300 s
    t = np.arange(0, 40_000.0, 1 / rate)
    z = np.zeros((t.size, 3))
    params = BodyImuParams(rate_hz=rate, accelerometer={"noise_density_mps2_per_sqrt_hz": 0.0,
                                                        "bias_rw_mps2_per_sqrt_s": 0.0},
                           gyroscope={"noise_density_radps_per_sqrt_hz": n_d, "bias_rw_radps_per_sqrt_s": k_rw})
    _, _, gyro = simulate_body_imu(t, z, Rotation.identity(t.size), z, params, rng=np.random.default_rng(11))
    taus = np.array([0.5, 1.0, 2.0, 2000.0, 4000.0])
    adev = allan_deviation(gyro, rate, taus).mean(axis=0)  # mean over the 3 axes
    expected = np.sqrt(n_d**2 / taus + k_rw**2 * taus / 3.0)
    # relative standard error of an overlapping Allan deviation ~ 1 / sqrt(2 (T / tau - 1)) per axis;
    # the 3 axes average it down by sqrt(3); 4 standard errors (+ the 0.1 s bias knots at short tau)
    se = 1.0 / np.sqrt(2.0 * 3.0 * (t[-1] / taus - 1.0))
    assert np.all(np.abs(adev / expected - 1.0) < 4 * se + 0.01), (adev / expected - 1.0, se)
    slope_white = np.polyfit(np.log(taus[:3]), np.log(adev[:3]), 1)[0]
    assert slope_white == pytest.approx(-0.5, abs=0.03)
    # well above the crossover the random walk dominates: slope +1/2 once the white part is removed
    rw_part = np.sqrt(adev[3:] ** 2 - n_d**2 / taus[3:])
    np.testing.assert_allclose(rw_part, k_rw * np.sqrt(taus[3:] / 3.0), rtol=4 * se[3:].max())


def test_imu_models_leave_their_inputs_unchanged():
    scn = load_scenario("cablecar-descending")
    t = np.arange(0, 30.0, 0.01)
    acc = np.stack([np.sin(t), np.cos(t), 0.1 * t], axis=0).T  # a transposed (F-ordered) view, as kinematics gives
    vel = np.cumsum(acc, axis=0) * 0.01 + 1.0
    kin = Kinematics(t_s=t, s_m=np.zeros_like(t), pos_enu_m=np.zeros_like(acc), vel_enu_mps=vel, acc_enu_mps2=acc)
    before = {k: getattr(kin, k).copy() for k in ("t_s", "acc_enu_mps2", "vel_enu_mps")}
    simulate_imu(kin, ImuParams(**scn.imu.model_dump()), rng=np.random.default_rng(0))
    att = simulate_attitude(t, vel, acc, AttitudeParams(kind="pendulum"))
    w0 = att.omega_body_radps.copy()
    simulate_body_imu(t, acc, att.rot, att.omega_body_radps,
                      BodyImuParams(time_offset_s=0.003, gyroscope={"g_sensitivity_radps_per_mps2": 1e-3}),
                      rng=np.random.default_rng(0))
    for k, v in before.items():
        np.testing.assert_array_equal(getattr(kin, k), v)
    np.testing.assert_array_equal(att.omega_body_radps, w0)


def test_device_errors_scale_misalignment_and_turn_on_bias():
    """Per-trace device draws: the static mean of the accelerometer is M f + b0 with the drawn M, b0."""
    t = np.arange(0, 10.0, 0.01)
    z = np.zeros((t.size, 3))
    params = BodyImuParams.model_validate({
        "accelerometer": {"noise_density_mps2_per_sqrt_hz": 0.0, "bias_rw_mps2_per_sqrt_s": 0.0,
                          "scale_factor_std": 0.01, "misalignment_std_rad": 0.002, "turn_on_bias_std_mps2": 0.05},
        "gyroscope": {"noise_density_radps_per_sqrt_hz": 0.0, "bias_rw_radps_per_sqrt_s": 0.0,
                      "turn_on_bias_std_radps": 0.01}})
    from physynth.models.imu import draw_imu_device
    dev = draw_imu_device(params, rng=np.random.default_rng(5))
    _, acc, gyro = simulate_body_imu(t, z, Rotation.identity(t.size), z, params, rng=np.random.default_rng(5))
    np.testing.assert_allclose(acc[0], dev.acc_matrix @ [0, 0, G0_MPS2] + dev.acc_turn_on_bias_mps2, atol=1e-12)
    np.testing.assert_allclose(gyro[0], dev.gyro_turn_on_bias_radps, atol=1e-15)
    assert np.abs(dev.acc_matrix - np.eye(3)).max() > 0
    # quantisation: every sample a multiple of the step
    q = BodyImuParams.model_validate({"accelerometer": {"quantisation_mps2": 0.01}})
    _, acc, _ = simulate_body_imu(t, z, Rotation.identity(t.size), z, q, rng=np.random.default_rng(1))
    np.testing.assert_allclose(acc / 0.01, np.round(acc / 0.01), atol=1e-9)


def test_time_offset_delays_the_measured_motion():
    t = np.arange(0, 10.0, 0.01)
    acc = np.stack([np.sin(2 * np.pi * 1.0 * t), np.zeros_like(t), np.zeros_like(t)], axis=1)
    params = BodyImuParams.model_validate({**NOISELESS, "time_offset_s": 0.02})
    t_imu, f, _ = simulate_body_imu(t, acc, Rotation.identity(t.size), np.zeros_like(acc), params,
                                    rng=np.random.default_rng(0))
    inner = t_imu > 0.1
    np.testing.assert_allclose(f[inner, 0], np.sin(2 * np.pi * (t_imu[inner] - 0.02)), atol=2e-3)


def test_kalibr_keys_are_read_and_written():
    from physynth.models.imu import body_imu_to_kalibr
    k = {"accelerometer_noise_density": 0.0028, "accelerometer_random_walk": 0.00086,
         "gyroscope_noise_density": 0.00016, "gyroscope_random_walk": 2.2e-5, "rostopic": "/imu0",
         "update_rate": 200.0}
    p = BodyImuParams.model_validate(k)
    assert p.rate_hz == 200.0 and p.accelerometer.noise_density_mps2_per_sqrt_hz == 0.0028
    assert p.gyroscope.bias_rw_radps_per_sqrt_s == 2.2e-5
    assert body_imu_to_kalibr(p) == k


def test_kalibr_file_round_trip_and_bad_file(tmp_path):
    from physynth.errors import ScenarioError
    from physynth.io.kalibr import read_kalibr_imu, write_kalibr_imu

    p = BodyImuParams.model_validate({"accelerometer_noise_density": 0.002, "gyroscope_random_walk": 3e-5,
                                      "update_rate": 250.0})
    write_kalibr_imu(p, tmp_path / "imu.yaml")
    back = read_kalibr_imu(tmp_path / "imu.yaml")
    assert back == p
    (tmp_path / "bad.yaml").write_text("update_rate: -5\naccelerometer_noise_density: 0.1\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="rate_hz"):
        read_kalibr_imu(tmp_path / "bad.yaml")


def test_imu_only_scenario_needs_an_explicit_empty_anchor_list():
    from helpers import simple_scenario_dict

    from physynth.errors import ScenarioError

    d = simple_scenario_dict()
    del d["anchors"]
    with pytest.raises(ScenarioError, match="anchors: Field required"):
        scenario_from_dict(d, "test")  # a forgotten anchors section is still an error
    d["anchors"], d["channel_per_anchor"] = [], {}
    tr = generate_trace(compile_scenario(scenario_from_dict(d, "test")), 0, 1)
    assert len(tr.uwb) == 0 and len(tr.anchors) == 0 and tr.imu is not None


def test_unwrap_matches_numpy_bit_for_bit():
    from physynth.models.attitude import unwrap

    rng = np.random.default_rng(3)
    cases = [np.arctan2(rng.standard_normal(500), rng.standard_normal(500)),
             np.cumsum(rng.standard_normal(2000)) % (2 * np.pi) - np.pi, np.linspace(-3.0, 3.0, 1000),
             np.array([0.0, np.pi, 0.0, -np.pi, 0.0, 2 * np.pi, 1.0, 4.0]), np.array([3.0, -3.0, 3.0]),
             np.array([-0.0, 0.0]), np.array([1.0]), np.zeros(0)]
    for c in cases:
        want, got = np.unwrap(c), unwrap(c)
        assert np.array_equal(want, got) and np.array_equal(np.signbit(want), np.signbit(got))


def test_speed_threshold_matches_hypot_bit_for_bit():
    from physynth.models.attitude import at_least

    rng = np.random.default_rng(5)
    for limit in (0.05, 1.0, 3.7e-7, 1e-120, 1e120):
        ang = rng.uniform(0.0, 2.0 * np.pi, 4000)
        # speeds at the limit to within a few ulps, far from it, and of every magnitude
        r = np.concatenate([limit * (1.0 + rng.integers(-8, 9, 2000) * 2.0**-52),
                            limit * 10.0 ** rng.uniform(-3.0, 3.0, 1000), 10.0 ** rng.uniform(-320, 300, 1000)])
        x, y = r * np.cos(ang), r * np.sin(ang)
        x[:5] = [np.nan, np.inf, -np.inf, 0.0, -0.0]
        y[:5] = [1.0, np.nan, 2.0, -0.0, limit]
        want = np.hypot(x, y) >= limit
        assert np.array_equal(at_least(x, y, limit), want)
        assert np.array_equal(at_least(np.array(y), np.array(x), limit), np.hypot(y, x) >= limit)


def test_gyro_vibration_grows_with_the_acceleration_per_body_axis():
    # a level, non-rotating unit at rest for 300 s, then accelerating at 4 m/s^2 for 300 s: the gyro
    # reads only its vibration, variance gain_k x |a| on body axis k (0 at rest)
    t = np.arange(0, 600.0, 0.01)
    acc = np.zeros((t.size, 3))
    acc[t >= 300.0, 0] = 4.0
    gain = [2e-3, 5e-4, 0.0]
    params = BodyImuParams.model_validate({**NOISELESS, "gyroscope": {
        **NOISELESS["gyroscope"], "vibration_acc_var_gain_rad2_per_m": gain}})
    _, _, gyro = simulate_body_imu(t, acc, Rotation.identity(t.size), np.zeros((t.size, 3)), params,
                                   rng=np.random.default_rng(3))
    t_imu = np.arange(gyro.shape[0]) / params.rate_hz
    rest, moving = gyro[t_imu < 299.0], gyro[t_imu > 301.0]
    assert np.all(rest == 0.0)
    # the comb's lines are 0.3 Hz wide: 300 s hold ~300 independent envelope values per line, so the
    # variance is within ~6 % (1 sigma); 25 % is 4 sigma
    np.testing.assert_allclose(np.mean(moving[:, :2] ** 2, axis=0), 4.0 * np.array(gain[:2]), rtol=0.25)
    assert np.all(moving[:, 2] == 0.0)
    # without the gain the gyroscope is silent while moving too
    _, _, quiet = simulate_body_imu(t, acc, Rotation.identity(t.size), np.zeros((t.size, 3)),
                                    BodyImuParams.model_validate(NOISELESS), rng=np.random.default_rng(3))
    assert np.all(quiet == 0.0)


@pytest.mark.parametrize("kind", ["heading", "general"])
def test_body_specific_force_is_scipys_apply_bit_for_bit(kind):
    """The body-frame force from quaternions (or rotations) is Rotation.apply(inverse=True)'s, to the bit
    (signed zeros included), for turns about the vertical (own formulas) and any rotation (matrices)."""
    from physynth.models.imu import ideal_body_imu

    rng = np.random.default_rng(11)
    n = 20000
    if kind == "heading":
        yaw = rng.uniform(-40.0, 40.0, n)
        yaw[::5] = np.round(yaw[::5] / (np.pi / 2)) * (np.pi / 2)  # quarter turns: zero matrix entries
        q = np.zeros((n, 4))
        q[:, 0], q[:, 3] = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    else:
        q = rng.standard_normal((n, 4))
    acc = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-6, 6, (n, 1))
    acc[::7, :2] = 0.0
    acc[::11, :2] = -0.0
    acc[::13, 2] = -G0_MPS2  # free fall: zero specific force
    f_w = acc + np.array([0.0, 0.0, G0_MPS2])
    rot = Rotation.from_quat(q, scalar_first=True)
    want = rot.apply(f_w, inverse=True)
    for r in (q, rot):
        got, _ = ideal_body_imu(np.arange(n) * 0.01, acc, r, np.zeros((n, 3)))
        assert np.ascontiguousarray(got).tobytes() == want.tobytes()
    with pytest.raises(ValueError):
        ideal_body_imu(np.arange(n) * 0.01, acc, np.zeros((n, 4)), np.zeros((n, 3)))  # zero quaternions


def test_the_tumble_attitude_is_the_running_product_of_its_steps():
    from scipy.spatial.transform import Rotation

    from physynth.models.attitude import cumulative_compose

    rng = np.random.default_rng(7)
    first = Rotation.random(random_state=8)
    steps = Rotation.from_rotvec(rng.normal(0.0, 0.05, (777, 3)))  # not a power of two
    got = cumulative_compose(first, steps)
    expected, cur = [first.as_matrix()], first
    for k in range(len(steps)):  # the definition, one composition at a time (777 steps, test only)
        cur = cur * steps[k]
        expected.append(cur.as_matrix())
    assert len(got) == len(steps) + 1
    np.testing.assert_allclose(got.as_matrix(), np.array(expected), atol=1e-12)


def test_a_walker_turns_about_at_a_bounded_rate_not_in_one_step():
    from physynth.generate import generate_traces
    from physynth.io.scenario_file import load_scenario
    from physynth.models.attitude import limit_turn_rate

    scn = load_scenario("walk-hanyang")
    cap = scn.attitude.max_turn_rate_radps
    for t in generate_traces(scn, 3, seed=4):  # each turned about at ~0.1 m/s in one step (-300 rad/s)
        assert np.abs(t.truth.omega_body_radps).max() <= cap * (1 + 1e-9)
    tt = np.arange(0.0, 10.0, 0.01)
    yaw = np.where(tt < 3.0, 0.0, np.pi) + 0.2 * np.sin(tt)  # a turn about in one step, then a slow sway
    out = limit_turn_rate(yaw, tt, 3.0)
    assert np.abs(np.diff(out)).max() <= 3.0 * 0.01 * (1 + 1e-9)
    np.testing.assert_allclose(out[tt > 5.0], yaw[tt > 5.0], atol=1e-12)  # caught up after ~1 s
    assert out[np.searchsorted(tt, 3.5)] < 2.0  # still turning half a second in
    smooth = np.sin(tt)  # never faster than the cap: returned as it was
    assert limit_turn_rate(smooth, tt, 3.0) is smooth
