"""Late stamps (``uwb.late_stamp_prob``, ``uwb.late_stamp_delay_s``): ranges measured in their slot and
stamped a fixed delay later, as ~1 % of the real Hanyang rows are (~31 ms after their burst). Generated on
their own stream, recovered by calibration, found in the real runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physynth.calibrate import calibrate, fit_burst_schedule
from physynth.calibrate.uwb_fit import LATE_STAMP_MIN_ROWS, LATE_STAMP_MIN_S
from physynth.generate import generate_trace, generate_traces
from physynth.io.scenario_file import load_scenario
from physynth.scenario import scenario_from_dict, scenario_to_dict

HANYANG = Path(__file__).resolve().parents[2] / "shared" / "data" / "hanyang-uwb"
DELAY_S = 0.031


def _scenario(prob: float, delay_s: float = DELAY_S):
    d = scenario_to_dict(load_scenario("walk-hanyang"))  # 10 Hz bursts, four anchors
    d["uwb"].update(late_stamp_prob=prob, late_stamp_delay_s=delay_s)
    return scenario_from_dict(d, "late")


def _rows(uwb) -> np.ndarray:
    """Every row as a tuple of its columns but the stamp, sorted (rows compared as a multiset)."""
    cols = np.stack([uwb.burst.astype(float), uwb.anchor.astype(float), np.nan_to_num(uwb.range_m, nan=-1.0),
                     uwb.true_range_m, uwb.reason.astype(float), uwb.nlos.astype(float)], axis=1)
    return cols[np.lexsort(cols.T[::-1])]


def test_late_stamps_move_only_the_stamps_of_their_rows():
    prob = 0.05
    base = generate_trace(_scenario(0.0), 3, 11)
    late = generate_trace(_scenario(prob), 3, 11)
    assert np.array_equal(base.truth.pos_enu_m, late.truth.pos_enu_m)
    assert np.array_equal(base.imu.acc_mps2, late.imu.acc_mps2)
    assert np.array_equal(_rows(base.uwb), _rows(late.uwb))  # the same rows, ranges measured at their slot
    assert np.all(np.diff(late.uwb.t_s) >= 0)  # sorted by stamp again
    # each row's stamp: the same as without late stamps, or exactly the delay later
    key = lambda u: np.lexsort((u.anchor, u.burst))  # noqa: E731 - a row is (burst, anchor)
    t0, t1 = base.uwb.t_s[key(base.uwb)], late.uwb.t_s[key(late.uwb)]
    moved = t1 != t0
    assert np.allclose(t1[moved] - t0[moved], DELAY_S, rtol=0, atol=1e-9)
    n = t0.size
    assert abs(moved.sum() - prob * n) < 4.0 * np.sqrt(n * prob * (1 - prob)), (moved.sum(), n)
    assert late.uwb.t_s[-1] <= late.truth.t_s[-1]  # still inside the truth span


def test_calibration_recovers_late_stamps_and_finds_none_where_there_are_none():
    prob = 0.02
    traces = list(generate_traces(_scenario(prob), 2, seed=5))
    fit = fit_burst_schedule(traces).diagnostics["late_stamps"]
    n = fit["n_rows"]
    assert fit["applied"] and abs(fit["prob"] - prob) < 4.0 * np.sqrt(prob * (1 - prob) / n), fit
    assert fit["delay_s"] == pytest.approx(DELAY_S, abs=1e-3)  # the delay past the row's own slot
    res = calibrate(traces)
    assert res.scenario.uwb.late_stamp_prob == pytest.approx(fit["prob"], rel=1e-3)
    assert res.scenario.uwb.late_stamp_delay_s == pytest.approx(DELAY_S, abs=1e-3)
    # none generated, none found: the slots alone never pass the threshold
    none = fit_burst_schedule(list(generate_traces(_scenario(0.0), 2, seed=5))).diagnostics["late_stamps"]
    assert none["n_late"] == 0 and not none["applied"]
    # a delay under a grid bin is no late stamp
    short = fit_burst_schedule(list(generate_traces(_scenario(prob, 0.5 * LATE_STAMP_MIN_S), 2, seed=5)))
    assert short.diagnostics["late_stamps"]["n_late"] < LATE_STAMP_MIN_ROWS


@pytest.mark.skipif(not HANYANG.is_dir(), reason="needs ../shared/data/hanyang-uwb")
def test_the_real_walks_have_late_stamps(tmp_path):
    """About 1 % of every shared Hanyang run's rows are stamped ~31 ms after their slot (65-135 per run)."""
    from physynth.io.importers.hanyang import import_hanyang

    runs = [HANYANG / "Dynamic_measurements" / c / "Trajectory_A" / k for c in ("LOS", "NLOS")
            for k in ("Case_1", "Case_2")]
    traces = [import_hanyang(r)[0] for r in runs]
    fit = fit_burst_schedule(traces).diagnostics["late_stamps"]
    assert fit["applied"] and 0.005 < fit["prob"] < 0.02, fit
    assert all(0.004 < p < 0.02 for p in fit["prob_per_run"]), fit["prob_per_run"]
    assert 0.028 < fit["delay_s"] < 0.034, fit
