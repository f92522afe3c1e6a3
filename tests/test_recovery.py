"""Calibration recovers what generated the data (issue 12 item 6).

Generate traces of a cable-car preset, calibrate on them, generate again from the calibrated
scenario: every metric must land within the seed-to-seed spread of the preset itself. Measured
seed-to-seed spread at 8 traces of cablecar-descending (relative std over root seeds 11-14,
``python tools/recovery_check.py cablecar-descending -n 8``): UWB >= 1 3.1 %, UWB >= 2 7.2 %, residual std
2.9 %, median 1.8 %, |r| P95 0.7 %, mean AoI 6.2 %. Two independent ensembles differ by sqrt(2) times
that; the tolerance is 3 such standard deviations.
"""

from __future__ import annotations

import numpy as np
import pytest

from physynth.calibrate import calibrate
from physynth.evaluate.metrics import compute_metrics, relative_deviation_pct
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario

N = 8
SEED_SPREAD = {"uwb_ge1_frac": 0.031, "uwb_ge2_frac": 0.072, "residual_std_m": 0.029,
               "residual_median_m": 0.018, "abs_residual_p95_m": 0.007, "mean_aoi_s": 0.062}
TOL_PCT = {k: 100.0 * 3.0 * np.sqrt(2.0) * v for k, v in SEED_SPREAD.items()}
KNOWN_BIASED = ("uwb_ge1_frac",)
"""Tag outages (mean 20 s) cannot be told apart from overlapping per-anchor outages (mean 16 s, each
anchor out about half the time) by their length: the calibration finds none, turns them into
independent per-anchor outages and overestimates UWB >= 1 by ~18 %. Needs a joint model of the
anchors' outages (docs/calibration.md)."""


@pytest.fixture(scope="module")
def recovered():
    preset = load_scenario("cablecar-descending")
    cs = compile_scenario(preset)
    source = [generate_trace(cs, i, 11) for i in range(N)]
    res = calibrate(source, name="recovered")
    again = compile_scenario(res.scenario)
    m_preset = compute_metrics(generate_trace(cs, i, 12) for i in range(N))
    m_recal = compute_metrics(generate_trace(again, i, 12) for i in range(N))
    return m_preset, m_recal, res


@pytest.mark.parametrize("key", [k for k in SEED_SPREAD if k not in KNOWN_BIASED])
def test_recalibrated_metrics_within_seed_spread(recovered, key):
    m_preset, m_recal, _ = recovered
    dev = relative_deviation_pct(getattr(m_preset, key), getattr(m_recal, key))
    assert dev <= TOL_PCT[key], f"{key}: {dev:.1f} % > {TOL_PCT[key]:.1f} %"


@pytest.mark.xfail(strict=True, reason="tag outages not separable from overlapping per-anchor outages")
@pytest.mark.parametrize("key", KNOWN_BIASED)
def test_known_biased_metrics(recovered, key):
    m_preset, m_recal, _ = recovered
    assert relative_deviation_pct(getattr(m_preset, key), getattr(m_recal, key)) <= TOL_PCT[key]


def test_no_spread_invented(recovered):
    # the preset has no run-to-run ranging offsets: the calibration may find a few cm of noise, not more
    _, _, res = recovered
    assert res.scenario.uwb.run_offset_std_m < 0.05
