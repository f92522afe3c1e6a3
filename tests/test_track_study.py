"""The tracking study end to end (tiny schedule), its results files, and the CLI's bad-input lines."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from track_helpers import site_scenario  # noqa: E402

from physynth.cli import main  # noqa: E402
from physynth.errors import PhySynthError  # noqa: E402
from physynth.generate import generate_trace  # noqa: E402
from physynth.io import write_dataset  # noqa: E402
from physynth.io.scenario_file import save_scenario  # noqa: E402
from physynth.records import Trace, Truth, Uwb  # noqa: E402
from physynth.studies.tracking import (  # noqa: E402
    METHODS,
    StudyConfig,
    StudyRun,
    finetune_windows,
    run_tracking_study,
)
from physynth.studies.tracking_report import write_results  # noqa: E402

TINY = {"epochs": 2, "pretrain_epochs": 1, "finetune_epochs": 1, "n_synth_traces": 2, "synth_windows_per_trace": 4,
        "gan_steps": 50, "gan_copies": 1, "threads": 1,
        "net": {"hidden": 16, "heads": 2, "window_steps": 12, "stride_steps": 6, "burn_in_steps": 2}}


@pytest.fixture(scope="module")
def runs():
    scn = site_scenario(noise_m=0.05, **{"uwb.time_offset_s": 0.05})
    return scn, [StudyRun(label=f"run{i}", trace=generate_trace(scn, i, 99)) for i in range(3)]


def test_tiny_study_end_to_end_and_results_parse(runs, tmp_path):
    scn, rr = runs
    res = run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**TINY))
    files = write_results(res, tmp_path)
    data = json.loads(files["json"].read_text())
    keys = [r["key"] for r in data["rows"]]
    assert keys[:len(METHODS) + 1] == ["NOAUG", "AUG_GAN", "SYNTH_PHY (synthetic only)", "SYNTH_PHY", "bilstm",
                                       "ls", "ekf"]
    for row in data["rows"]:
        assert {"method", "rmse_m", "rmse_2d_m", "mae_m", "p50_m", "p95_m", "delta_rmse_pct"} <= set(row)
        assert np.isfinite(row["rmse_m"]) and row["p95_m"] >= row["p50_m"]
    assert data["rows"][0]["delta_rmse_pct"] is None and data["rows"][1]["delta_rmse_pct"] is not None
    assert data["config"]["epochs"] == 2 and data["config"]["finetune_lr"] == 5e-5
    assert data["data"]["time_offset"]["offset_s"] == pytest.approx(0.05, abs=0.01)  # estimated, not given
    ekf = next(r for r in data["rows"] if r["key"] == "ekf")
    assert ekf["rmse_2d_m"] < 0.25  # height is weakly observed by this layout
    md = files["md"].read_text()
    assert "| Method | RMSE (m)" in md and "NOAUG" in md
    assert files["figure"].stat().st_size > 1000
    with np.load(files["estimates"]) as est:  # every row's RMSE, recomputed from the saved estimates
        ok = est["scored"]
        assert ok.sum() > 1000 and est["trusted"].all() and est["truth_enu_m"].shape == (ok.size, 3)
        for row in data["rows"]:
            err = est["estimate/" + row["key"]][ok] - est["truth_enu_m"][ok]
            assert np.sqrt(np.mean(np.sum(err**2, axis=1))) == pytest.approx(row["rmse_m"], rel=1e-9)


def test_study_is_deterministic_for_a_seed(runs):
    scn, rr = runs
    cfg = StudyConfig(**{**TINY, "methods": ("NOAUG", "SYNTH_PHY")})
    a = run_tracking_study(rr[:2], rr[2], scenario=scn, config=cfg)
    b = run_tracking_study(rr[:2], rr[2], scenario=scn, config=cfg)
    assert [r["rmse_m"] for r in a.rows] == [r["rmse_m"] for r in b.rows]


def test_finetune_mix_draws_real_and_synthetic_windows_deterministically(runs):
    from physynth.track.inputs import track_input
    from physynth.track.torch_data import SyntheticWindows, TraceWindows, WindowSpec

    scn, rr = runs
    spec = WindowSpec(length=12, stride=6)
    real = TraceWindows([track_input(r.trace) for r in rr[:2]], spec)
    synth = SyntheticWindows(scn, 3, 5, spec, windows_per_trace=8, cache_size=3)
    same, n0 = finetune_windows(real, synth, 0.0, 1)
    assert same is real and n0 == 0
    mixed, n = finetune_windows(real, synth, 0.5, 1)
    assert n == round(0.5 * len(real)) and len(mixed) == len(real) + n
    first, second = mixed.datasets
    assert first is real and second.dataset is synth and len(set(second.indices)) == n
    again, _ = finetune_windows(real, synth, 0.5, 1)
    other, _ = finetune_windows(real, synth, 0.5, 2)
    assert list(again.datasets[1].indices) == list(second.indices) != list(other.datasets[1].indices)
    capped, n_all = finetune_windows(real, synth, 100.0, 1)
    assert n_all == len(synth)  # never more than the pre-training set
    with pytest.raises(PhySynthError):
        StudyConfig(finetune_synth_ratio=-0.1)


def test_finetune_mix_and_input_switch_are_honoured_and_recorded(runs):
    scn, rr = runs
    base = {**TINY, "methods": ("SYNTH_PHY",)}
    plain = run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**base))
    mixed = run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**base, finetune_synth_ratio=1.0))
    off = run_tracking_study(rr[:2], rr[2], scenario=scn,
                             config=StudyConfig(**{**base, "net": {**TINY["net"], "age_weighted_direction": False}}))
    n_real = plain.data["notes"]["finetune_windows"]["real"]
    assert plain.data["notes"]["finetune_windows"] == {"real": n_real, "synthetic": 0}
    assert mixed.data["notes"]["finetune_windows"] == {"real": n_real, "synthetic": min(n_real, 8)}
    assert mixed.config["finetune_synth_ratio"] == 1.0 and plain.config["finetune_synth_ratio"] == 0.0
    stages = [h["stage"] for h in mixed.data["notes"]["SYNTH_PHY.training"]]
    assert stages[-1] == "fine-tune (real + synthetic)"
    def rmse(res):
        return next(r["rmse_m"] for r in res.rows if r["key"] == "SYNTH_PHY")

    assert rmse(mixed) != rmse(plain)
    assert plain.data["inputs"]["age_weighted_direction"] is True
    assert off.data["inputs"] == {"age_weighted_direction": False, "direction_range_std_m": None,
                                  "direction_range_rate_mps": None, "direction_ridge_m2": 0.1}


def test_bad_inputs_are_user_errors(runs):
    scn, rr = runs
    with pytest.raises(PhySynthError, match="unknown method"):
        StudyConfig(methods=("NOAUG", "kalman"))
    t = rr[2].trace
    no_truth = Trace(truth=Truth(t_s=t.truth.t_s, pos_enu_m=np.full_like(t.truth.pos_enu_m, np.nan),
                                 vel_enu_mps=t.truth.vel_enu_mps), uwb=t.uwb, anchors=t.anchors)
    with pytest.raises(PhySynthError, match="no ground truth"):
        run_tracking_study(rr[:2], StudyRun(label="x", trace=no_truth), config=StudyConfig(methods=("ls",)))
    no_uwb = Trace(truth=t.truth, uwb=Uwb(t_s=np.array([]), anchor=np.array([], np.int16), range_m=np.array([])),
                   anchors=t.anchors)
    with pytest.raises(PhySynthError, match="no UWB"):
        run_tracking_study([StudyRun(label="y", trace=no_uwb)], rr[2], config=StudyConfig(methods=("ls",)))


def test_a_run_that_is_trained_on_and_scored_is_refused(runs):
    """The same recording on both sides: the same samples, or the same source recording over overlapping
    times (a test run turned, or imported again); one recording's other times may be scored."""
    import dataclasses

    from physynth.studies.tracking_report import results_markdown
    from physynth.transform import turn_trace

    scn, rr = runs
    cfg = StudyConfig(methods=("ls",))
    with pytest.raises(PhySynthError, match="test run copy holds the same recording as training run run0"):
        run_tracking_study(rr[:2], StudyRun(label="copy", trace=rr[0].trace), config=cfg)
    recorded = dataclasses.replace(rr[0].trace, meta={**rr[0].trace.meta, "path": "/data/run0", "time_origin_s": 0.0})
    train = [StudyRun(label="run0", trace=recorded), rr[1]]
    turned = turn_trace(recorded, 1.0)
    with pytest.raises(PhySynthError, match="same recording"):
        run_tracking_study(train, StudyRun(label="turned", trace=turned), config=cfg)
    later = dataclasses.replace(turned, meta={**turned.meta, "time_origin_s": 1e6})  # another stretch of it
    res = run_tracking_study(train, StudyRun(label="later", trace=later), config=StudyConfig(methods=("ls", "ekf")))
    md = results_markdown(res)  # what applies to ls and ekf only: no Δ against NOAUG, no training schedule
    assert "Δ" not in md and "schedule" not in md and "SYNTH_PHY" not in md and "thread" not in md
    assert "| Method | RMSE (m) | RMSE 2D (m) | MAE (m) | P50 (m) | P95 (m) |\n" in md
    rows = [{**res.rows[0], "key": "NOAUG"}, {**res.rows[1], "delta_rmse_pct": 1.0}]
    config = {**res.config, "methods": ["NOAUG", "SYNTH_PHY", "ekf"]}
    md = results_markdown(dataclasses.replace(res, rows=rows, config=config))
    assert "Δ RMSE (%) |" in md and "| +1.0 |" in md and "Δ RMSE is relative to NOAUG" in md
    assert "- schedule: NOAUG 200 epochs" in md and "SYNTH_PHY 300 pre-training epochs" in md


def test_cli_shows_no_delta_column_without_noaug(runs, tmp_path, capsys):
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [rr[2].trace])
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls,ekf",
          "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert "Δ" not in out and "NOAUG" not in out and "errors in metres" in out


def _cli(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main([*map(str, args)])
    return exc.value.code, capsys.readouterr()


def test_cli_bad_input_exit_2_one_line(runs, tmp_path, capsys):
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    t = rr[2].trace
    no_truth = Trace(truth=Truth(t_s=t.truth.t_s, pos_enu_m=np.full_like(t.truth.pos_enu_m, np.nan),
                                 vel_enu_mps=t.truth.vel_enu_mps), uwb=t.uwb, anchors=t.anchors)
    bad_test = write_dataset(tmp_path / "bad", [no_truth])
    cases = [
        (["--train", train, "--test", bad_test, "--methods", "ls"], "no ground truth"),
        (["--train", train, "--test", train, "--methods", "NOAUG,kalman"], "unknown method"),
        (["--test", train, "--methods", "ls"], "--test needs --train"),
        (["--train", train, "--methods", "ls", "--protocol", "split"], "give --test"),
        (["--train", train, "--methods", "ls", "--protocol", "leave-one-layout-out"], "two or more anchor layouts"),
        (["--train", train, "--methods", "ls", "--protocol", "k-fold"], "--protocol must be one of"),
        (["--test", train, "--methods", "ls", "--protocol", "survey-only"], "needs --scenario"),
        (["--train", train, "--methods", "ls", "--tag-height", "nan"], "tag height must be a finite"),
        (["--train", train, "--methods", "ls", "--tag-height", "1", "--tag-height-std", "0"], "spread must be"),
        (["--train", train, "--methods", "ls", "--tag-height", "1", "--no-height"], "exclude each other"),
        (["--train", train, "--test", train, "--methods", "ls", "--seeds", "0"], "Invalid value for '--seeds'"),
        (["--train", train, "--test", train, "--methods", "ls"],
         "test run train[0] holds the same recording as training run train[0]"),
        (["--train", tmp_path / "missing", "--test", train, "--methods", "ls"], "does not exist"),
        (["--train", train, "--test", train, "--methods", "ls", "--finetune-synth-ratio", "-1"],
         "--finetune-synth-ratio must be in [0, 100]"),  # the option, not the parameter
        (["--train", train, "--test", train, "--methods", "ls", "--turn-test", "nan"], "--turn-test"),
        (["--train", train, "--test", train, "--methods", "ls", "--frame", "north"], "--frame must be one of"),
        (["--train", train, "--test", train, "--methods", "NOAUG", "--lr-schedule", "step"],
         "--lr-schedule must be constant or cosine"),
        (["--train", train, "--test", train, "--methods", "NOAUG", "--weight-average", "ema"],
         "--weight-average must be none or swa"),
        (["--train", train, "--test", train, "--methods", "NOAUG", "--ekf-prior", "kalman"],
         "--ekf-prior must be one of none, input, residual"),
        (["--train", train, "--test", train, "--methods", "ls", "--synth-nlos-spread", "0.5"],
         "--synth-nlos-spread only matters for SYNTH_PHY"),
        (["--train", train, "--test", train, "--methods", "ls", "--synth-layouts", "training"],
         "--synth-layouts only matters for SYNTH_PHY"),
        (["--train", train, "--test", train, "--methods", "SYNTH_PHY", "--synth-layouts", "random"],
         "--synth-layouts must be one of drawn, training"),
        (["--train", train, "--test", train, "--methods", "SYNTH_PHY", "--synth-nlos-spread", "-1"],
         "Invalid value for '--synth-nlos-spread'"),
    ]
    for args, needle in cases:
        code, out = _cli(capsys, "study", "tracking", *args, "--out", tmp_path / "o", "-q")
        assert code == 2, (args, out.err)
        assert needle in out.err and len(out.err.strip().splitlines()) == 1 and "Traceback" not in out.err


def test_cli_passes_the_pretraining_options_to_the_study(runs, tmp_path, capsys):
    pytest.importorskip("torch")
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [rr[2].trace])
    main(["study", "tracking", "--seeds", "1", "--train", str(train), "--test", str(test), "--methods", "SYNTH_PHY",
          "--scenario", str(save_scenario(scn, tmp_path / "s.yaml")), "--pretrain-epochs", "2",
          "--finetune-epochs", "2", "--n-synth", "2", "--synth-windows", "3", "--weight-average", "swa",
          "--ekf-prior", "input", "--synth-nlos-spread", "0.7", "--out", str(tmp_path / "out"), "-q"])
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    cfg = res["config"]
    assert cfg["synth_windows_per_trace"] == 3 and cfg["n_synth_traces"] == 2
    assert cfg["variation"]["nlos_log_std"] == 0.7 and cfg["variation"]["random_route_prob"] == 0.5
    assert cfg["net"] == {"weight_average": "swa"} and cfg["ekf_prior"] == "input"
    stages = res["data"]["notes"]["SYNTH_PHY.training"]
    assert stages[0]["windows"] == 6  # 2 traces x 3 windows
    # the prior the networks were given is scored too
    assert [r["key"] for r in res["rows"]] == ["SYNTH_PHY (synthetic only)", "SYNTH_PHY", "ekf prior"]
    assert all(np.isfinite(r["rmse_m"]) for r in res["rows"])
    assert [h["averaged_epochs"] for h in stages] == [1, 1]  # the second of 2 epochs, in each stage


def test_cli_classical_methods_write_results(runs, tmp_path, capsys, monkeypatch):
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [rr[2].trace])
    monkeypatch.setenv("COLUMNS", "80")
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls,ekf",
          "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert "results.json" in out
    rows = json.loads((tmp_path / "out" / "results.json").read_text())["rows"]
    assert [r["key"] for r in rows] == ["ls", "ekf"]
    # the table in 80 columns: every number whole on its method's line, the description under its name
    table = out.split("wrote ")[0].splitlines()
    assert max(len(line) for line in table) <= 80
    for r in rows:
        line = next(line for line in table if line.startswith(f"│ {r['key']} "))
        assert f"{r['rmse_m']:.3f}" in line and f"{r['p95_m']:.3f}" in line
    assert any("robust multilateration" in line for line in table)
    # the same test run turned by 120 degrees and mirrored: the same ranges, a path in another direction;
    # the classical trackers do not depend on the direction, so their errors are the same (to the
    # stopping tolerances of the iterative least-squares solver: 1e-8 m steps, well inside 1e-3)
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls,ekf",
          "--turn-test", "120", "--mirror-test", "--out", str(tmp_path / "turned"), "-q"])
    res = json.loads((tmp_path / "turned" / "results.json").read_text())
    assert res["data"]["test"][0]["label"].endswith("(turned 120 deg, mirrored)")
    m = np.asarray(res["data"]["test"][0]["isometry"]["matrix"])
    assert abs(np.linalg.det(m) + 1) < 1e-9 and abs(m[0, 0] - np.cos(np.radians(120))) < 1e-9
    for a, b in zip(rows, res["rows"], strict=True):
        assert abs(a["rmse_m"] - b["rmse_m"]) < 1e-3 * a["rmse_m"], (a, b)


def test_cli_route_frame_scores_a_turned_run_like_the_run(runs, tmp_path, capsys):
    """``--frame route``: a network sees a turned test run in the same route frame, so its error is the
    same (to float32 precision) as on the run itself; the default frame is ``turned``."""
    pytest.importorskip("torch")
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [rr[2].trace])
    base = ["study", "tracking", "--seeds", "1", "--train", str(train), "--test", str(test), "--methods", "NOAUG",
            "--epochs", "1",
            "-q"]
    main([*base, "--frame", "route", "--out", str(tmp_path / "plain")])
    main([*base, "--frame", "route", "--turn-test", "75", "--out", str(tmp_path / "turned")])
    a, b = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("plain", "turned"))
    assert a["config"]["route_frame"] and not a["config"]["random_isometry"]
    assert abs(a["rows"][0]["rmse_m"] - b["rows"][0]["rmse_m"]) < 1e-3 * a["rows"][0]["rmse_m"]
    assert "route frame (--frame route)" in (tmp_path / "plain" / "results.md").read_text()
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls", "-q",
          "--out", str(tmp_path / "default")])
    d = json.loads((tmp_path / "default" / "results.json").read_text())["config"]
    assert d["random_isometry"] and not d["route_frame"]
    assert "frame" not in (tmp_path / "default" / "results.md").read_text()  # no network ran: no frame to tell
    assert (tmp_path / "default" / "paths.png").stat().st_size > 1000  # one classical method alone is plotted


def test_without_torch_the_command_names_the_extra(tmp_path):
    import subprocess
    import sys

    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('no torch here')\n"
            "sys.meta_path.insert(0, Block())\n"
            "import physynth, physynth.track, physynth.studies.tracking\n"
            "from physynth.cli import main\n"
            f"main(['study', 'tracking', '--methods', 'NOAUG', '--out', {str(tmp_path / 'o')!r}])\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == ("physynth: error: a learned tracker needs torch, which is not installed: install "
                                   "the extra physynth[ml] (pip install 'physynth[ml]', or pip install -e '.[ml]' in "
                                   "a PhySynth clone)")


@pytest.mark.parametrize("name", ["epochs", "pretrain_epochs", "finetune_epochs", "n_synth_traces", "threads"])
@pytest.mark.parametrize("value", [0, -1])
def test_study_config_refuses_counts_below_one_naming_them(name, value):
    """0 epochs would train nothing and report an untrained network: refused like -1."""
    with pytest.raises(PhySynthError, match=rf"^{name} must be at least 1, got {value}$"):
        StudyConfig(**{name: value})


def test_an_ensemble_of_classical_trackers_only_is_refused():
    """The classical trackers draw no seed: an ensemble of them would run the same study K times."""
    with pytest.raises(PhySynthError, match=r"^ensemble 3 averages the networks .* methods ls, ekf train none"):
        StudyConfig(methods=("ls", "ekf"), ensemble=3)
    assert StudyConfig(methods=("ekf", "NOAUG"), ensemble=2).ensemble == 2


def test_default_runs_follow_physynth_shared_data(tmp_path, monkeypatch):
    from physynth.studies.tracking import default_data_root, hanyang_default_runs

    monkeypatch.setenv("PHYSYNTH_SHARED_DATA", str(tmp_path))
    assert default_data_root() == tmp_path
    with pytest.raises(PhySynthError, match=r"not found under .*hanyang-uwb.*set PHYSYNTH_SHARED_DATA"):
        hanyang_default_runs()


def test_bad_network_settings_fail_before_any_work():
    with pytest.raises(PhySynthError, match="lr_schedule must be constant or cosine"):
        StudyConfig(methods=("SYNTH_PHY",), net={"lr_schedule": "step"})
    with pytest.raises(PhySynthError, match="unknown network setting"):
        StudyConfig(methods=("NOAUG",), net={"hiden": 8})
    assert StudyConfig(methods=("SYNTH_PHY",), net={"lr_schedule": "cosine"}).net == {"lr_schedule": "cosine"}


def test_rmse_over_the_trusted_truth_leaves_out_what_the_recording_flags(runs, tmp_path):
    """A test run whose truth is displaced by 5 m inside a flagged span (a truth that errs): the RMSE over
    every step grows, the RMSE over the trusted steps is that of the same run with a correct truth, to
    the last digit (the estimates do not depend on the truth); without spans there is no such figure."""
    import dataclasses

    from physynth.records import TRUTH_UNTRUSTED_KEY

    scn, rr = runs
    test = rr[2].trace
    t0, t1 = float(test.truth.t_s[0]), float(test.truth.t_s[-1])
    span = [t0 + 0.3 * (t1 - t0), t0 + 0.5 * (t1 - t0)]
    inside = (test.truth.t_s >= span[0]) & (test.truth.t_s < span[1])
    pos = test.truth.pos_enu_m.copy()
    pos[inside, 0] += 5.0
    meta = {**test.meta, TRUTH_UNTRUSTED_KEY: [span]}
    wrong = dataclasses.replace(test, truth=dataclasses.replace(test.truth, pos_enu_m=pos), meta=meta)
    right = dataclasses.replace(test, meta=meta)
    cfg = StudyConfig(**{**TINY, "methods": ("ekf",)})
    rows, res_wrong = {}, None
    for name, tr in (("wrong", wrong), ("right", right), ("plain", test)):
        res = run_tracking_study(rr[:2], StudyRun(label="t", trace=tr), scenario=scn, config=cfg)
        rows[name] = next(r for r in res.rows if r["key"] == "ekf")
        res_wrong = res if name == "wrong" else res_wrong
    assert rows["wrong"]["rmse_m"] > 2.0 > 5 * rows["right"]["rmse_m"]
    assert rows["wrong"]["rmse_trusted_m"] == rows["right"]["rmse_trusted_m"] < rows["right"]["rmse_m"] + 0.05
    assert rows["plain"]["rmse_trusted_m"] is None
    with np.load(write_results(res_wrong, tmp_path)["estimates"]) as est:  # the flagged steps, as scored
        inside = (est["t_s"] >= span[0]) & (est["t_s"] < span[1])
        np.testing.assert_array_equal(est["trusted"], ~inside)
        ok = est["scored"] & est["trusted"]
        err = est["estimate/ekf"][ok] - est["truth_enu_m"][ok]
        assert np.sqrt(np.mean(np.sum(err**2, axis=1))) == pytest.approx(rows["wrong"]["rmse_trusted_m"], rel=1e-9)


def test_training_on_the_trusted_truth_ignores_what_the_recording_flags(runs):
    """Training runs whose truth is displaced by 5 m inside a flagged span: the ``ekf`` fitted on them
    (its range std from the training residuals, after the lag fit) is the one fitted on the correct truth when the study
    trains on the trusted truth only, to the last digit, and far off when it trains on every step. The
    network inputs mark those steps as without truth (no loss there)."""
    import dataclasses

    from physynth.records import TRUTH_UNTRUSTED_KEY
    from physynth.track.inputs import track_input

    scn, rr = runs

    def flagged(run, shift_m):
        tr = run.trace
        t0, t1 = float(tr.truth.t_s[0]), float(tr.truth.t_s[-1])
        span = [t0 + 0.2 * (t1 - t0), t0 + 0.6 * (t1 - t0)]
        pos = tr.truth.pos_enu_m.copy()
        pos[(tr.truth.t_s >= span[0]) & (tr.truth.t_s < span[1]), 0] += shift_m
        return dataclasses.replace(run, trace=dataclasses.replace(
            tr, truth=dataclasses.replace(tr.truth, pos_enu_m=pos), meta={**tr.meta, TRUTH_UNTRUSTED_KEY: [span]}))

    inp = track_input(flagged(rr[0], 5.0).trace, trusted_truth_only=True)
    lo, hi = flagged(rr[0], 5.0).trace.meta[TRUTH_UNTRUSTED_KEY][0]
    unknown = ~np.all(np.isfinite(inp.pos_rel_m), axis=1)
    np.testing.assert_array_equal(unknown, (inp.t_s >= lo) & (inp.t_s < hi))
    assert not np.any(~np.all(np.isfinite(track_input(flagged(rr[0], 5.0).trace).pos_rel_m), axis=1))

    std = {}
    for shift in (0.0, 5.0):
        for trusted in (False, True):
            cfg = StudyConfig(**{**TINY, "methods": ("ekf",), "train_trusted_truth": trusted})
            res = run_tracking_study([flagged(r, shift) for r in rr[:2]], rr[2], scenario=scn, config=cfg)
            std[shift, trusted] = res.data["notes"]["ekf_range_std_m"]
    assert std[5.0, True] == std[0.0, True]
    assert std[5.0, False] > 1.5 * std[0.0, False]  # robust (MAD): 40 % of the rows 5 m off nearly double it


def test_a_seed_ensemble_scores_the_mean_of_the_seeds_studies(runs, tmp_path):
    """``ensemble=2`` is the two studies of seeds 3 and 4 averaged step by step: each member's rows are those
    studies' rows to the last digit, and every row of the ensemble scores the mean of their estimates."""
    from physynth.track.scoring import error_stats

    scn, rr = runs
    base = {**TINY, "methods": ("NOAUG", "ekf")}
    single = [run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**base, seed=s)) for s in (3, 4)]
    ens = run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**base, seed=3, ensemble=2))
    assert ens.data["ensemble"]["seeds"] == [3, 4] and ens.config["ensemble"] == 2
    def scores(rows):  # the rows without their timings
        return [{k: v for k, v in r.items() if k not in ("fit_s", "predict_s")} for r in rows]

    assert [scores(r) for r in ens.data["ensemble"]["member_rows"]] == [scores(s.rows) for s in single]
    truth, ok = ens.test_input.pos_enu_m, ens.test_input.eval_mask()
    for row in ens.rows:
        mean = np.mean([s.estimates[row["key"]] for s in single], axis=0)
        np.testing.assert_array_equal(ens.estimates[row["key"]], mean)
        assert row["rmse_m"] == error_stats(mean, truth, ok)["rmse_m"]
    # the same members trained at once in two processes: the same numbers, and every member's progress
    said: list[str] = []
    par = run_tracking_study(rr[:2], rr[2], scenario=scn, config=StudyConfig(**base, seed=3, ensemble=2, jobs=2),
                             progress=said.append)
    assert [scores(r) for r in par.data["ensemble"]["member_rows"]] == [scores(s.rows) for s in single]
    for row in ens.rows:
        np.testing.assert_array_equal(par.estimates[row["key"]], ens.estimates[row["key"]])
    assert {m.split(":")[0] for m in said} == {"ensemble member 1/2 (seed 3)", "ensemble member 2/2 (seed 4)"}
    # the members' CPU time counted: about the work of the members trained one after the other (CPU time,
    # not wall time, so a loaded machine does not change it; this process alone does a small part of it)
    assert par.data["cpu_time_s"] > 0.5 * ens.data["cpu_time_s"]
    noaug = [next(r["rmse_m"] for r in s.rows if r["key"] == "NOAUG") for s in single]
    assert noaug[0] != noaug[1]  # the members differ: an ensemble of one network twice would prove nothing
    md = write_results(ens, tmp_path)["md"].read_text()
    assert "seed ensemble: every row scores the mean of 2 studies' estimates (seeds 3, 4" in md
    with pytest.raises(PhySynthError, match="ensemble must be at least 1"):
        StudyConfig(**base, ensemble=0)
    with pytest.raises(PhySynthError, match="it needs ensemble >= 2"):
        StudyConfig(**base, jobs=2)


def test_an_ensemble_member_that_dies_without_a_word_is_an_error():
    """A member process that ends without its result (killed, out of memory) is one clear error, not a hang."""
    import multiprocessing as mp
    import os

    from physynth.studies.tracking import next_member_message

    ctx = mp.get_context("spawn")
    proc = ctx.Process(target=os._exit, args=(3,))
    proc.start()
    proc.join()
    with pytest.raises(PhySynthError, match=r"ensemble member 1 \(seed 7\) ended without a result \(exit code 3\)"):
        next_member_message(ctx.Queue(), {0: proc}, [StudyConfig(**TINY, seed=7)])


def test_every_test_run_is_saved_and_plotted_with_its_own_rmse(runs, tmp_path):
    """Two test runs: estimates.npz holds both (``run`` tells them apart), so every row's pooled RMSE and
    each run's own RMSE are recomputed from it; the figure has a column per run."""
    from physynth.track.scoring import error_stats

    scn, rr = runs
    res = run_tracking_study(rr[:1], rr[1:], scenario=scn, config=StudyConfig(**{**TINY, "methods": ("ls", "ekf")}))
    files = write_results(res, tmp_path)
    rows = json.loads(files["json"].read_text())["rows"]
    with np.load(files["estimates"]) as est:
        assert list(est["run_labels"]) == ["run1", "run2"]
        assert est["t_s"].size == sum(i.n_steps for i in res.test_inputs) == est["run"].size
        for row in rows:
            st = error_stats(est["estimate/" + row["key"]], est["truth_enu_m"], est["scored"])
            assert st["rmse_m"] == pytest.approx(row["rmse_m"], rel=1e-9) and st["n_steps"] == row["n_steps"]
            for j, inp in enumerate(res.test_inputs):
                one = est["run"] == j
                own = error_stats(est["estimate/" + row["key"]][one], est["truth_enu_m"][one], est["scored"][one])
                assert own["rmse_m"] == pytest.approx(
                    error_stats(res.estimates_per_test[row["key"]][j], inp.pos_enu_m, inp.eval_mask())["rmse_m"])
    assert files["figure"].stat().st_size > 1000


def test_missing_estimates_and_truth_after_the_last_range_are_reported(runs, tmp_path, capsys, monkeypatch):
    """A test run whose ranges stop 6 s before its truth (an uncropped import): a warning line (stderr and
    results.md); an ls without an estimate on its first 50 steps says how many steps its row leaves out,
    in results.md and the printed table."""
    import dataclasses

    from physynth.track.trackers.ls import LsTracker

    predict = LsTracker.predict

    def gappy(self, inp):
        est = predict(self, inp).copy()
        est[np.flatnonzero(inp.eval_mask())[:50]] = np.nan
        return est

    monkeypatch.setattr(LsTracker, "predict", gappy)
    scn, rr = runs
    t = rr[2].trace
    late = t.uwb.t_s > float(t.truth.t_s[-1]) - 6.0
    cut = dataclasses.replace(t, uwb=dataclasses.replace(t.uwb, range_m=np.where(late, np.nan, t.uwb.range_m),
                                                         reason=None))
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [cut])
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls,ekf",
          "--out", str(tmp_path / "out")])
    out = capsys.readouterr()
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(res["data"]["warnings"]) == 1 and "after its last UWB range" in res["data"]["warnings"][0]
    warned = [line for line in out.err.splitlines() if line.startswith("warning:")]
    assert len(warned) == 1 and "after its last UWB range" in warned[0]
    md = (tmp_path / "out" / "results.md").read_text()
    assert "Warning: test run" in md
    missing = [r for r in res["rows"] if r["n_missing"]]
    assert [r["key"] for r in missing] == ["ls"] and missing[0]["n_missing"] == 50
    for r in missing:
        text = f"no estimate on {r['n_missing']} of {r['n_missing'] + r['n_steps']} scored steps"
        assert text in md and text.split(" scored")[0] in out.out.replace("\n", " ")


def test_cli_refuses_no_methods_and_options_without_effect(runs, tmp_path, capsys):
    """``--methods ""`` is no method (not all of them); --frame and --ensemble set up the networks only."""
    scn, rr = runs
    train = write_dataset(tmp_path / "train", [r.trace for r in rr[:2]])
    test = write_dataset(tmp_path / "test", [rr[2].trace])
    cases = [(["--methods", ""], "no method to run"),
             (["--methods", "ls,ekf", "--frame", "route"], "--frame only matters for NOAUG"),
             (["--methods", "ls", "--ensemble", "2"], "--ensemble only matters for NOAUG")]
    for args, needle in cases:
        code, out = _cli(capsys, "study", "tracking", "--seeds", "1", "--train", train, "--test", test, *args,
                         "--quick", "--out", tmp_path / "o", "-q")
        assert code == 2, (args, out.err)
        assert needle in out.err and len(out.err.strip().splitlines()) == 1 and "Traceback" not in out.err
    assert not (tmp_path / "o" / "results.json").exists()
