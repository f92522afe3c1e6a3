"""What a validation report says beside its tables (report.md, report.html, the terminal summary): an
anchor subset, real truth running on past its last UWB range, a 5-95 % band with too few synthetic
traces, options that do not apply."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from test_validate import _real_meta, _run, _scenario_dict

from physynth.generate import generate_trace
from physynth.io import write_dataset
from physynth.scenario import scenario_from_dict


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """test_validate's fixture data: a 'real' dataset, a synthetic one (three traces), a.yaml."""
    from test_validate import data as make

    return make.__wrapped__(tmp_path_factory)


def _files(out) -> tuple[dict, str, str]:
    return (json.loads((out / "report.json").read_text()), (out / "report.md").read_text(),
            (out / "report.html").read_text())


def test_anchor_subset_is_said_in_the_summary_markdown_and_html(data, tmp_path, capsys):
    out = tmp_path / "rep"
    assert _run(["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"), "--anchors", "A3",
                 "--no-figures", "--out", str(out)]) == 0
    said = " ".join(capsys.readouterr().out.split())
    rep, md, page = _files(out)
    assert rep["inputs"]["anchor_subset"] == ["A3"]
    for text in (said, md, page):
        assert "Anchor subset: the synthetic traces use only A3 (1 of the 3 anchors)" in " ".join(text.split())


def test_truth_past_the_last_uwb_row_is_warned_in_one_line(data, tmp_path, capsys):
    """As a Hanyang run imported without --crop-to-uwb: the truth runs on after the last range, and those
    seconds count as an outage. The report and the summary say so; the CLI names the import option."""
    import dataclasses

    from physynth.io import read_dataset
    from physynth.validate.compare import TRUTH_PAST_UWB_S

    tr = read_dataset(data / "real").traces[0]
    keep = tr.uwb.t_s < tr.truth.t_s[-1] - TRUTH_PAST_UWB_S - 3.0
    uwb = dataclasses.replace(tr.uwb, **{f.name: getattr(tr.uwb, f.name)[keep] for f in dataclasses.fields(tr.uwb)
                                         if isinstance(getattr(tr.uwb, f.name), np.ndarray)})
    write_dataset(tmp_path / "uncropped", [dataclasses.replace(tr, uwb=uwb)], meta=_real_meta())
    out = tmp_path / "rep"
    assert _run(["validate", "--real", str(tmp_path / "uncropped"), "--synthetic", str(data / "synth"),
                 "--no-figures", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    rep, md, page = _files(out)
    assert rep["inputs"]["real"]["truth_past_last_uwb_s"] > TRUTH_PAST_UWB_S + 2.9
    for text in (said, md, page):
        assert "Warning: the real truth runs on" in text and "past its last UWB row" in " ".join(text.split())
    assert "physynth import hanyang --crop-to-uwb" in " ".join(said.split())
    assert "--crop-to-uwb" not in md + page
    assert _run(["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"),
                 "--no-figures", "--out", str(tmp_path / "cropped")]) == 0
    assert "Warning: the real truth" not in capsys.readouterr().out


def test_too_few_synthetic_traces_give_no_band_and_say_why(data, tmp_path, capsys):
    from physynth.validate.compare import MIN_BAND_TRACES

    out = tmp_path / "rep"
    assert _run(["validate", "--real", str(data / "real"), "--scenario", str(data / "a.yaml"), "-n", "2",
                 "--seed", "1", "--no-figures", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    rep, md, page = _files(out)
    c = rep["comparison"]["uwb_ge1_frac"]
    assert c["band_5_95"] is None and c["real_in_band"] is None and c["n_traces_in_band"] == 2
    note = "Synth 5–95 % band not available: 2 synthetic trace(s)"
    for text in (said, md, page):
        assert note in " ".join(text.split()) and f"the {MIN_BAND_TRACES} a band needs" in " ".join(text.split())
    assert "OUT" not in said and "band —" in said
    assert "| NO |" not in md


def test_budget_message_is_about_memory_and_time_not_disk(data, tmp_path, capsys):
    """validate streams the synthetic traces and writes none: its budget message speaks of samples to
    generate and reduce (time) and of one trace's memory, never of disk; generate's is unchanged."""
    from physynth.bounds import check_budget
    from physynth.errors import BudgetError
    from physynth.io.scenario_file import load_scenario

    assert _run(["validate", "--real", str(data / "real"), "--scenario", str(data / "a.yaml"), "-n", "100000000",
                 "--seed", "1", "--no-figures", "--out", str(tmp_path / "rep")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "on disk" not in err and "output budget" not in err
    assert "samples to generate and reduce (validate writes none of them" in err and "--force" in err
    with pytest.raises(BudgetError, match="on disk; the output budget"):
        check_budget(load_scenario(str(data / "a.yaml")), 100000000)


@pytest.mark.parametrize("extra, needle", [
    (["-n", "3"], "-n needs --scenario"), (["--seed", "3"], "--seed needs --scenario")])
def test_options_for_generated_traces_are_refused_with_a_synthetic_dataset(data, tmp_path, capsys, extra, needle):
    assert _run(["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"), *extra,
                 "--no-figures", "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep" / "report.json").exists()


@pytest.mark.parametrize("extra, needle", [
    (["--anchors", "A1"], "an anchor subset does not apply"),
    (["--all-truth"], "comparing the ranges also where the truth errs does not apply")])
def test_uwb_options_are_refused_on_an_imu_only_real_dataset(data, tmp_path, capsys, extra, needle):
    imu_only = scenario_from_dict(_scenario_dict(anchors=[]), "imu")
    write_dataset(tmp_path / "imu", [generate_trace(imu_only, 0, 5)], meta=_real_meta())
    assert _run(["validate", "--real", str(tmp_path / "imu"), "--synthetic", str(tmp_path / "imu"), *extra,
                 "--no-figures", "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert "IMU-only recording (no UWB)" in err and needle in err and len(err.strip().splitlines()) == 1


def test_imu_only_report_has_inputs_citation_allan_ratios_and_scenario(tmp_path, capsys):
    """As a BROAD trial validated against a scenario: the IMU report says what was compared, cites the
    data (CC BY), shows the Allan ratios and keeps the scenario, as docs/validation.md promises."""
    imu_only = _scenario_dict(anchors=[])
    write_dataset(tmp_path / "imu", [generate_trace(scenario_from_dict(imu_only, "imu"), 0, 5)],
                  meta={"kind": "real", "source": "broad"})
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(imu_only), encoding="utf-8")
    out = tmp_path / "rep"
    assert _run(["validate", "--real", str(tmp_path / "imu"), "--scenario", str(tmp_path / "s.yaml"), "-n", "3",
                 "--seed", "4", "--no-figures", "--out", str(out), "--quiet"]) == 0
    rep, md, page = _files(out)
    assert rep["kind"] == "imu"
    for text in (md, page):
        for needle in (f"Real: {tmp_path / 'imu'}", "s.yaml", "root seed 4", "3 trace(s)", "physynth 0.",
                       "BROAD", "CC BY 4.0", "Allan deviation of the error", "imu_allan_ratio"):
            assert needle in text, needle
    assert (out / "scenario.yaml").is_file()
