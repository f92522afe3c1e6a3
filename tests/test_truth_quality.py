"""The truth's own quality: spans where the recording says its truth errs (``truth_untrusted_s``), read by
the Hanyang importer from the RTK receiver's status; the validation that compares residuals only outside
them (the default; ``all_truth=True``, ``--all-truth``: every range) and the calibration that fits the
ranging channel there (``trusted_truth=True``, ``--trusted-truth``; by default it takes every range)."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import simple_scenario

from physynth.calibrate import calibrate
from physynth.calibrate.uwb_fit import robust_line
from physynth.errors import RecordingError
from physynth.evaluate.metrics import residuals
from physynth.generate import generate_traces
from physynth.io.importers import import_hanyang
from physynth.models.uwb import range_decades
from physynth.records import TRUTH_UNTRUSTED_KEY, untrusted_truth

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
DYN = DATA / "Dynamic_measurements"
real = pytest.mark.skipif(not (DYN / "NLOS" / "Trajectory_A" / "Case_2").is_dir(),
                          reason=f"real Hanyang data not found at {DATA}")


def test_untrusted_truth_masks_the_spans_end_exclusive():
    meta = {TRUTH_UNTRUSTED_KEY: [[5.0, 6.0], [1.0, 2.0], [1.5, 3.0]]}  # unsorted, overlapping
    t = np.array([0.5, 1.0, 1.7, 2.5, 3.0, 4.0, 5.0, 5.99, 6.0, 7.0])
    np.testing.assert_array_equal(untrusted_truth(meta, t), [0, 1, 1, 1, 0, 0, 1, 1, 0, 0])
    assert not untrusted_truth({}, t).any() and not untrusted_truth({TRUTH_UNTRUSTED_KEY: []}, t).any()


@real
@pytest.mark.parametrize(("case", "lo", "hi"), [("LOS/Trajectory_A/Case_1", 0.95, 1.0),
                                                ("NLOS/Trajectory_A/Case_2", 0.6, 0.8)])
def test_hanyang_spans_hold_every_solution_without_an_rtk_fix(case, lo, hi):
    """Read independently from gnss.csv: every solution without an RTK fix (status != 2) or with a
    horizontal variance above 1e-3 m^2 lies inside a span, every other one outside."""
    tr, rep = import_hanyang(DYN / case)
    g = pd.read_csv(DYN / case / "gnss.csv")
    t = g["field.header.stamp"].to_numpy(float) * 1e-9 - tr.meta["time_origin_unix_s"]
    var = np.maximum(g["field.position_covariance0"], g["field.position_covariance4"]).to_numpy()
    bad = (g["field.status.status"].to_numpy() != 2) | (var > 1e-3)
    assert bad.any() and (~bad).any()
    np.testing.assert_array_equal(untrusted_truth(tr.meta, t), bad)
    assert lo < tr.meta["truth_trusted_share"] < hi
    assert tr.meta["truth_trusted_share"] == pytest.approx(1 - bad.mean(), abs=1e-4)
    assert any("RTK-fixed" in n for n in rep.notes)


def test_residuals_leave_out_the_ranges_at_untrusted_truth():
    scn = simple_scenario(**WALK, **{"uwb.burst_rate_hz": 10.0, "channel.rate_hz": 10.0})
    (tr,) = generate_traces(scn, 1, seed=2)
    r_all, _, t_all = residuals(tr)
    span = [float(t_all[100]), float(t_all[400])]
    marked = dataclasses.replace(tr, meta={**tr.meta, TRUTH_UNTRUSTED_KEY: [span]})
    r, _, t = residuals(marked)
    inside = (t_all >= span[0]) & (t_all < span[1])
    assert 250 < inside.sum() < r_all.size and r.size == r_all.size - inside.sum()
    np.testing.assert_array_equal(t, t_all[~inside])


@real
def test_hanyang_ranges_scatter_more_where_the_rtk_truth_is_not_fixed():
    """NLOS Case_2 (31 % of its solutions without the fix): the ranges more than 15 cm off their
    anchor's LOS line (lag-corrected residuals) are at least three times as common where the truth is
    untrusted (measured 14 % against 2.7 %)."""
    tr, _ = import_hanyang(DYN / "NLOS" / "Trajectory_A" / "Case_2", crop_to_uwb=True)
    spans, lag = tr, 0.177
    every = {k: v for k, v in tr.meta.items() if k != TRUTH_UNTRUSTED_KEY}  # residuals() would leave them out
    tr = dataclasses.replace(tr, uwb=dataclasses.replace(tr.uwb, t_s=tr.uwb.t_s - lag), meta=every)
    res, idx, t = residuals(tr)
    rng = np.linalg.norm(tr.truth.position_at(t) - tr.anchors.pos_enu_m[idx], axis=1)
    dev = np.empty_like(res)
    for k in range(len(tr.anchors)):
        s = idx == k
        mu, beta, _, _ = robust_line(res[s], range_decades(rng[s]), True)
        dev[s] = res[s] - mu - beta * range_decades(rng[s])
    bad = untrusted_truth(spans.meta, t)
    near = np.abs(dev) < 1.0
    off = np.abs(dev) > 0.15
    share_bad, share_good = off[bad & near].mean(), off[~bad & near].mean()
    assert (bad & near).sum() > 1000 and share_bad > 3 * share_good, (share_bad, share_good)


@real
def test_a_run_without_gnss_file_trusts_its_truth_and_a_broken_one_is_refused(tmp_path):
    run = tmp_path / "Case_1"
    shutil.copytree(DYN / "LOS" / "Trajectory_A" / "Case_1", run)
    (run / "gnss.csv").unlink()
    tr, rep = import_hanyang(run)
    assert TRUTH_UNTRUSTED_KEY not in tr.meta and any("no gnss.csv" in n for n in rep.notes)
    pd.DataFrame({"field.header.stamp": [1.0], "field.status.status": [2]}).to_csv(run / "gnss.csv", index=False)
    with pytest.raises(RecordingError, match="gnss.csv.*field.position_covariance0"):
        import_hanyang(run)


WALK = {"path": {"kind": "waypoints", "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0},
                 "waypoints_enu_m": [[0, 0, 1], [40, 0, 1], [40, 30, 1], [0, 30, 1], [0, 0, 1]]},
        "anchors": [{"id": "A1", "pos_enu_m": [-10, -10, 2]}, {"id": "A2", "pos_enu_m": [50, -10, 2]},
                    {"id": "A3", "pos_enu_m": [20, 40, 2]}]}


def _with_truth_errors(trace, *, share: float, shift_m: float, seed: int):
    """``trace`` with spans over ``share`` of its time in which the ranges read ``shift_m`` (plus 5 cm of
    slow scatter) off, as a truth position error projected on every anchor would make them."""
    rng = np.random.default_rng(seed)
    t0, t1 = trace.truth.t_s[0], trace.truth.t_s[-1]
    n = 6
    length = share * (t1 - t0) / n
    starts = t0 + np.arange(n) * (t1 - t0) / n + rng.uniform(0, (t1 - t0) / n - length, n)
    spans = [[float(a), float(a + length)] for a in starts]
    meta = {**trace.meta, TRUTH_UNTRUSTED_KEY: spans}
    bad = untrusted_truth(meta, trace.uwb.t_s)
    drift = shift_m + 0.05 * np.sin(trace.uwb.t_s / 3.0)
    rng_m = np.where(bad, trace.uwb.range_m + drift, trace.uwb.range_m)
    return dataclasses.replace(trace, uwb=dataclasses.replace(trace.uwb, range_m=rng_m), meta=meta), bad.mean()


def test_trusted_truth_calibration_sees_through_the_truth_errors():
    """Walks with 3 cm LOS errors and 4 % NLOS ranges (+0.6 m), and in a third of their time a truth
    that reads 25 cm off: the default fit takes those ranges as ranging errors (a wider channel, more
    NLOS), the trusted-truth fit recovers the generated channel; without it (the default) the spans are
    ignored."""
    scn = simple_scenario(**WALK, **{"channel.los_std_m": 0.03, "channel.nlos_prob": 0.04,
                                     "channel.nlos_modes": [{"weight": 1.0, "mean_m": 0.6, "std_m": 0.2}],
                                     "uwb.burst_rate_hz": 10.0, "channel.rate_hz": 10.0,
                                     "motion.cruise_speed_mps": 1.2})
    clean = [dataclasses.replace(t, imu=None) for t in generate_traces(scn, 3, seed=5)]
    pairs = [_with_truth_errors(t, share=0.33, shift_m=-0.25, seed=i) for i, t in enumerate(clean)]
    traces = [p[0] for p in pairs]
    assert 0.25 < np.mean([p[1] for p in pairs]) < 0.4
    plain = calibrate(traces)
    fit = calibrate(traces, trusted_truth=True)
    ch, ch0 = fit.scenario.channel, plain.scenario.channel
    assert ch.los_std_m == pytest.approx(0.03, rel=0.15)
    assert ch.nlos_prob == pytest.approx(0.04, abs=0.015)
    far = [m for m in ch.nlos_modes if m.mean_m > 0.3]
    assert far and sum(m.weight for m in far) > 0.8  # the +0.6 m mode, not a truth-error mode below LOS
    assert ch0.nlos_prob > 0.1 or ch0.los_std_m > 1.5 * 0.03  # every range: fooled by the truth errors
    tq = fit.report["truth_quality"]
    assert tq["trusted_truth"] and all(0.25 < v < 0.4 for v in tq["untrusted_share_of_truth"].values())
    # without trusted_truth the spans change nothing
    again = calibrate([dataclasses.replace(t, meta={k: v for k, v in t.meta.items() if k != TRUTH_UNTRUSTED_KEY})
                       for t in traces])
    assert not plain.report["truth_quality"]["trusted_truth"]
    assert again.scenario.channel == plain.scenario.channel
    assert again.scenario.channel_per_anchor == plain.scenario.channel_per_anchor


@real
def test_cli_imports_the_spans_and_calibrates_and_validates_on_the_trusted_truth(tmp_path, capsys):
    """``physynth import hanyang`` keeps the spans through the dataset files; ``physynth calibrate
    --trusted-truth`` reports the run's untrusted share and that it used them (by default: not);
    ``physynth validate`` leaves the real ranges at untrusted truth out of the residuals, counted
    (``--all-truth``: compared too)."""
    import json

    from physynth.cli import main
    from physynth.io.dataset import read_dataset

    ds, scn, rep = tmp_path / "nlos2", tmp_path / "s.yaml", tmp_path / "fit.json"
    main(["import", "hanyang", str(DYN / "NLOS" / "Trajectory_A" / "Case_2"), "--crop-to-uwb", "--out", str(ds), "-q"])
    capsys.readouterr()
    main(["inspect", str(ds)])
    assert "1 trace flags spans where the truth errs" in capsys.readouterr().out
    (trace,) = read_dataset(ds).traces
    direct, _ = import_hanyang(DYN / "NLOS" / "Trajectory_A" / "Case_2", crop_to_uwb=True)
    assert trace.meta[TRUTH_UNTRUSTED_KEY] == direct.meta[TRUTH_UNTRUSTED_KEY]
    main(["calibrate", str(ds), "--trusted-truth", "--out", str(scn), "--report", str(rep), "-q"])
    tq = json.loads(rep.read_text())["truth_quality"]
    assert tq["trusted_truth"] is True
    (share,) = tq["untrusted_share_of_truth"].values()
    assert share == pytest.approx(float(np.mean(untrusted_truth(direct.meta, direct.truth.t_s))), abs=1e-9)
    assert 0.2 < share < 0.4
    rep_all = tmp_path / "fit-all.json"
    main(["calibrate", str(ds), "--out", str(tmp_path / "a.yaml"), "--report", str(rep_all), "-q"])
    assert json.loads(rep_all.read_text())["truth_quality"]["trusted_truth"] is False
    u = direct.uwb
    n_bad = int(untrusted_truth(direct.meta, u.t_s[u.valid]).sum())
    inside = (u.t_s[u.valid] >= direct.truth.t_s[0]) & (u.t_s[u.valid] <= direct.truth.t_s[-1])
    counts = {}
    for flag in ([], ["--all-truth"]):
        out = tmp_path / f"rep{len(flag)}"
        main(["validate", "--real", str(ds), "--scenario", str(scn), "--transfer", "-n", "1", "--seed", "1",
              "--no-figures", "--out", str(out), "-q", *flag])
        got = json.loads((out / "report.json").read_text())["inputs"]
        counts[len(flag)] = got["n_residuals"]["real"]
        md = (out / "report.md").read_text()
        assert f"{n_bad} of" in md and ("left out of the residual metrics" in md) is (not flag)
        assert got["real"]["truth"]["untrusted_truth_ranges"] == n_bad > 1000
        assert got["real"]["truth"]["untrusted_left_out_of_residuals"] is (not flag)
    assert counts[1] == int(inside.sum()) and counts[0] == counts[1] - int((untrusted_truth(
        direct.meta, u.t_s[u.valid]) & inside).sum())
