"""The command line: exit codes, one-line errors, JSON output, progress-free quiet mode."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from physynth.cli import main
from physynth.evaluate.metrics import METRIC_KEYS, compute_metrics
from physynth.io import read_dataset
from physynth.io.scenario_file import load_scenario
from physynth.scenario import scenario_to_dict


def run(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main([*map(str, args)])
        raise SystemExit(0)
    out = capsys.readouterr()
    return exc.value.code or 0, out.out, out.err


def test_generate_then_inspect_json(tmp_path, capsys):
    code, out, _ = run(capsys, "generate", "-n", 2, "--seed", 5, "--out", tmp_path / "ds", "--quiet")
    assert code == 0
    code, out, _ = run(capsys, "inspect", tmp_path / "ds", "--json")
    assert code == 0
    d = json.loads(out)
    assert set(d) == set(METRIC_KEYS) | {"per_anchor"}
    assert len(d["imu_std_mps2"]) == 3
    m = compute_metrics(read_dataset(tmp_path / "ds").traces)
    assert d["uwb_ge1_frac"] == pytest.approx(m.uwb_ge1_frac)
    assert set(d["per_anchor"]) == {"A101", "A103", "A105", "A106", "A107", "A108"}
    code, out, _ = run(capsys, "inspect", tmp_path / "ds")
    assert code == 0 and "uwb_ge1_frac" in out


def test_generate_refuses_to_overwrite(tmp_path, capsys):
    assert run(capsys, "generate", "-n", 1, "--out", tmp_path / "ds", "-q")[0] == 0
    code, _, err = run(capsys, "generate", "-n", 1, "--out", tmp_path / "ds", "-q")
    assert code == 2 and err.count("\n") == 1 and "already exists" in err
    assert run(capsys, "generate", "-n", 1, "--out", tmp_path / "ds", "-q", "--overwrite")[0] == 0


@pytest.mark.parametrize(("args", "needle"), [
    (["generate", "-n", "0"], "greater than or equal to 1"),
    (["generate", "--scenario", "no-such-preset"], "unknown scenario"),
    (["generate", "-n", "many"], "--n-traces"),
    (["generate", "--frobnicate"], "No such option"),
    (["inspect", "/nonexistent/dataset"], "does not exist"),
    (["scenario", "show", "nope"], "unknown scenario"),
])
def test_user_mistakes_exit_2_with_one_line(tmp_path, capsys, args, needle):
    code, out, err = run(capsys, *args)
    assert code == 2
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


def test_bad_scenario_file(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    d = scenario_to_dict(load_scenario("cablecar-descending"))
    d["channel"]["los_std_m"] = -1
    bad.write_text(yaml.safe_dump(d))
    code, _, err = run(capsys, "generate", "--scenario", bad, "--out", tmp_path / "x", "-q")
    assert code == 2 and "channel.los_std_m" in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


def test_scenarios_and_show(capsys):
    code, out, _ = run(capsys, "scenarios")
    assert code == 0 and "cablecar-descending" in out and "cablecar-ascending" in out
    code, out, _ = run(capsys, "scenario", "show", "cablecar-ascending")
    assert code == 0
    assert yaml.safe_load(out)["path"]["reverse"] is True


def test_no_arguments_prints_help(capsys):
    code, out, _ = run(capsys)
    assert code == 0 and "generate" in out and "inspect" in out


def _command_paths(groups: bool) -> list[list[str]]:
    """The argument paths of physynth and every command group under it (``groups``), or of every command,
    found in the command tree."""
    import typer

    from physynth.cli import app, register_commands

    register_commands()
    found, todo = [], [([], typer.main.get_command(app))]
    while todo:
        path, cmd = todo.pop()
        is_group = hasattr(cmd, "commands")
        if is_group == groups:
            found.append(path)
        if is_group:
            todo += [([*path, name], sub) for name, sub in cmd.commands.items()]
    return found


def _groups() -> list[list[str]]:
    return _command_paths(groups=True)


def test_every_group_without_arguments_prints_its_help_and_exits_0(capsys):
    groups = _groups()
    assert [] in groups and ["import"] in groups and ["study"] in groups and ["scenario"] in groups
    for path in groups:
        code, out, err = run(capsys, *path)
        assert (code, err) == (0, ""), path
        assert out == run(capsys, *path, "--help")[1], path  # the same help, on stdout


def test_console_script_entry_point(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "physynth.cli", "generate", "-n", "1", "--seed", "1", "--out",
                           str(tmp_path / "ds")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "wrote 1 trace" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "physynth.cli", "inspect", str(tmp_path / "missing")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr


def test_make_run_installs_matplotlib_for_the_readme_figures():
    """The README's worked example draws figures after ``make run``: its install has the extra report."""
    root = Path(__file__).resolve().parents[1]
    make = (root / "Makefile").read_text(encoding="utf-8")
    run_recipe = make.split("\nrun:", 1)[1].split("\n\n", 1)[0]
    assert "pip install --quiet -e '.[report]'" in run_recipe
    readme = (root / "README.md").read_text(encoding="utf-8")
    assert ".venv/bin/pip install -e '.[report]'" in readme
    assert "pip install 'physynth[" not in readme


@pytest.mark.parametrize("option", ["--epochs", "--pretrain-epochs", "--finetune-epochs", "--n-synth",
                                    "--synth-windows", "--threads", "--ensemble", "--jobs"])
@pytest.mark.parametrize("value", ["0", "-1"])
def test_study_tracking_refuses_counts_below_one(tmp_path, capsys, option, value):
    code, _, err = run(capsys, "study", "tracking", option, value, "--methods", "ls", "--out", tmp_path / "o")
    assert code == 2 and err.count("\n") == 1 and option in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_study_tracking_jobs_without_an_ensemble_is_one_line(tmp_path, capsys):
    code, _, err = run(capsys, "study", "tracking", "--jobs", "2", "--methods", "ls", "--protocol", "split",
                       "--out", tmp_path / "o")
    assert code == 2 and err.count("\n") == 1 and "--jobs 2" in err and "--ensemble" in err
    assert not (tmp_path / "o").exists()


def test_scenario_file_with_a_repeated_key_is_one_line(tmp_path, capsys):
    f = tmp_path / "dup.yaml"
    f.write_text("name: a\nname: b\n", encoding="utf-8")
    code, _, err = run(capsys, "generate", "--scenario", f, "--out", tmp_path / "x", "-q")
    assert code == 2 and err.count("\n") == 1 and "duplicate key 'name' at line 2 (first at line 1)" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args", [[], ["generate"], ["study"], ["study", "tracking"], ["import", "csv"],
                                  ["scenario", "show"], ["calibrate"], ["export"]])
def test_dash_h_is_help_everywhere(capsys, args):
    code, out, err = run(capsys, *args, "-h")
    assert code == 0 and out.startswith("Usage:") and err == ""
    assert out == run(capsys, *args, "--help")[1]


def test_generate_refuses_resume_with_overwrite(tmp_path, capsys):
    assert run(capsys, "generate", "-n", 1, "--seed", 1, "--out", tmp_path / "ds", "-q")[0] == 0
    before = (tmp_path / "ds" / "dataset.json").read_bytes()
    code, _, err = run(capsys, "generate", "-n", 1, "--out", tmp_path / "ds", "-q", "--resume", "--overwrite")
    assert code == 2 and err.count("\n") == 1 and "--resume and --overwrite exclude each other" in err
    assert (tmp_path / "ds" / "dataset.json").read_bytes() == before
    from physynth.errors import PhySynthError
    from physynth.workflows import generate_dataset

    with pytest.raises(PhySynthError, match="^resume and overwrite exclude each other"):
        generate_dataset(load_scenario("cablecar-descending"), 1, tmp_path / "ds", resume=True, overwrite=True)


def test_resume_of_a_complete_run_says_so_and_of_another_run_names_the_difference(tmp_path, capsys):
    out = tmp_path / "ds"
    assert run(capsys, "generate", "-n", 3, "--seed", 4, "--shard-traces", 2, "--out", out, "-q")[0] == 0
    before = (out / "dataset.json").read_bytes()
    code, text, err = run(capsys, "generate", "-n", 3, "--seed", 4, "--shard-traces", 2, "--out", out, "--resume")
    assert code == 0 and "is already complete (3 traces, root seed 4): nothing to resume" in text and err == ""
    code, _, err = run(capsys, "generate", "-n", 4, "--seed", 4, "--shard-traces", 2, "--out", out, "--resume")
    assert code == 2 and err.count("\n") == 1 and "differs in n_traces" in err and "--overwrite" not in err
    assert (out / "dataset.json").read_bytes() == before


def test_generate_workers_help_is_plain_words(capsys):
    code, out, _ = run(capsys, "generate", "--help")
    text = " ".join(out.split())  # as read, whatever the wrapping
    assert code == 0 and "one below" not in text and "costs seconds" not in text
    assert ("Worker processes. 0 (the default) picks for you: all cores for 1000 traces or more, one process "
            "below that, since starting workers takes seconds.") in text


def test_generate_summary_counts_workers_and_traces_grammatically(tmp_path, capsys):
    code, out, _ = run(capsys, "generate", "-n", 1, "--seed", 1, "--out", tmp_path / "one")
    assert code == 0 and "wrote 1 trace of " in out and "(root seed 1, 1 worker)" in out and "(s)" not in out
    code, out, _ = run(capsys, "generate", "-n", 3, "--seed", 1, "--out", tmp_path / "three")
    assert code == 0 and "wrote 3 traces of " in out
    code, out, _ = run(capsys, "inspect", tmp_path / "three")
    assert code == 0 and "- 3 traces, " in out and "(s)" not in out
    code, out, _ = run(capsys, "inspect", tmp_path / "one")
    assert code == 0 and "- 1 trace, " in out and "(s)" not in out


def test_help_shows_meaningful_metavars_everywhere(capsys):
    import re

    commands = _command_paths(groups=False)
    assert ["verify"] in commands and ["study", "placement"] in commands and len(commands) >= 15
    placeholder = re.compile(r"<[A-Za-z][\w\[\]. ]*>")  # typer's <int range>, <str>, <path>, <list[Path]>
    for path in commands:
        code, out, _ = run(capsys, *path, "--help")
        listed = out[min(i for i in (out.find("\nArguments:\n"), out.find("\nOptions:\n")) if i >= 0):]
        names = [line.strip().split("  ")[0] for line in listed.splitlines() if re.match(r"  [-A-Z]", line)]
        assert code == 0 and names and not [n for n in names if placeholder.search(n)], (path, names)
    code, out, _ = run(capsys, "generate", "--help")
    text = " ".join(out.split())
    for shown in ("-n, --n-traces N ", "--seed SEED ", "-o, --out DIR ", "-w, --workers N ", "-s, --scenario SCENARIO ",
                  "[default: 20; x>=1]", "[x>=0]"):  # ranges stay visible
        assert shown in text, shown
    code, out, _ = run(capsys, "calibrate", "--help")
    assert "  DATASET...  " in out and "-o, --out FILE " in out and "--path-kind <auto|polynomial|waypoints>" in out


def test_scenarios_wraps_whole_descriptions_in_80_columns(capsys, monkeypatch):
    from physynth.io.scenario_file import list_presets

    monkeypatch.setenv("COLUMNS", "80")
    code, out, _ = run(capsys, "scenarios")
    assert code == 0 and max(len(line) for line in out.splitlines()) <= 80, out
    text = " ".join(out.split())
    descriptions = {name: " ".join(load_scenario(name).description.split()) for name in list_presets()}
    assert max(map(len, descriptions.values())) > 80 - 25  # one at least needs more than a line
    for name, description in descriptions.items():
        assert f"{name} {description}" in text, name


@pytest.mark.parametrize(("given", "seen"), [(None, "1"), ("3", "3")])
def test_command_line_runs_blas_on_one_thread_unless_told(given, seen):
    """Generation parallelises over worker processes; a second BLAS thread in each only costs CPU time.
    The command line sets OPENBLAS_NUM_THREADS=1 before NumPy loads, and keeps a value the user set."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    code = ("import sys; import physynth.cli; assert 'numpy' not in sys.modules; import os, numpy; "
            "print(os.environ['OPENBLAS_NUM_THREADS'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == seen


def test_generate_refuses_a_scheduler_with_workers(tmp_path, capsys):
    code, _, err = run(capsys, "generate", "--scheduler", "tcp://127.0.0.1:1", "--workers", 2, "-n", 1,
                       "--out", tmp_path / "ds", "-q")
    assert code == 2 and err.count("\n") == 1 and "--scheduler and --workers exclude each other" in err
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize(("option", "value", "needle"), [
    ("--n-synth", "999999999", "--n-synth only matters for SYNTH_PHY"),
    ("--scenario", "cablecar-descending", "--scenario only matters for SYNTH_PHY"),
    ("--epochs", "3", "--epochs only matters for NOAUG, AUG_GAN or bilstm"),
    ("--ekf-prior", "input", "--ekf-prior only matters for NOAUG, AUG_GAN, SYNTH_PHY or bilstm"),
])
def test_study_tracking_refuses_an_option_no_chosen_method_uses(tmp_path, capsys, option, value, needle):
    code, _, err = run(capsys, "study", "tracking", option, value, "--methods", "ls,ekf", "--out", tmp_path / "o")
    assert code == 2 and err.count("\n") == 1 and needle in err and "(ls,ekf)" in err
    assert not (tmp_path / "o").exists()


def test_study_tracking_knows_which_methods_are_networks():
    from physynth.studies.tracking import NETWORK_METHODS
    from physynth.studies.tracking_setup import METHOD_SETTINGS, NETWORKS

    assert set(NETWORKS) == NETWORK_METHODS and set(METHOD_SETTINGS["frame"]) == NETWORK_METHODS


def test_bench_warns_when_the_scaling_run_is_too_short(capsys):
    """Two traces on two workers measure the workers' start, not the scaling: one line on stderr says so."""
    pytest.importorskip("distributed")
    from physynth.bench import SCALING_MIN_RUN_S, scaling_caveat

    assert scaling_caveat(SCALING_MIN_RUN_S, 2) is None
    code, out, err = run(capsys, "bench", "-n", 1, "--n-scaling", 2, "--workers", 2, "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["scaling_caveat"] and "scaling_efficiency" in res["scaling_caveat"]
    assert err.count("\n") == 1 and err.startswith("physynth: warning: ") and "--n-scaling" in err


def test_bench_alternates_the_scaling_runs_and_keeps_the_best():
    """With ``repeat`` the one-worker and two-worker scaling runs alternate (a slower spell of the machine
    reaches both sides of the ratio), and the rates reported are the best of each."""
    pytest.importorskip("distributed")
    from physynth.bench import run_bench
    from physynth.io.scenario_file import load_scenario

    phases: list[str] = []

    def progress(message, done=None, total=None):
        if message.startswith("scaling") and (not phases or phases[-1] != message):
            phases.append(message)

    with pytest.raises(ValueError, match="repeat must be >= 1"):  # before any work
        run_bench(load_scenario("cablecar-descending"), n=1, repeat=0)
    res = run_bench(load_scenario("cablecar-descending"), n=1, n_scaling=4, workers=2, repeat=2, progress=progress)
    assert phases == ["scaling, 1 worker(s)", "scaling, 2 worker(s)"] * 2  # the start-stop run reports nothing
    rates = res["traces_per_s_workers"]
    assert set(rates) == {"1", "2"} and all(v > 0 for v in rates.values())
    assert res["scaling_efficiency"] == pytest.approx(rates["2"] / (2 * rates["1"]), rel=0.03, abs=1e-3)  # both rounded
    # the steady state takes the cluster's start and stop off the run with workers: never below end to end
    assert res["cluster_start_stop_s"] > 0
    steady = res["scaling_efficiency_steady"]
    assert steady is None or steady >= res["scaling_efficiency"] - 1e-3


def test_inspect_of_a_dataset_without_anchors_shows_no_uwb_nans(tmp_path, capsys):
    from physynth.cli.generate import UWB_METRICS
    from physynth.evaluate.metrics import METRIC_KEYS

    assert set(UWB_METRICS) <= set(METRIC_KEYS)
    assert run(capsys, "generate", "-s", "handheld-broad", "-n", 1, "--seed", 1, "--out", tmp_path / "ds", "-q")[0] == 0
    code, out, err = run(capsys, "inspect", tmp_path / "ds", "-q")
    assert code == 0 and err == "" and "nan" not in out and "imu_std_mps2" in out
    assert "no anchors (IMU only): the UWB metrics do not apply" in out and "uwb_ge1_frac" not in out


def test_python_dash_m_physynth_is_the_command(tmp_path):
    """``python -m physynth`` runs the command line (there was only ``python -m physynth.cli``), workers
    included: a child process that re-imports the main module must not run the command again."""
    run = subprocess.run([sys.executable, "-m", "physynth", "--version"], capture_output=True, text=True, check=False)
    assert run.returncode == 0 and run.stdout.startswith("physynth ")
    run = subprocess.run([sys.executable, "-m", "physynth", "generate", "-n", "4", "--shard-traces", "2", "-w", "2",
                          "--seed", "1", "--out", str(tmp_path / "d"), "-q"],
                         capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr
    from physynth.io import read_meta

    assert read_meta(tmp_path / "d")["n_traces"] == 4


def test_bench_writes_in_the_folder_asked_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    import tempfile as _tempfile

    from physynth.bench import run_bench
    from physynth.errors import PhySynthError
    from physynth.io.scenario_file import load_scenario

    made = []
    mkdtemp = _tempfile.mkdtemp

    def spy(*args, **kwargs):
        made.append(mkdtemp(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(_tempfile, "mkdtemp", spy)
    res = run_bench(load_scenario("cablecar-descending"), n=1, workers=1, exports=True, directory=tmp_path)
    assert made and all(m.startswith(str(tmp_path)) for m in made)
    assert list(tmp_path.iterdir()) == []  # removed after
    assert set(res["export_vs_parquet"]["ratios"]) >= {"hdf5"} and res["traces_per_s_parquet"] > 0
    with pytest.raises(PhySynthError, match="not an existing folder"):
        run_bench(load_scenario("cablecar-descending"), n=1, workers=1, directory=tmp_path / "nowhere")
    code, out, err = run(capsys, "bench", "-n", 1, "-w", 1, "--dir", tmp_path / "nowhere")
    assert code == 2 and "nowhere" in err and "Traceback" not in err
