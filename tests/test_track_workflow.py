"""``physynth.workflows.tracking_study``: the tracking study called from Python (tiny sizes), its result, its
files, and errors that name its parameters, never the command line's options."""

from __future__ import annotations

import json

import pytest
from track_helpers import site_scenario

from physynth.errors import OutputExistsError
from physynth.generate import generate_trace
from physynth.io import write_dataset
from physynth.studies.tracking_setup import TrackingArgumentError, TrackingStudyRun
from physynth.workflows import tracking_study


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    scn = site_scenario(noise_m=0.05)
    traces = [generate_trace(scn, i, 5) for i in range(3)]
    root = tmp_path_factory.mktemp("runs")
    return write_dataset(root / "train", traces[:2]), write_dataset(root / "test", traces[2:])


def test_a_classical_study_from_python(datasets, tmp_path):
    train, test = datasets
    lines = []
    run = tracking_study(tmp_path / "out", train=[train], test=[test], methods=["ls", "ekf"], seeds=1,
                         progress=lines.append)
    assert isinstance(run, TrackingStudyRun) and run.single and run.result.protocol == "split"
    assert set(run.files) >= {"json", "md"} and all(p.exists() for p in run.files.values())
    data = json.loads(run.files["json"].read_text())
    assert [r["key"] for r in data["rows"]][:2] == ["ls", "ekf"] and "per_run" in data["protocol"]
    assert lines and all(isinstance(line, str) for line in lines)
    with pytest.raises(OutputExistsError):  # the output is checked before any work
        tracking_study(tmp_path / "out", train=[train], test=[test], methods=["ls", "ekf"], seeds=1)
    again = tracking_study(tmp_path / "out", train=[train], test=[test], methods=["ls", "ekf"], seeds=2,
                           turn_test=90.0, overwrite=True)
    assert again.result.seeds == [0]  # the classical trackers draw no seed: one study
    assert all("(turned 90 deg)" in i.label for i in again.result.studies[0].test_inputs)


def test_a_network_with_flat_window_settings(datasets, tmp_path):
    """A network's settings by name (the window's too) reach the study's configuration."""
    pytest.importorskip("torch")
    train, test = datasets
    net = {"hidden": 8, "heads": 2, "window_steps": 12, "stride_steps": 6, "burn_in_steps": 2}
    run = tracking_study(tmp_path / "out", train=[train], test=[test], methods=["NOAUG"], seeds=1,
                         settings={"epochs": 1, "threads": 1, "net": net}, frame="compass")
    cfg = run.result.studies[0].config
    assert cfg["net"] == net and cfg["random_isometry"] is False and cfg["route_frame"] is False


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"methods": ["ls", "ekf"], "settings": {"epochs": 3}},
     "epochs only matters for NOAUG, AUG_GAN or bilstm, which methods leaves out (ls,ekf): add one or leave "
     "epochs out"),
    ({"methods": ["ls"], "frame": "route"}, "frame only matters for NOAUG, AUG_GAN, SYNTH_PHY or bilstm"),
    ({"frame": "sideways"}, "frame must be one of route, turned, compass, got 'sideways'"),
    ({"no_height": True, "tag_height": 1.0}, "no_height and tag_height exclude each other"),
    ({"methods": ["ls"], "protocol": "survey-only"}, "protocol survey-only needs scenario"),
    ({"methods": ["ls"], "settings": {"seed": 3}}, "settings: seed not a study setting"),
])
def test_errors_name_the_parameters(tmp_path, kwargs, message):
    with pytest.raises(TrackingArgumentError) as exc:
        tracking_study(tmp_path / "out", **kwargs)
    assert message in str(exc.value) and "--" not in str(exc.value)
    assert "--methods" in exc.value.worded({"methods": "--methods"}) or "methods" not in exc.value.template
    assert not (tmp_path / "out").exists()


def test_run_errors_name_the_parameters(datasets, tmp_path):
    train, test = datasets
    with pytest.raises(TrackingArgumentError, match="^test needs train"):
        tracking_study(tmp_path / "a", test=[test], methods=["ls"])
    with pytest.raises(TrackingArgumentError, match="^jobs 2 runs several studies at once.*give seeds N"):
        tracking_study(tmp_path / "b", train=[train], test=[test], methods=["ls"], seeds=1, jobs=2)
