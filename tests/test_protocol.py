"""The tracking study's protocols: runs grouped by anchor layout, folds, seeds, summaries, paired tests."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import ttest_rel, wilcoxon
from track_helpers import ANCHORS, site_scenario

from physynth.cli import main
from physynth.errors import PhySynthError
from physynth.generate import generate_trace
from physynth.io import write_dataset
from physynth.records import Anchors
from physynth.studies.protocol import (
    compare_methods,
    default_protocol,
    layout_groups,
    make_folds,
    run_protocol,
    same_layout,
    summarize,
)
from physynth.studies.tracking import StudyConfig, StudyRun, default_data_root, hanyang_default_runs

TINY = {"epochs": 1, "pretrain_epochs": 1, "finetune_epochs": 1, "n_synth_traces": 2, "synth_windows_per_trace": 3,
        "threads": 1, "net": {"hidden": 8, "heads": 2, "window_steps": 12, "stride_steps": 6, "burn_in_steps": 2}}
MOVED = [{**a, "pos_enu_m": [a["pos_enu_m"][0] + 3.0, a["pos_enu_m"][1], a["pos_enu_m"][2] + 0.5]} for a in ANCHORS]


def _relabelled(trace, order):
    """The trace with its anchors listed in another order (the same layout, other ids at each place)."""
    a = trace.anchors
    anchors = Anchors(ids=tuple(a.ids[i] for i in order), names=a.names, pos_enu_m=a.pos_enu_m[order])
    inv = np.argsort(order)
    uwb = replace(trace.uwb, anchor=inv[trace.uwb.anchor].astype(trace.uwb.anchor.dtype))
    return replace(trace, anchors=anchors, uwb=uwb)


@pytest.fixture(scope="module")
def two_layouts():
    """Four runs of two anchor layouts (two runs each; the second run of each lists its anchors in
    another order)."""
    a, b = site_scenario(noise_m=0.05), site_scenario(noise_m=0.05, anchors=MOVED)
    runs = [StudyRun(label="a0", trace=generate_trace(a, 0, 5)),
            StudyRun(label="a1", trace=_relabelled(generate_trace(a, 1, 5), [2, 0, 3, 1])),
            StudyRun(label="b0", trace=generate_trace(b, 2, 5)),
            StudyRun(label="b1", trace=_relabelled(generate_trace(b, 3, 5), [1, 3, 0, 2]))]
    return a, runs


def test_same_layout_ignores_anchor_order_not_positions():
    lay = np.array([p["pos_enu_m"] for p in ANCHORS], float)
    assert same_layout(lay, lay[[3, 1, 0, 2]])
    assert same_layout(lay, lay + 0.05)  # within the tolerance (0.09 m apart)
    moved = lay.copy()
    moved[2, 2] += 0.5
    assert not same_layout(lay, moved)
    assert not same_layout(lay, lay[:3])


def test_layout_groups_and_folds(two_layouts):
    _, runs = two_layouts
    assert layout_groups(runs) == [[0, 1], [2, 3]]
    assert default_protocol(runs, tests_given=False) == "leave-one-layout-out"
    assert default_protocol(runs[:2], tests_given=False) == "leave-one-run-out"
    assert default_protocol(runs, tests_given=True) == "split"
    folds = make_folds("leave-one-layout-out", runs)
    assert [[r.label for r in f.test] for f in folds] == [["a0", "a1"], ["b0", "b1"]]
    assert [[r.label for r in f.train] for f in folds] == [["b0", "b1"], ["a0", "a1"]]
    for f in folds:  # no test layout is a training layout
        assert not any(same_layout(t.trace.anchors.pos_enu_m, r.trace.anchors.pos_enu_m) for t in f.test
                       for r in f.train)
    assert [f.test[0].label for f in make_folds("leave-one-run-out", runs)] == ["a0", "a1", "b0", "b1"]
    with pytest.raises(PhySynthError, match="two or more anchor layouts"):
        make_folds("leave-one-layout-out", runs[:2])
    with pytest.raises(PhySynthError, match="protocol must be one of"):
        make_folds("k-fold", runs)
    with pytest.raises(PhySynthError, match="holds out runs of the given ones itself"):
        make_folds("leave-one-layout-out", runs, runs[:1])


@pytest.mark.skipif(not (default_data_root() / "hanyang-uwb").is_dir(), reason="shared Hanyang runs not present")
def test_the_hanyang_runs_hold_two_layouts():
    train, test = hanyang_default_runs()
    runs = [*train, test]
    assert [[runs[i].label for i in g] for g in layout_groups(runs)] == [
        ["LOS/Trajectory_A/Case_1", "NLOS/Trajectory_A/Case_1"],
        ["LOS/Trajectory_A/Case_2", "NLOS/Trajectory_A/Case_2"]]


def test_compare_methods_pairs_runs_and_seeds():
    rng = np.random.default_rng(3)
    recs = []
    for seed in range(3):
        for run in ("r1", "r2", "r3"):
            base = rng.uniform(0.5, 1.5)
            recs.append({"fold": "f", "seed": seed, "run": run, "method": "NOAUG", "rmse_m": base})
            recs.append({"fold": "f", "seed": seed, "run": run, "method": "SYNTH_PHY",
                         "rmse_m": base - 0.1 + rng.normal(0, 0.02)})
    (c,) = compare_methods(recs, pairs=[("SYNTH_PHY", "NOAUG")])
    a = np.array([r["rmse_m"] for r in recs if r["method"] == "SYNTH_PHY"])
    b = np.array([r["rmse_m"] for r in recs if r["method"] == "NOAUG"])
    assert c["n_pairs"] == 9 and c["wins"] == int((a < b).sum())
    assert c["mean_diff_m"] == pytest.approx(float(np.mean(a - b)))
    assert c["p_wilcoxon"] == pytest.approx(float(wilcoxon(a, b).pvalue))
    assert c["p_ttest"] == pytest.approx(float(ttest_rel(a, b).pvalue))
    assert c["p_ttest"] < 0.01  # a 0.1 m improvement against 0.02 m of noise
    assert compare_methods(recs[:4], pairs=[("SYNTH_PHY", "NOAUG")])[0]["p_wilcoxon"] is None  # 2 pairs
    s = summarize([{**r, "rmse_2d_m": r["rmse_m"], "rmse_v_m": 0.0, "p95_m": 2 * r["rmse_m"]} for r in recs])
    row = next(r for r in s if r["run"] == "r1" and r["method"] == "NOAUG")
    vals = [r["rmse_m"] for r in recs if r["run"] == "r1" and r["method"] == "NOAUG"]
    assert row["n_seeds"] == 3 and row["rmse_m"] == pytest.approx(np.mean(vals))
    assert row["rmse_m_std"] == pytest.approx(np.std(vals, ddof=1))


def test_run_protocol_leaves_each_layout_out_over_seeds(two_layouts):
    pytest.importorskip("torch")
    scn, runs = two_layouts
    cfg = StudyConfig(methods=("NOAUG", "ekf"), **TINY)
    res = run_protocol(runs, protocol=None, seeds=(0, 1), scenario=scn, config=cfg)
    assert res.protocol == "leave-one-layout-out" and len(res.studies) == 4
    assert {(r["fold"], r["seed"]) for r in res.per_run} == {(f["name"], s) for f in res.folds for s in (0, 1)}
    noaug = [r for r in res.summary if r["method"] == "NOAUG"]
    assert {r["run"] for r in noaug} == {"a0", "a1", "b0", "b1"} and all(r["n_seeds"] == 2 for r in noaug)
    for r in noaug:
        assert r["rmse_m"] ** 2 == pytest.approx(r["rmse_2d_m"] ** 2 + r["rmse_v_m"] ** 2, rel=0.05)
    assert all(np.isfinite(r["rmse_m_std"]) for r in noaug)
    (c,) = [c for c in res.comparisons if (c["method"], c["against"]) == ("NOAUG", "ekf")]
    assert c["n_pairs"] == 8
    only_classical = run_protocol(runs, seeds=(0, 1, 2), scenario=scn, config=StudyConfig(methods=("ekf",)))
    assert only_classical.seeds == [0]  # nothing to vary
    with pytest.raises(PhySynthError, match="distinct"):
        run_protocol(runs, seeds=(1, 1), scenario=scn, config=cfg)


def test_survey_only_needs_no_training_run(two_layouts):
    pytest.importorskip("torch")
    scn, runs = two_layouts
    res = run_protocol([], runs[:2], protocol="survey-only", seeds=(0,), scenario=scn,
                       config=StudyConfig(methods=("SYNTH_PHY", "ekf"), **TINY))
    keys = [r["key"] for r in res.studies[0].rows]
    assert keys[:2] == ["SYNTH_PHY (survey only)", "ekf"] and "SYNTH_PHY" not in keys
    with pytest.raises(PhySynthError, match="NOAUG train on real runs"):
        run_protocol([], runs[:2], protocol="survey-only", seeds=(0,), scenario=scn,
                     config=StudyConfig(methods=("NOAUG",), **TINY))
    with pytest.raises(PhySynthError, match="needs the site's scenario"):
        run_protocol([], runs[:2], protocol="survey-only", seeds=(0,), config=StudyConfig(methods=("ekf",)))


def test_cli_writes_the_summary_over_seeds(two_layouts, tmp_path, capsys):
    pytest.importorskip("torch")
    _, runs = two_layouts
    data = write_dataset(tmp_path / "runs", [r.trace for r in runs])
    main(["study", "tracking", "--train", str(data), "--methods", "NOAUG,ekf", "--seeds", "2", "--epochs", "1",
          "--tag-height", "1.0", "--tag-height-std", "0.1", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert "leave-one-layout-out" in out and "NOAUG against ekf" in out
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["protocol"] == "leave-one-layout-out" and res["seeds"] == [0, 1] and len(res["studies"]) == 4
    assert res["config"]["height"] == "given" and res["studies"][0]["data"]["height_prior"] == {"mean_m": 1.0,
                                                                                                "std_m": 0.1}
    assert {r["key"] for r in res["rows"]} >= {"NOAUG", "ekf"}
    md = (tmp_path / "out" / "results.md").read_text()
    assert "## Per test run (mean ± std over seeds)" in md and "Paired comparisons" in md
    assert (tmp_path / "out" / "rmse_by_run.png").stat().st_size > 1000
    assert (tmp_path / "out" / "studies" / "2-seed1" / "estimates.npz").is_file()


def test_studies_at_once_give_the_same_numbers(two_layouts):
    pytest.importorskip("torch")
    scn, runs = two_layouts
    cfg = StudyConfig(methods=("NOAUG",), **TINY)
    one = run_protocol(runs, seeds=(0,), scenario=scn, config=cfg)
    two = run_protocol(runs, seeds=(0,), scenario=scn, config=cfg, jobs=2)  # the two folds in two processes
    assert [r["rmse_m"] for r in one.per_run] == [r["rmse_m"] for r in two.per_run]
    assert len(two.per_run) == 8  # four test runs, NOAUG and the ekf prior it was given
