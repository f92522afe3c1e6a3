"""Every model passes physynth.testing.check_model: shapes, physical ranges, finite outputs,
determinism per seed, inputs left unchanged; the generator is batch- and order-independent."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import simple_scenario

from physynth.generate import compile_scenario, generate_trace, generate_traces
from physynth.io.scenario_file import load_scenario
from physynth.models.availability import simulate_availability
from physynth.models.imu import simulate_imu
from physynth.models.motion import RunDraw, draw_run, kinematics
from physynth.models.path import PathPerturbation, draw_perturbation
from physynth.models.uwb import simulate_uwb
from physynth.testing import ModelCase, check_model
from physynth.testing.check_model import check_generator


@pytest.fixture(scope="module")
def compiled():
    return compile_scenario(load_scenario("cablecar-descending"))


@pytest.fixture(scope="module")
def kin(compiled):
    s = compiled.scenario
    return kinematics(compiled.geometry, PathPerturbation(lateral_m=1.0, sag_m=-0.5), s.motion, compiled.shape,
                      RunDraw(speed_factor=1.0, length_factor=1.0), rate_hz=s.truth_rate_hz,
                      lateral_dir=compiled.lateral_dir)


def test_path_perturbation(compiled):
    p = compiled.scenario.path.perturbation
    check_model(ModelCase(name="path.draw_perturbation", run=lambda rng: draw_perturbation(p, rng=rng), inputs=[p],
                          bounds={"lateral_m": (-10 * p.lateral_std_m, 10 * p.lateral_std_m),
                                  "sag_m": (-10 * p.sag_std_m, 10 * p.sag_std_m)}))


def test_motion_draw(compiled):
    m = compiled.scenario.motion
    check_model(ModelCase(name="motion.draw_run", run=lambda rng: draw_run(m, rng=rng), inputs=[m],
                          bounds={"speed_factor": (1 - m.cruise_speed_spread_frac, 1 + m.cruise_speed_spread_frac),
                                  "length_factor": (1 - m.length_spread_frac, 1 + m.length_spread_frac)}))


def test_kinematics(compiled):
    s = compiled.scenario

    def run(rng):
        return kinematics(compiled.geometry, draw_perturbation(s.path.perturbation, rng=rng), s.motion,
                          compiled.shape, draw_run(s.motion, rng=rng), rate_hz=s.truth_rate_hz,
                          lateral_dir=compiled.lateral_dir)

    check_model(ModelCase(name="motion.kinematics", run=run, inputs=[compiled.geometry, compiled.shape, s.motion],
                          shapes={"t_s": (None,), "s_m": (None,), "pos_enu_m": (None, 3), "vel_enu_mps": (None, 3),
                                  "acc_enu_mps2": (None, 3)},
                          bounds={"t_s": (0.0, 1e4), "s_m": (0.0, compiled.geometry.length_m),
                                  "vel_enu_mps": (-20.0, 20.0), "acc_enu_mps2": (-10.0, 10.0)}))


def test_jitter(kin):
    from physynth.models.jitter import JitterParams, add_jitter

    p = JitterParams(acc_rms_mps2=[[0.1, 0.2, 0.1], [0.3, 0.3, 0.2], [0.5, 0.4, 0.3], [0.2, 0.2, 0.2], [0.1, 0.1, 0.1]],
                     intensity_log_std=0.3)
    n = kin.t_s.shape[0]
    check_model(ModelCase(name="jitter.add_jitter", run=lambda rng: add_jitter(kin, p, rng=rng), inputs=[kin, p],
                          shapes={"t_s": (n,), "s_m": (n,), "pos_enu_m": (n, 3), "vel_enu_mps": (n, 3),
                                  "acc_enu_mps2": (n, 3)},
                          bounds={"vel_enu_mps": (-20.0, 20.0), "acc_enu_mps2": (-20.0, 20.0)}))


def test_imu(compiled, kin):
    p = compiled.scenario.imu
    check_model(ModelCase(name="imu.simulate_imu", run=lambda rng: simulate_imu(kin, p, rng=rng), inputs=[kin, p],
                          shapes={"t_s": (None,), "acc_mps2": (None, 3)},
                          bounds={"t_s": (0.0, float(kin.t_s[-1])), "acc_mps2": (-200.0, 200.0)}))


def test_uwb(compiled, kin):
    s = compiled.scenario
    ch = compiled.channel
    n = len(s.anchors)
    check_model(ModelCase(name="uwb.simulate_uwb", run=lambda rng: simulate_uwb(kin, s.uwb, ch, rng=rng),
                          inputs=[kin, s.uwb, ch],
                          shapes={"burst": (None,), "anchor": (None,), "t_true_s": (None,),
                                  "true_range_m": (None,), "measured_m": (None,)},
                          bounds={"anchor": (0, n - 1), "true_range_m": (0.0, 5e3), "measured_m": (0.0, 5e3),
                                  "t_true_s": (0.0, float(kin.t_s[-1]))}))


def test_availability(compiled, kin):
    s = compiled.scenario
    att = simulate_uwb(kin, s.uwb, compiled.channel, rng=np.random.default_rng(3))

    def run(rng):
        return simulate_availability(att.t_true_s, att.anchor, att.burst, att.bursts_s, compiled.availability,
                                     s.uwb.burst_rate_hz, rng=rng)

    check_model(ModelCase(name="availability.simulate_availability", run=run,
                          inputs=[att, compiled.availability], shapes={"0": (att.t_true_s.size,),
                                                                       "1": (att.t_true_s.size,)}))


def test_check_model_catches_a_model_that_writes_into_its_input(kin):
    def bad(rng):
        kin.acc_enu_mps2[0, 0] += rng.standard_normal()
        return {"x": kin.acc_enu_mps2[:5].copy()}

    with pytest.raises(AssertionError, match="changed its input"):
        check_model(ModelCase(name="bad", run=bad, inputs=[kin]))


def test_check_model_catches_nan_and_ignored_seed():
    with pytest.raises(AssertionError, match="non-finite.*identical outputs"):
        check_model(ModelCase(name="nan", run=lambda rng: {"x": np.array([1.0, np.nan])}))


def test_generator_is_batch_and_order_independent():
    cs = compile_scenario(simple_scenario(**{"channel.los_std_m": 0.1, "availability.dropout_prob": 0.1}))
    check_generator(lambda i: generate_trace(cs, i, 99), lambda start, n: list(generate_traces(cs, n, 99, start)))
    with pytest.raises(AssertionError, match="differs"):  # the check can fail: a different root seed
        check_generator(lambda i: generate_trace(cs, i, 99), lambda start, n: list(generate_traces(cs, n, 98, start)))
