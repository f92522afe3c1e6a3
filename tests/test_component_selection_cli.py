"""``calibrate --select-components`` from the command line (physynth.calibrate.held_out): the per-component
section it writes and the errors it refuses with. Moved unchanged from test_component_selection.py (the
same evidence, through the command, on two synthetic walk-hanyang runs: one-run folds, no run-to-run spread
to take out), so that the two halves can run on two pytest-xdist workers.
"""

from __future__ import annotations

import json

import pytest
from helpers import run_cli

from physynth.calibrate.held_out import DROP_RULE
from physynth.io.scenario_file import load_scenario


@pytest.fixture(scope="module")
def two_run_dataset(tmp_path_factory):
    from physynth.cli import main

    ds = tmp_path_factory.mktemp("sel") / "walks"
    with pytest.raises(SystemExit) as exc:
        main(["generate", "--scenario", "walk-hanyang", "-n", "2", "--seed", "7", "--out", str(ds), "--quiet"])
        raise SystemExit(0)
    assert not exc.value.code
    return ds


def test_the_option_writes_the_per_component_section(two_run_dataset, tmp_path, capsys):
    code, out, err = run_cli(capsys, "calibrate", two_run_dataset, "--out", tmp_path / "s.yaml", "--report",
                             tmp_path / "r.json", "--select-components", "evidence", "--evidence-traces", 1)
    assert code == 0, err
    rep = json.loads((tmp_path / "r.json").read_text())
    sel = rep["component_selection"]
    assert sel["n_traces"] == 1 and len(sel["held_out_runs"]) == 2 and sel["rule"] == DROP_RULE
    comps = rep["components"]
    assert "held_out" not in comps["geometry"] and comps["geometry"]["fitted"]  # not an optional component
    assert comps["ranging"]["held_out"]["skipped"]  # one-run folds: no run-to-run spread to take out
    for name in ("timing", "antenna_sway", "tag_nlos"):
        ev = comps[name]["held_out"]
        assert comps[name]["fitted"] and len(ev["per_run"]) == 2 and ev["combined_gain"] is not None
        assert comps[name]["selected"] == (name not in sel["taken_out"]) == (ev["decision"] != "drop")
    assert comps["link_budget"]["fitted"] is False and comps["link_budget"]["why"]
    assert comps["link_budget"]["held_out"]["decision"] == "no evidence"
    # the summary's table: every optional component with its gain and what the selection did
    assert "components by held-out evidence" in out
    for name in ("timing", "antenna_sway", "tag_nlos"):
        line = next(ln for ln in out.splitlines() if ln.startswith(name + " "))
        assert ("taken out" in line) == (name in sel["taken_out"])
    scn = load_scenario(tmp_path / "s.yaml")
    if "tag_nlos" in sel["taken_out"]:
        assert scn.uwb.tag_nlos_prob == 0.0


@pytest.mark.parametrize(("args", "needle"), [
    (["--select-components", "best"], "--select-components"),
    (["--select-components", "evidence", "--evidence-traces", "0"], "--evidence-traces"),
])
def test_bad_option_values_exit_2_with_one_line(two_run_dataset, tmp_path, capsys, args, needle):
    code, _, err = run_cli(capsys, "calibrate", two_run_dataset, "--out", tmp_path / "s.yaml", *args)
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "s.yaml").exists()


def test_one_run_with_evidence_exits_2_naming_the_option(tmp_path, capsys):
    code, _, _ = run_cli(capsys, "generate", "--scenario", "walk-hanyang", "-n", 1, "--seed", 3, "--out",
                         tmp_path / "one", "--quiet")
    assert code == 0
    code, _, err = run_cli(capsys, "calibrate", tmp_path / "one", "--out", tmp_path / "s.yaml",
                           "--select-components", "evidence", "--quiet")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "--select-components evidence needs at least 2 runs" in err
