"""Run-to-run tilts of the range law: measured per (run, anchor), drawn per synthetic trace.

The received-power bias of the real walks grows by 13-15 cm per decade of range in one Hanyang run and
by 20-26 cm in the three others, every anchor of a run alike. Calibration measures each run's slope per
anchor (:func:`physynth.calibrate.run_spread.cell_slope`, its sampling error by a jackknife over
blocks in time), splits the run-to-run part off by REML and generation draws one tilt per trace.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import lfilter

from physynth.calibrate import calibrate
from physynth.calibrate.run_spread import MIN_DECADE_SPAN, cell_slope
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.models.motion import draw_run, kinematics
from physynth.models.path import draw_perturbation
from physynth.models.uwb import range_decades, simulate_uwb
from physynth.rng import component_rng


def _ar1_rows(rng: np.random.Generator, n: int, phi: float, sd: float) -> np.ndarray:
    """Stationary AR(1) noise of standard deviation ``sd`` (a burn-in of 20 correlation times dropped)."""
    burn = int(20 / (1.0 - phi))
    return lfilter([sd * np.sqrt(1.0 - phi**2)], [1.0, -phi], rng.standard_normal(n + burn))[burn:]


def test_cell_slope_and_its_sampling_error():
    # 60 cells of 1,500 rows: log10 range sweeping 0.7-1.7 back and forth (a walk out and back), slope
    # 0.2 m per decade, AR(1) noise (phi 0.98: errors correlated over ~50 rows, as the real sway is).
    # The mean slope within 3 standard errors of the truth; the jackknife variance, averaged, within
    # 3 relative standard errors of the slopes' own scatter (sqrt(2 / 59) for a variance of 60 values).
    rng = np.random.default_rng(7)
    n, k, slope = 1500, 60, 0.2
    dec = 1.2 + 0.5 * np.sin(np.linspace(0.0, 3.0 * np.pi, n))
    got = np.array([cell_slope(slope * dec + _ar1_rows(rng, n, 0.98, 0.05), dec) for _ in range(k)])
    est, var = got[:, 0], got[:, 1]
    assert np.allclose(got[:, 2], dec.mean())
    assert est.mean() == pytest.approx(slope, abs=3.0 * est.std(ddof=1) / np.sqrt(k))
    rel = 3.0 * np.sqrt(2.0 / (k - 1))
    assert var.mean() / est.var(ddof=1) == pytest.approx(1.0, abs=rel)


def test_cell_slope_needs_a_span_of_ranges():
    dec = np.full(400, 1.3) + np.linspace(0.0, 0.9 * MIN_DECADE_SPAN, 400)
    assert cell_slope(np.zeros(400), dec) is None
    assert cell_slope(np.zeros(60), np.linspace(0.5, 1.5, 60)) is None  # too few rows for blocks


def _attempts(scn, index: int):
    """The UWB attempts of trace ``index`` (root seed 1) before availability, as generation draws them."""
    cs = compile_scenario(scn)
    pert = draw_perturbation(scn.path.perturbation, rng=component_rng(1, index, "path"))
    run = draw_run(scn.motion, rng=component_rng(1, index, "motion"))
    kin = kinematics(cs.geometry, pert, scn.motion, cs.shape, run, rate_hz=scn.truth_rate_hz,
                     reverse=scn.path.reverse, lateral_dir=cs.lateral_dir)
    return simulate_uwb(kin, scn.uwb, cs.channel, rng=component_rng(1, index, "uwb"))


def test_one_tilt_per_trace_and_nothing_else_moves():
    base = load_scenario("cablecar-descending")
    tilted = base.model_copy(update={"uwb": base.uwb.model_copy(update={"run_slope_std_m": 0.1,
                                                                        "run_slope_ref_range_m": 30.0})})
    tilts = []
    for i in range(2):
        a, b = _attempts(base, i), _attempts(tilted, i)
        assert np.array_equal(a.true_range_m, b.true_range_m) and np.array_equal(a.nlos, b.nlos)
        lever = range_decades(a.true_range_m) - np.log10(30.0)
        use = np.abs(lever) > 0.05
        ratio = (b.measured_m - a.measured_m)[use] / lever[use]
        assert np.ptp(ratio) < 1e-6  # one tilt for every row of the trace
        tilts.append(ratio[0])
    assert abs(tilts[0] - tilts[1]) > 1e-3  # drawn anew for each trace


def test_calibration_recovers_the_tilt_spread():
    # 12 traces of the descending cable car, each tilted by its own draw of N(0, 0.5^2) m per decade (its
    # anchors see a fraction of a decade of range each, through slow errors: a cell's slope is known to
    # about 0.3 m per decade, so a smaller spread would not be told from 0 by 12 runs). The fitted spread
    # within 3 standard errors of a standard deviation from 12 runs seen through the cells' sampling
    # error: sqrt(2 / 11) x (s^2 + mean sampling variance / anchors) / (2 s).
    s_true, n = 0.5, 12
    preset = load_scenario("cablecar-descending")
    scn = preset.model_copy(update={"uwb": preset.uwb.model_copy(update={"run_slope_std_m": s_true})})
    cs = compile_scenario(scn)
    # without their IMU samples: the UWB fit does not use them (the same scenario.uwb and report section to
    # the last digit, checked), and the IMU calibration would double the test's time
    traces = [replace(generate_trace(cs, i, 21), imu=None) for i in range(n)]
    res = calibrate(traces, name="tilted", run_slopes=True)
    sec = res.report["run_slopes"]
    assert sec["identifiable"] and sec["significant"] and sec["applied"]
    v = np.mean(list(sec["sampling_var_per_cell"].values()))
    se = np.sqrt(2.0 / (n - 1)) * (s_true**2 + v / sec["n_anchors"]) / (2.0 * s_true)
    assert res.scenario.uwb.run_slope_std_m == pytest.approx(s_true, abs=3.0 * se)
    # the pivot is the LOS rows' mean log range: within 0.1 decade of the mean log range of all valid rows
    # (the NLOS rows left out move it by less), not the default 10 m
    decades = np.concatenate([np.log10(np.linalg.norm(
        t.truth.position_at(t.uwb.t_s[t.uwb.valid]) - t.anchors.pos_enu_m[t.uwb.anchor[t.uwb.valid]], axis=1))
        for t in traces])
    assert np.log10(res.scenario.uwb.run_slope_ref_range_m) == pytest.approx(decades.mean(), abs=0.1)
    # without the option the spread is fitted and reported, not generated
    plain = calibrate(traces, name="plain")
    assert plain.report["run_slopes"]["significant"] and not plain.report["run_slopes"]["applied"]
    assert plain.scenario.uwb.run_slope_std_m == 0.0
    assert plain.report["parameters"]["uwb.run_slope_std_m"]["value"] == 0.0  # the report says what is generated
    assert res.report["parameters"]["uwb.run_slope_std_m"]["value"] == res.scenario.uwb.run_slope_std_m  # as written
    assert res.scenario.uwb.run_slope_std_m == pytest.approx(sec["run_slope_std_m"], rel=1e-3)
