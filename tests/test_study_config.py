"""The tracking study's configuration file (``physynth study tracking --config``): read, checked, merged
under the command's options."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from track_helpers import site_scenario  # noqa: E402

from physynth.cli import main  # noqa: E402
from physynth.errors import PhySynthError  # noqa: E402
from physynth.generate import generate_trace  # noqa: E402
from physynth.io import write_dataset  # noqa: E402
from physynth.studies.tracking_config import (  # noqa: E402
    STUDY_LAYOUTS,
    STUDY_VARIATION,
    StudyConfig,
    quick_config,
    read_study_settings,
)


def _file(tmp_path, text: str):
    p = tmp_path / "study.yaml"
    p.write_text(text, encoding="utf-8")
    return p


def test_settings_are_read_and_the_variation_changes_the_study_default(tmp_path):
    s = read_study_settings(_file(tmp_path, "finetune_lr: 2.0e-4\nmethods: [ls, ekf]\nnet: {lr_schedule: cosine}\n"
                                            "variation: {random_route_prob: 0.25, "
                                            "layout_distribution: {anchor_count: [4, 8]}}\n"))
    assert s["finetune_lr"] == 2e-4 and s["methods"] == ("ls", "ekf") and s["net"] == {"lr_schedule": "cosine"}
    v = s["variation"]
    assert v.random_route_prob == 0.25 and v.path_lateral_std_m == STUDY_VARIATION.path_lateral_std_m
    assert v.layout_distribution.anchor_count == [4, 8]
    assert v.layout_distribution.footprint_m == STUDY_LAYOUTS.footprint_m  # the rest of the study's layouts
    cfg = quick_config(**s)
    assert cfg.finetune_lr == 2e-4 and cfg.epochs == quick_config().epochs  # the file's, then the schedule's
    assert StudyConfig(**read_study_settings(_file(tmp_path, "variation: {layout_distribution: null}\n"))
                       ).variation.layout_distribution is None  # the training layouts, jittered
    assert read_study_settings(_file(tmp_path, "")) == {}


@pytest.mark.parametrize(("text", "needle"), [
    ("epochs: 0\n", "epochs must be at least 1"),
    ("finetune_lr: 1e-4\nwarmup: 3\n", "unknown setting(s) warmup"),
    ("quick: true\n", "unknown setting(s) quick"),
    ("- epochs\n", "a mapping of study settings expected"),
    ("variation: {random_route_prob: 2}\n", "variation: random_route_prob"),
    ("variation: 3\n", "variation must be a mapping"),
    ("net: {depth: 3}\n", "unknown network setting(s) depth"),
    ("methods: [NOAUG, kalman]\n", "unknown method(s) kalman"),
    ("epochs: [1\n", "not YAML"),
])
def test_bad_files_are_refused_naming_the_setting(tmp_path, text, needle):
    with pytest.raises(PhySynthError, match="study configuration") as e:
        read_study_settings(_file(tmp_path, text))
    assert needle in str(e.value)
    with pytest.raises(PhySynthError, match="cannot read it"):
        read_study_settings(tmp_path / "missing.yaml")


def _cli(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main([*map(str, args)])
    return exc.value.code, capsys.readouterr()


def test_the_command_takes_the_file_and_its_options_win(tmp_path, capsys):
    scn = site_scenario(noise_m=0.1)
    traces = [generate_trace(scn, i, 11) for i in range(3)]
    train = write_dataset(tmp_path / "train", traces[:2])
    test = write_dataset(tmp_path / "test", traces[2:])
    cfg = _file(tmp_path, "methods: [ls]\nepochs: 7\n")
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--config", str(cfg), "-q",
          "--out", str(tmp_path / "file")])
    res = json.loads((tmp_path / "file" / "results.json").read_text())
    assert [r["key"] for r in res["rows"]] == ["ls"] and res["config"]["epochs"] == 7
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--config", str(cfg), "-q",
          "--methods", "ekf", "--out", str(tmp_path / "flag")])
    res = json.loads((tmp_path / "flag" / "results.json").read_text())
    assert [r["key"] for r in res["rows"]] == ["ekf"] and res["config"]["epochs"] == 7
    code, out = _cli(capsys, "study", "tracking", "--train", train, "--test", test, "--config",
                     _file(tmp_path, "epochs: 0\n"), "--out", tmp_path / "bad")
    assert code == 2 and "epochs must be at least 1" in out.err
    assert len(out.err.strip().splitlines()) == 1 and "Traceback" not in out.err
    assert not (tmp_path / "bad" / "results.json").exists()
