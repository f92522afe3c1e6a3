"""The motion model: the speed shape, the trip it makes, and kinematics consistent with each other."""

from __future__ import annotations

import numpy as np
import pytest

from physynth.models.motion import (
    MotionParams,
    RunDraw,
    SpeedProfileParams,
    compile_speed_shape,
    draw_run,
    kinematics,
    trip_duration_s,
)
from physynth.models.path import PathParams, PathPerturbation, compile_path

GEO = compile_path(PathParams(kind="waypoints", waypoints_enu_m=[[0, 0, 0], [300, 0, 30]]))
FLAT = PathPerturbation(lateral_m=0.0, sag_m=0.0)


@pytest.mark.parametrize("profile", [
    SpeedProfileParams(kind="trapezoid", accel_frac=0.2, decel_frac=0.1),
    SpeedProfileParams(kind="polynomial", coeffs=[0.0, 4.0, -4.0]),
    SpeedProfileParams(kind="empirical", samples=[0.0, 0.5, 1.0, 1.0, 0.8, 1.0, 0.4, 0.0]),
])
def test_kinematics_travel_the_path_at_the_cruise_speed_and_are_self_consistent(profile):
    params = MotionParams(cruise_speed_mps=5.0, profile=profile, dwell_start_s=2.0, dwell_end_s=3.0)
    kin = kinematics(GEO, FLAT, params, compile_speed_shape(profile), RunDraw(speed_factor=1.0, length_factor=1.0),
                     rate_hz=100.0)
    speed = np.linalg.norm(kin.vel_enu_mps, axis=1)
    assert speed.max() == pytest.approx(5.0, rel=0.02)  # max g = 1: the peak speed is the cruise speed
    assert kin.s_m[-1] == pytest.approx(GEO.length_m, abs=1e-6) and kin.s_m[0] == 0.0
    assert np.all(speed[kin.t_s < 2.0] == 0.0) and np.all(speed[kin.t_s > kin.t_s[-1] - 3.0 + 0.01] == 0.0)
    dt = 0.01
    np.testing.assert_allclose(np.gradient(kin.pos_enu_m, dt, axis=0)[200:-300], kin.vel_enu_mps[200:-300],
                               atol=0.02)
    np.testing.assert_allclose(np.gradient(kin.vel_enu_mps, dt, axis=0)[210:-310], kin.acc_enu_mps2[210:-310],
                               atol=0.05)


def test_trip_duration_follows_the_run_draw():
    params = MotionParams(cruise_speed_mps=5.0)
    shape = compile_speed_shape(params.profile)
    base = trip_duration_s(GEO.length_m, params, shape, RunDraw(speed_factor=1.0, length_factor=1.0))
    assert base == pytest.approx(GEO.length_m / (5.0 * shape.mean))
    faster = trip_duration_s(GEO.length_m, params, shape, RunDraw(speed_factor=1.1, length_factor=0.95))
    assert faster == pytest.approx(base * 0.95 / 1.1)


def test_run_draws_are_uniform_within_the_spread():
    params = MotionParams(cruise_speed_mps=5.0, cruise_speed_spread_frac=0.12, length_spread_frac=0.05)
    rng = np.random.default_rng(5)
    draws = [draw_run(params, rng=rng) for _ in range(4000)]
    v = np.array([d.speed_factor for d in draws])
    assert v.min() >= 0.88 and v.max() <= 1.12
    # uniform on [0.88, 1.12]: std = 0.24 / sqrt(12); 5 standard errors of a std estimate
    assert v.std() == pytest.approx(0.24 / np.sqrt(12), rel=5 / np.sqrt(2 * 4000))


def test_bad_profiles_are_refused():
    with pytest.raises(ValueError, match="must not exceed 1"):
        SpeedProfileParams(kind="trapezoid", accel_frac=0.6, decel_frac=0.6)
    with pytest.raises(ValueError, match="needs coeffs"):
        SpeedProfileParams(kind="polynomial")
