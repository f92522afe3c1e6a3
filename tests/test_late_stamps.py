"""Late bursts (``uwb.late_burst_prob``, ``uwb.late_burst_delay_s``): in ~1.5 % of the real Hanyang bursts
every range after the first is stamped ~31 ms late (measured in its slot, delivered late). Generated on
their own stream, recovered by calibration, found in the real runs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from physynth.calibrate import calibrate, fit_burst_schedule
from physynth.calibrate.uwb_fit import LATE_BURST_MIN, LATE_STAMP_MIN_S, burst_schedule
from physynth.generate import generate_trace, generate_traces
from physynth.io.scenario_file import load_scenario
from physynth.models.uwb import late_stamps
from physynth.scenario import scenario_from_dict, scenario_to_dict

HANYANG = Path(__file__).resolve().parents[2] / "shared" / "data" / "hanyang-uwb"
DELAY_S = 0.031


def _scenario(prob: float, delay_s: float = DELAY_S):
    d = scenario_to_dict(load_scenario("walk-hanyang"))  # 10 Hz bursts, four anchors
    d["uwb"].update(late_burst_prob=prob, late_burst_delay_s=delay_s)
    return scenario_from_dict(d, "late")


def _rows(uwb) -> np.ndarray:
    """Every row as a tuple of its columns but the stamp, sorted (rows compared as a multiset)."""
    cols = np.stack([uwb.burst.astype(float), uwb.anchor.astype(float), np.nan_to_num(uwb.range_m, nan=-1.0),
                     uwb.true_range_m, uwb.reason.astype(float), uwb.nlos.astype(float)], axis=1)
    return cols[np.lexsort(cols.T[::-1])]


def test_late_bursts_move_only_the_stamps_of_their_ranges_after_the_first():
    prob = 0.05
    base = generate_trace(_scenario(0.0), 3, 11)
    late = generate_trace(_scenario(prob), 3, 11)
    assert np.array_equal(base.truth.pos_enu_m, late.truth.pos_enu_m)
    assert np.array_equal(base.imu.acc_mps2, late.imu.acc_mps2)
    assert np.array_equal(_rows(base.uwb), _rows(late.uwb))  # the same rows, ranges measured at their slot
    assert np.all(np.diff(late.uwb.t_s) >= 0)  # sorted by stamp again
    # each row's stamp: the same as without late stamps, or exactly the delay later
    key = lambda u: np.lexsort((u.anchor, u.burst))  # noqa: E731 - a row is (burst, anchor)
    u0, u1 = base.uwb, late.uwb
    t0, t1, burst, ok = u0.t_s[key(u0)], u1.t_s[key(u1)], u0.burst[key(u0)], u0.valid[key(u0)]
    moved = t1 != t0
    assert np.allclose(t1[moved] - t0[moved], DELAY_S, rtol=0, atol=1e-9)
    assert ok[moved].all()  # delivered ranges only
    # a late burst: every delivered range but the first moved
    hit = np.unique(burst[moved])
    for b in hit:
        rows = np.flatnonzero((burst == b) & ok)
        assert not moved[rows[0]] and moved[rows[1:]].all(), b
    n = np.count_nonzero(np.bincount(burst[ok]) >= 2)  # bursts that can show it
    assert abs(hit.size - prob * n) < 4.0 * np.sqrt(n * prob * (1 - prob)), (hit.size, n)
    assert late.uwb.t_s[-1] <= late.truth.t_s[-1]  # still inside the truth span


def test_calibration_recovers_late_bursts_and_finds_none_where_there_are_none():
    prob = 0.02
    # without their IMU samples: the UWB fit does not use them (the same scenario but for its imu section,
    # to the last digit, checked), and the IMU calibration would add a third to the test's time
    traces = [replace(t, imu=None) for t in generate_traces(_scenario(prob), 2, seed=5)]
    fit = fit_burst_schedule(traces).diagnostics["late_bursts"]
    n = fit["n_bursts_two_or_more"]
    assert fit["applied"] and abs(fit["prob"] - prob) < 4.0 * np.sqrt(prob * (1 - prob) / n), fit
    assert fit["delay_s"] == pytest.approx(DELAY_S, abs=1e-3)  # the delay past the row's own slot
    assert fit["all_but_first_late_frac"] == 1.0
    res = calibrate(traces)
    assert res.scenario.uwb.late_burst_prob == pytest.approx(fit["prob"], rel=1e-3)
    assert res.scenario.uwb.late_burst_delay_s == pytest.approx(DELAY_S, abs=1e-3)
    # none generated, none found: the slots alone never pass the threshold
    none = fit_burst_schedule(list(generate_traces(_scenario(0.0), 2, seed=5))).diagnostics["late_bursts"]
    assert none["n_late_bursts"] == 0 and not none["applied"]
    # a delay under a grid bin is no late stamp
    short = fit_burst_schedule(list(generate_traces(_scenario(prob, 0.5 * LATE_STAMP_MIN_S), 2, seed=5)))
    assert short.diagnostics["late_bursts"]["n_late_bursts"] < LATE_BURST_MIN


@pytest.mark.parametrize(("preset", "slot_s", "extra", "naive_slots"),
                         [("walk-hanyang", 0.012, 0, 0), ("cablecar-descending", 0.0025, 8, 5)])
def test_a_random_ranging_order_at_wide_slots_is_no_late_stamp(preset, slot_s, extra, naive_slots):
    """Anchors ranged in a random order put rows up to one slot less than there are anchors from their
    place in the burst (four anchors 12 ms apart: 36 ms; fourteen 2.5 ms apart: 32.5 ms): more than a grid
    bin, and for fourteen anchors more than five slots from their median place, but no late stamp (the
    threshold is also five slots, or one per anchor if more)."""
    d = scenario_to_dict(load_scenario(preset))
    d["uwb"].update(slot_s=slot_s, late_burst_prob=0.0)
    d["anchors"] += [{**a, "id": f"X{i}", "pos_enu_m": [a["pos_enu_m"][0] + 5.0, *a["pos_enu_m"][1:]]}
                     for i, a in enumerate(d["anchors"][:extra])]
    traces = []
    rng = np.random.default_rng(3)
    for tr in generate_traces(scenario_from_dict(d, "wide"), 2, seed=5):
        u = tr.uwb
        t = u.t_s.copy()
        for b in np.unique(u.burst):  # the burst's slot times dealt to its rows in a random order
            rows = np.flatnonzero(u.burst == b)
            t[rows] = t[rows][rng.permutation(rows.size)]
        o = np.argsort(t, kind="stable")
        uwb = type(u)(t_s=t[o], anchor=u.anchor[o], range_m=u.range_m[o], true_range_m=u.true_range_m[o],
                      nlos=u.nlos[o], burst=u.burst[o], reason=u.reason[o], nlos_known=True)
        traces.append(type(tr)(truth=tr.truth, imu=tr.imu, uwb=uwb, anchors=tr.anchors, meta=tr.meta))
    fit = fit_burst_schedule(traces)
    late = fit.diagnostics["late_bursts"]
    assert late["n_late_bursts"] == 0 and not late["applied"], late
    n_anchors = len(traces[0].anchors)
    assert late["min_delay_s"] == pytest.approx(max(5, n_anchors) * fit.params["slot_s"], rel=0.05)
    # one grid bin alone (four anchors), or with five slots (fourteen), would have called many of them late
    e = np.concatenate([burst_schedule(t).within_offset_s for t in traces])
    assert np.count_nonzero(e - np.median(e) > max(LATE_STAMP_MIN_S, naive_slots * slot_s)) > 100


def test_late_stamps_refuse_rows_out_of_burst_order():
    rec = generate_trace(_scenario(0.0), 0, 1).uwb
    rng = np.random.default_rng(0)
    no_ids = type(rec)(t_s=rec.t_s, anchor=rec.anchor, range_m=rec.range_m)  # burst -1: a real record
    with pytest.raises(ValueError, match="burst order"):
        late_stamps(no_ids, 0.5, DELAY_S, rng=rng)
    assert late_stamps(rec, 0.0, DELAY_S, rng=rng) is rec  # none late: the record itself


@pytest.mark.skipif(not HANYANG.is_dir(), reason="needs ../shared/data/hanyang-uwb")
def test_the_real_walks_have_late_bursts(tmp_path):
    """About 1.5 % of the shared Hanyang runs' bursts have their ranges after the first stamped ~31 ms late
    (150 of ~9,800; all ranges but the first in 147 of them)."""
    from physynth.io.importers.hanyang import import_hanyang

    runs = [HANYANG / "Dynamic_measurements" / c / "Trajectory_A" / k for c in ("LOS", "NLOS")
            for k in ("Case_1", "Case_2")]
    traces = [import_hanyang(r)[0] for r in runs]
    fit = fit_burst_schedule(traces).diagnostics["late_bursts"]
    assert fit["applied"] and 0.008 < fit["prob"] < 0.03, fit
    assert all(0.005 < p < 0.03 for p in fit["prob_per_run"]), fit["prob_per_run"]
    assert fit["all_but_first_late_frac"] > 0.9, fit
    assert 0.028 < fit["delay_s"] < 0.034, fit
