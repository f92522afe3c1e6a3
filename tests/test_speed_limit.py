"""The mover's acceleration limit (``motion.max_acc_mps2``): slowing at tight bends and reversals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physynth.calibrate.geometry import (
    MAX_ACC_FACTOR,
    MAX_ACC_QUANTILE,
    fit_motion,
    summarize_track,
    trip_acceleration_quantile,
)
from physynth.models.motion import (
    MotionParams,
    RunDraw,
    SpeedProfileParams,
    compile_speed_shape,
    curvature,
    kinematics,
)
from physynth.models.path import PathParams, PathPerturbation, compile_path

# out 20 m east, a hairpin of about 0.2 m radius, back: a walker's turn-around
HAIRPIN = PathParams(kind="waypoints", waypoints_enu_m=[[0, 0, 1], [10, 0, 1], [20, 0, 1], [20.2, 0.2, 1],
                                                       [20, 0.4, 1], [10, 0.4, 1], [0, 0.4, 1]],
                     perturbation={"lateral_std_m": 0.0, "sag_std_m": 0.0})
NO_PERT = PathPerturbation(lateral_m=0.0, sag_m=0.0)
RUN = RunDraw(speed_factor=1.0, length_factor=1.0)
RATE_HZ = 100.0


def _kin(max_acc: float | None):
    motion = MotionParams(cruise_speed_mps=1.5, profile=SpeedProfileParams(kind="trapezoid"), dwell_start_s=2.0,
                          dwell_end_s=2.0, max_acc_mps2=max_acc)
    geo = compile_path(HAIRPIN)
    return geo, kinematics(geo, NO_PERT, motion, compile_speed_shape(motion.profile), RUN, rate_hz=RATE_HZ)


def test_a_hairpin_is_taken_slowly_within_the_limit():
    _, free = _kin(None)
    geo, lim = _kin(2.0)
    a_free = np.linalg.norm(free.acc_enu_mps2, axis=1).max()
    a_lim = np.linalg.norm(lim.acc_enu_mps2, axis=1)
    assert a_free > 10.0  # without a limit the hairpin at walking speed needs more than 1 g
    # sideways and along the path each at most the limit: |a| <= sqrt(2) x 2 m/s^2 (plus the slack of
    # one grid step of the numerical along-track derivative)
    assert a_lim.max() < np.sqrt(2.0) * 2.0 * 1.1
    # the velocity's own derivative agrees: no step the analytic acceleration hides
    a_num = np.linalg.norm(np.gradient(lim.vel_enu_mps, lim.t_s, axis=0), axis=1)
    assert np.quantile(a_num, 0.999) < np.sqrt(2.0) * 2.0 * 1.2
    # the whole path is still travelled, station to station, on a uniform grid, and it takes longer
    assert lim.s_m[0] == 0.0 and lim.s_m[-1] == pytest.approx(geo.length_m, abs=1e-6)
    assert np.all(np.diff(lim.s_m) >= -1e-12)
    assert np.allclose(np.diff(lim.t_s), 1.0 / RATE_HZ)
    assert lim.t_s[-1] > free.t_s[-1]
    # the speed at the apex is the bend's limit sqrt(a / kappa)
    _, d1, d2 = geo.evaluate_cf(lim.s_m)
    kappa = curvature(d1, d2)
    apex = np.argmax(kappa)
    v = np.linalg.norm(lim.vel_enu_mps, axis=1)
    assert v[apex] <= np.sqrt(2.0 / kappa[apex]) * 1.05


def test_a_limit_that_never_binds_changes_nothing():
    _, free = _kin(None)
    _, loose = _kin(1000.0)
    for name in ("t_s", "s_m", "pos_enu_m", "vel_enu_mps", "acc_enu_mps2"):
        assert np.array_equal(getattr(free, name), getattr(loose, name)), name


HANYANG_RUN = (Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"
               / "LOS" / "Trajectory_A" / "Case_1")


@pytest.mark.skipif(not HANYANG_RUN.is_dir(), reason="shared Hanyang run not found")
def test_the_limit_is_fitted_as_a_high_quantile_of_the_real_acceleration():
    from physynth.io.importers import import_hanyang

    trace, _ = import_hanyang(HANYANG_RUN, crop_to_uwb=True)
    fit = fit_motion(trace)
    track = summarize_track(trace, "los1")
    a = np.linalg.norm(np.gradient(np.gradient(track.pos_m, track.t_s, axis=0), track.t_s, axis=0), axis=1)
    trip = a[track.i_start:track.i_end + 1]
    assert fit.params.max_acc_mps2 == pytest.approx(MAX_ACC_FACTOR * np.quantile(trip, MAX_ACC_QUANTILE), rel=1e-3)
    assert trip_acceleration_quantile([track], 0.5) < fit.params.max_acc_mps2
    assert 2.0 < fit.params.max_acc_mps2 < 20.0  # a walk: twice a few m/s^2
