"""The burst clock's phase (``uwb.burst_phase_s``) when calibrating several runs: kept when the runs
share it (traces generated from a scenario with a phase), dropped when they differ (real runs start at
random phases; :func:`physynth.calibrate.uwb_fit.shared_burst_phase`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from physynth.calibrate import calibrate, fit_burst_schedule
from physynth.calibrate.uwb_fit import BURST_PHASE_AGREE_MIN_S, BURST_PHASE_AGREE_SE, shared_burst_phase
from physynth.generate import generate_traces
from physynth.io.scenario_file import load_scenario
from physynth.scenario import scenario_from_dict, scenario_to_dict

PHASE_S = 0.0421


def _scenario(phase_s: float | None, lag_std_s: float = 0.0):
    d = scenario_to_dict(load_scenario("walk-hanyang"))  # 10 Hz bursts, 0.19 ms jitter
    d["uwb"].update(burst_phase_s=phase_s, time_offset_std_s=lag_std_s)
    return scenario_from_dict(d, "phase")


def test_a_shared_phase_is_kept_and_differing_phases_are_dropped():
    # without their IMU samples: the UWB fit does not use them (the same scenario but for its imu section,
    # to the last digit, checked), and the IMU calibration would add a third to the test's time
    traces = [replace(t, imu=None) for t in generate_traces(_scenario(PHASE_S), 2, seed=2)]
    res = calibrate(traces)
    jitter = res.scenario.uwb.burst_jitter_s
    assert res.scenario.uwb.burst_phase_s == pytest.approx(PHASE_S, abs=jitter)  # was None with two runs
    # phases drawn per trace, or one phase with a lag per trace (the stamps' phase moves with the lag)
    for scn in (_scenario(None), _scenario(PHASE_S, 0.03)):
        fit = fit_burst_schedule(list(generate_traces(scn, 3, seed=2)))
        assert fit.params["burst_phase_s"] is None, fit.diagnostics["burst_phase_per_run_s"]


def test_the_rule_on_known_phases():
    period = 0.1
    # the four shared Hanyang runs
    assert shared_burst_phase([0.0147, 0.058, 0.020, 0.071], [2300] * 4, period, 1.9e-4)["phase_s"] is None
    got = shared_burst_phase([0.09996, 0.00002], [2000, 2000], period, 1.9e-4)["phase_s"]  # across the wrap
    assert min(got, period - got) < 2e-5
    # the limit: BURST_PHASE_AGREE_SE standard errors (2 jitter / sqrt(bursts)) from the circular mean ...
    jitter, n = 3e-3, 2500
    limit = BURST_PHASE_AGREE_SE * 2.0 * jitter / np.sqrt(n)
    assert limit > BURST_PHASE_AGREE_MIN_S
    for frac, kept in ((0.9, True), (1.1, False)):  # two runs: each lies half their difference from the mean
        got = shared_burst_phase([0.05, 0.05 + 2 * frac * limit], [n, n], period, jitter)["phase_s"]
        assert (got is not None) == kept
    # ... at least BURST_PHASE_AGREE_MIN_S (bursts without jitter)
    for frac, kept in ((0.9, True), (1.1, False)):
        got = shared_burst_phase([0.05, 0.05 + 2 * frac * BURST_PHASE_AGREE_MIN_S], [n, n], period, 0.0)["phase_s"]
        assert (got is not None) == kept
    assert shared_burst_phase([0.0147], [10], period, 1e-3)["phase_s"] == 0.0147  # one run keeps its own


def test_a_jittery_clock_is_numbered_burst_by_burst():
    """At the cable-car presets' 23 Hz and 3 ms jitter, bursts numbered from the first one by the median
    period were misnumbered over a run's ~2,500 bursts (rates off by up to 0.3 %, so the runs' shared
    phase was dropped too). Numbered from the burst before, each run's rate comes out within 1e-5 of the
    clock's (the line's slope over ~2,500 bursts is good to ~1e-6) and the shared phase is kept."""
    d = scenario_to_dict(load_scenario("cablecar-descending"))
    d["uwb"].update(burst_phase_s=0.0123)
    traces = list(generate_traces(scenario_from_dict(d, "jittery"), 3, seed=4))
    fit = fit_burst_schedule(traces)
    assert d["uwb"]["burst_jitter_s"] == 0.003 and d["uwb"]["burst_rate_hz"] == 23.0
    for run in fit.diagnostics["per_run"].values():
        assert run["burst_rate_hz"] == pytest.approx(23.0, rel=1e-5)
    assert fit.params["burst_phase_s"] == pytest.approx(0.0123, abs=0.003)
