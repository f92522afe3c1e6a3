"""Issue 14: what PhySynth does with the user's files and exit codes (docs/reliability.md).

Each test feeds one case of the issue's list through the real command line (in process, or as a
real subprocess receiving real signals) and checks the exit code, the one-line message and the
files left on disk.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from helpers import run_cli as run
from helpers import simple_scenario_dict

from physynth.errors import DatasetError, IntegrityError, OutputLockedError, ScenarioError
from physynth.io import read_dataset
from physynth.io.safety import OutputLock, lock_path
from physynth.parallel import available_cores

CLI = [sys.executable, "-m", "physynth.cli"]


def one_line(err: str) -> bool:
    return err.count("\n") == 1 and "Traceback" not in err


def write_recording(folder: Path) -> Path:
    """The csv tests' clean recording, with times from 0 s."""
    from test_import_csv import T0_UNIX_S, make_tables, write_rec

    tables = make_tables()
    for name in ("truth", "uwb", "imu"):
        tables[name]["t_s"] = tables[name]["t_s"] - T0_UNIX_S
    return write_rec(folder, tables)


def write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def small(tmp_path) -> Path:
    """A scenario file of a short walk (a trace in a few milliseconds)."""
    return write_yaml(tmp_path / "walk.yaml", simple_scenario_dict())


@pytest.fixture
def dataset(tmp_path, small, capsys) -> Path:
    code, _, err = run(capsys, "generate", "-s", small, "-n", 3, "--seed", 1, "--out", tmp_path / "ds", "-q")
    assert code == 0, err
    return tmp_path / "ds"


# ------------------------------------------------------------------ 1. overwrite
def test_overwrite_refuses_a_folder_physynth_did_not_write(tmp_path, small, capsys):
    mine = tmp_path / "mydata"
    mine.mkdir()
    (mine / "thesis.txt").write_text("four years of work")
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", mine, "--overwrite", "-q")
    assert code == 2 and one_line(err) and "not a PhySynth dataset" in err
    assert (mine / "thesis.txt").read_text() == "four years of work"


def test_overwrite_refuses_a_dataset_holding_a_foreign_file(dataset, small, capsys):
    (dataset / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", dataset, "--overwrite", "-q")
    assert code == 2 and one_line(err) and "'notes.txt'" in err
    assert (dataset / "notes.txt").exists()


def test_overwrite_replaces_a_physynth_dataset(dataset, small, capsys):
    code, _, err = run(capsys, "generate", "-s", small, "-n", 2, "--seed", 2, "--out", dataset, "--overwrite", "-q")
    assert code == 0, err
    assert json.loads((dataset / "dataset.json").read_text())["n_traces"] == 2
    assert [p.name for p in dataset.parent.iterdir() if p.name.startswith(".")] == []


def test_generate_creates_missing_parent_folders(tmp_path, small, capsys):
    out = tmp_path / "runs" / "default"  # `make run` in a fresh checkout
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--seed", 1, "--out", out, "--overwrite", "-q")
    assert code == 0, err
    assert sorted(p.name for p in out.parent.iterdir()) == ["default"]


def test_import_refuses_an_output_holding_its_input(tmp_path, capsys):
    rec = write_recording(tmp_path / "mydata" / "rec")
    before = sorted(p.name for p in rec.iterdir())
    code, _, err = run(capsys, "import", "csv", rec, "--out", tmp_path / "mydata", "--overwrite", "-q")
    assert code == 2 and one_line(err) and "holds the input" in err
    assert sorted(p.name for p in rec.iterdir()) == before


def test_generate_out_dot_is_refused(tmp_path, small, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "generate", "-n", 1, "--out", ".", "--overwrite", "-q")
    assert code == 2 and one_line(err) and "current folder" in err
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", ".", "--overwrite", "-q")
    assert code == 2 and one_line(err) and "holds the input" in err
    assert small.exists()


def test_symlinked_out_replaces_the_target_and_keeps_the_link(dataset, small, tmp_path, capsys):
    link = tmp_path / "latest"
    link.symlink_to(dataset, target_is_directory=True)
    code, _, err = run(capsys, "generate", "-s", small, "-n", 2, "--seed", 9, "--out", link, "--overwrite", "-q")
    assert code == 0, err
    assert link.is_symlink() and json.loads((link / "dataset.json").read_text())["root_seed"] == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "latest", "walk.yaml"]  # no .old-<pid>


# ------------------------------------------------------------------ 2. interruption
def _hidden(folder: Path) -> list[str]:
    """Every hidden name below ``folder`` (temporary folders, locks), relative."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*"))


def _start_long_generate(out: Path, tmp_path: Path) -> subprocess.Popen:
    """A real ``physynth generate`` subprocess, returned once it is writing its (single) shard."""
    proc = subprocess.Popen([*CLI, "generate", "-n", "3000", "--seed", "1", "--out", str(out), "-q", "--force",
                             "--workers", "1", "--shard-traces", "100000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 120
    partial = out.with_name(f".{out.name}.partial")
    while not (partial.is_dir() and any(p.name.startswith(".shard-00000.tmp-") for p in partial.iterdir())):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the writer never started"
        time.sleep(0.05)
    time.sleep(0.3)
    return proc


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_signal_exits_128_plus_signal_and_removes_temporary_files(tmp_path, sig, code):
    out = tmp_path / "ds"
    proc = _start_long_generate(out, tmp_path)
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()  # never leave a writer behind, even when the test fails
    assert proc.returncode == code, err
    assert err.count("\n") == 1 and "interrupted by SIG" in err and "--resume" in err and "Traceback" not in err
    # nothing that looks complete: no dataset, no temporary shard, no lock; only the resumable plan
    assert not out.exists()
    assert _hidden(tmp_path) == [".ds.partial"]
    assert [p.name for p in (tmp_path / ".ds.partial").iterdir()] == ["run.json"]


def test_after_sigkill_the_next_run_says_so_and_starts_over_or_resumes(tmp_path, small, capsys):
    out = tmp_path / "ds"
    proc = _start_long_generate(out, tmp_path)
    proc.kill()
    proc.wait(timeout=60)
    assert not out.exists() and (tmp_path / ".ds.partial").is_dir()
    # the shard being written: with a core to spare its writer process removes it once the run is killed;
    # otherwise it stays (and the next run removes it)
    def temporary() -> bool:
        return any(p.name.startswith(".shard-") for p in (tmp_path / ".ds.partial").iterdir())

    deadline = time.monotonic() + 10
    while available_cores() >= 2 and temporary() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert temporary() == (available_cores() < 2)
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", out, "-q")
    assert code == 2 and one_line(err) and "unfinished run" in err and "--resume" in err
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", out, "-q", "--overwrite")
    assert code == 0, err
    assert _hidden(tmp_path) == [] and (out / "dataset.json").is_file()


def test_an_orphaned_temporary_folder_is_removed_and_reported(tmp_path, small, capsys):
    out = tmp_path / "ds"
    orphan = tmp_path / ".ds.tmp-999999"  # what a kill during the final rename or an import leaves
    orphan.mkdir()
    (orphan / "truth.parquet").write_bytes(b"x" * 1000)
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", out, "-q")
    assert code == 0 and "removed" in err and "interrupted run (pid 999999)" in err and one_line(err)
    assert _hidden(tmp_path) == [] and (out / "dataset.json").is_file()


def test_typer_130_return_is_not_dropped(monkeypatch, capsys):
    import physynth.cli as cli

    monkeypatch.setattr(cli.app, "__call__", lambda *a, **k: 130)
    monkeypatch.setattr(type(cli.app), "__call__", lambda self, *a, **k: 130)
    code, _, err = run(capsys, "scenarios")
    assert code == 130 and "interrupted" in err


def test_a_failure_inside_close_leaves_nothing(tmp_path, monkeypatch):
    from helpers import simple_scenario

    from physynth.generate import generate_traces
    from physynth.io import dataset as dsmod
    from physynth.io import write_dataset

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(dsmod.integrity, "file_records", boom)
    with pytest.raises(OSError):
        write_dataset(tmp_path / "ds", generate_traces(simple_scenario(), 2, seed=1))
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ 3. concurrency
def test_a_second_writer_is_refused_while_the_first_runs(tmp_path, small, capsys):
    out = tmp_path / "ds"
    proc = _start_long_generate(out, tmp_path)
    try:
        code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", out, "--overwrite", "-q")
        assert code == 2 and one_line(err) and "being written by another physynth process" in err
        assert f"pid {proc.pid}" in err
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=120)
        finally:
            proc.kill()


def test_a_stale_lock_is_taken_over(tmp_path, small, capsys):
    out = tmp_path / "ds"
    lock_path(out).write_text("pid 999999 host elsewhere since 2020-01-01T00:00:00Z\n")
    code, _, err = run(capsys, "generate", "-s", small, "-n", 1, "--out", out, "-q")
    assert code == 0, err
    assert not lock_path(out).exists()
    lock = OutputLock(out)
    lock_path(out).write_text("pid 999999 host elsewhere since 2020-01-01T00:00:00Z\n")
    with lock:
        assert lock.stale_owner.startswith("pid 999999")


def test_lock_held_in_this_process_blocks_another_holder(tmp_path):
    out = tmp_path / "x"
    with OutputLock(out):
        with pytest.raises(OutputLockedError, match=f"pid {os.getpid()}"):
            OutputLock(out).acquire()
    with OutputLock(out):
        pass


# ------------------------------------------------------------------ 4. bounds and budget
@pytest.mark.parametrize(("key", "value", "needle"), [
    ("imu.rate_hz", 1e7, "imu.rate_hz"),
    ("truth_rate_hz", 1e6, "truth_rate_hz"),
    ("motion.dwell_start_s", 1e7, "motion.dwell_start_s"),
    ("uwb.nlos_dwell_s", 1e-300, "uwb.nlos_dwell_s"),
    ("uwb.time_offset_s", 1e6, "uwb.time_offset_s"),
    ("motion.cruise_speed_mps", 1e-7, "motion.cruise_speed_mps"),
    ("motion.jitter.acc_rms_mps2", [[0.1, 0.1, 2000.0]] * 5, "motion.jitter.acc_rms_mps2"),
    ("imu.white_noise_density_mps2_per_sqrt_hz", [-0.1, 0.1, 0.1], "white_noise_density"),
    ("motion.profile", {"kind": "polynomial", "coeffs": [0, 0]}, "zero"),
    ("motion.profile", {"kind": "empirical", "samples": [0.5, 1.0, 0.5]}, "at least 5 samples"),
])
def test_out_of_range_fields_are_refused_with_one_line(tmp_path, capsys, key, value, needle):
    f = write_yaml(tmp_path / "s.yaml", simple_scenario_dict(**{key: value}))
    code, _, err = run(capsys, "generate", "-s", f, "-n", 1, "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and needle in err
    assert not (tmp_path / "o").exists()


def test_polynomial_path_of_absurd_length_is_refused(tmp_path, capsys):
    d = simple_scenario_dict()
    d["path"] = {"kind": "polynomial", "length_m": 1e9, "coeffs_enu_m": [[0, 1e9], [0, 0], [0, 0]]}
    code, _, err = run(capsys, "generate", "-s", write_yaml(tmp_path / "s.yaml", d), "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and "path.length_m" in err


def test_a_trip_too_short_for_a_trace_is_refused(tmp_path, capsys):
    d = simple_scenario_dict(**{"motion.cruise_speed_mps": 150.0})
    d["path"]["waypoints_enu_m"] = [[0, 0, 0], [0.5, 0, 0]]
    code, _, err = run(capsys, "generate", "-s", write_yaml(tmp_path / "s.yaml", d), "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and "the trip takes only" in err


def test_over_budget_is_refused_before_any_work_with_the_estimate(tmp_path, capsys):
    f = write_yaml(tmp_path / "s.yaml", simple_scenario_dict(**{"motion.dwell_start_s": 80_000.0,
                                                                "imu.rate_hz": 10_000.0}))
    t0 = time.monotonic()
    code, _, err = run(capsys, "generate", "-s", f, "-n", 1, "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and "GB of memory" in err and "--force" in err
    assert time.monotonic() - t0 < 5 and not (tmp_path / "o").exists()
    f = write_yaml(tmp_path / "s.yaml", simple_scenario_dict())
    code, _, err = run(capsys, "generate", "-s", f, "-n", 10**9, "--out", tmp_path / "o", "-q")
    assert code == 2 and "output budget" in err and "1000000000 trace(s)" in err


def test_yaml_aliases_are_bounded(tmp_path, capsys):
    lol = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{','.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(9))
    for text, needle in ((lol, "expands to more than"), ("name: &n [*n]\n", "refers to itself")):
        f = tmp_path / "s.yaml"
        f.write_text(text)
        t0 = time.monotonic()
        code, _, err = run(capsys, "generate", "-s", f, "--out", tmp_path / "o", "-q")
        assert code == 2 and one_line(err) and needle in err and time.monotonic() - t0 < 5


def test_negative_seed_is_a_usage_error(tmp_path, capsys):
    code, _, err = run(capsys, "generate", "--seed", -1, "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and "--seed" in err


def test_same_file_as_two_outputs_is_refused(dataset, tmp_path, capsys):
    code, _, err = run(capsys, "calibrate", dataset, "--out", tmp_path / "s.yaml", "--report", tmp_path / "s.yaml")
    assert code == 2 and one_line(err) and "same file" in err
    assert not (tmp_path / "s.yaml").exists()


def test_every_scenario_number_has_a_documented_range():
    from physynth.bounds import BOUNDS
    from physynth.scenario import Scenario

    def numbers(model, prefix):
        import types
        import typing

        from pydantic import BaseModel

        for name, field in model.model_fields.items():
            path = f"{prefix}{name}"
            ann = field.annotation
            union = typing.get_origin(ann) in (typing.Union, types.UnionType)
            args = [a for a in typing.get_args(ann) if a is not type(None)] if union else [ann]
            for a in args:
                inner = typing.get_args(a)
                origin = typing.get_origin(a)
                if origin is dict:
                    a = inner[1]
                    path = {"channel_per_anchor": "channel", "availability_per_anchor": "availability"}.get(name)
                    if path is None:  # free-form (provenance)
                        continue
                    if isinstance(a, type) and issubclass(a, BaseModel):
                        yield from numbers(a, f"{path}.")
                    continue
                suffix = ""
                while origin is list:
                    suffix += "[]"
                    a = inner[0]
                    inner, origin = typing.get_args(a), typing.get_origin(a)
                    if typing.get_origin(a) is typing.Annotated:
                        a = inner[0]
                        inner, origin = typing.get_args(a), typing.get_origin(a)
                if isinstance(a, type) and issubclass(a, BaseModel):
                    yield from numbers(a, f"{path}{suffix}.")
                elif a in (float, int):
                    yield f"{path}{suffix}"

    found = set(numbers(Scenario, ""))
    assert "imu.rate_hz" in found and "anchors[].pos_enu_m[]" in found and len(found) > 40
    assert found - set(BOUNDS) == set()
    doc = (Path(__file__).parents[1] / "docs" / "reliability.md").read_text()
    assert all(f"`{k}`" in doc for k in BOUNDS), [k for k in BOUNDS if f"`{k}`" not in doc]


def test_presets_are_within_bounds():
    from physynth.io.scenario_file import list_presets, load_scenario

    for name in list_presets():
        load_scenario(name)


# ------------------------------------------------------------------ 5. integrity
def _flip_byte(f: Path, where: float = 0.5) -> None:
    data = bytearray(f.read_bytes())
    data[int(len(data) * where)] ^= 0x01
    f.write_bytes(bytes(data))


def test_flipped_byte_is_named_by_reader_and_verify(dataset, capsys):
    code, out, _ = run(capsys, "verify", dataset)
    assert code == 0 and "ok" in out and "sha256 match" in out
    _flip_byte(dataset / "truth.parquet")
    with pytest.raises(IntegrityError, match="truth.parquet does not match its sha256"):
        read_dataset(dataset)
    code, _, err = run(capsys, "verify", dataset)
    assert code == 2 and one_line(err) and "truth.parquet" in err
    code, _, err = run(capsys, "inspect", dataset)
    assert code == 2 and one_line(err) and "truth.parquet" in err


def test_verify_names_every_damaged_file(dataset, tmp_path, capsys):
    intact = tmp_path / "intact"
    shutil.copytree(dataset, intact)
    _flip_byte(dataset / "imu.parquet")
    f = dataset / "uwb.parquet"
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    code, out, err = run(capsys, "verify", dataset)
    assert code == 2 and out == "" and "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 2 and all(line.startswith("physynth: error: ") for line in lines), err
    assert "imu.parquet does not match its sha256" in lines[0] and "uwb.parquet has" in lines[1]
    with pytest.raises(IntegrityError, match="imu.parquet"):  # a reader still stops at the first
        read_dataset(dataset)
    code, out, err = run(capsys, "verify", dataset, intact)
    assert code == 2 and f"{intact}: ok" in out
    assert [line.split(": ", 1)[0] for line in err.splitlines()[:2]] == [str(dataset)] * 2
    assert "imu.parquet" in err and "uwb.parquet" in err and "1 of 2 datasets failed verification" in err


def test_missing_trace_rows_and_wrong_n_traces_are_noticed(dataset):
    meta = json.loads((dataset / "dataset.json").read_text())
    meta["n_traces"] = 4
    (dataset / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(IntegrityError, match="n_traces 4"):
        read_dataset(dataset)
    meta["n_traces"] = 3
    table = pq.read_table(dataset / "imu.parquet")
    keep = table.filter(pa.compute.not_equal(table["trace"], 1))
    pq.write_table(keep, dataset / "imu.parquet")
    (dataset / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(IntegrityError, match="imu.parquet"):
        read_dataset(dataset)


def test_truncated_file_is_named(dataset):
    f = dataset / "uwb.parquet"
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    with pytest.raises(IntegrityError, match="uwb.parquet has .* bytes"):
        read_dataset(dataset)


def test_unsorted_times_in_a_table_are_one_line(dataset, capsys):
    meta = json.loads((dataset / "dataset.json").read_text())
    del meta["files"]  # a dataset edited by hand (or written before integrity records)
    (dataset / "dataset.json").write_text(json.dumps(meta))
    t = pq.read_table(dataset / "truth.parquet").to_pandas()
    t["t_s"] = t["t_s"].to_numpy()[::-1]
    pq.write_table(pa.Table.from_pandas(t, preserve_index=False), dataset / "truth.parquet")
    code, _, err = run(capsys, "inspect", dataset)
    assert code == 2 and one_line(err) and "trace 0 is invalid" in err
    code, _, err = run(capsys, "verify", dataset)
    assert code == 2 and "no integrity record" in err


# ------------------------------------------------------------------ 6. import sanity
def test_truth_in_milliseconds_is_detected(tmp_path, capsys):
    import pandas as pd

    rec = write_recording(tmp_path / "rec")

    truth = pd.read_csv(rec / "truth.csv")
    truth["t_s"] = truth["t_s"] * 1000.0
    truth.to_csv(rec / "truth.csv", index=False)
    code, _, err = run(capsys, "import", "csv", rec, "--out", tmp_path / "ds", "-q")
    assert code == 2 and one_line(err) and "milliseconds" in err and "truth.csv" in err


def test_a_stream_covering_a_small_part_is_named_with_the_truth(tmp_path, capsys):
    import pandas as pd

    rec = write_recording(tmp_path / "rec")
    uwb = pd.read_csv(rec / "uwb.csv")
    uwb = uwb[uwb["t_s"] < uwb["t_s"].min() + 0.06]  # 0.06 s of ranges against 20 s of truth
    uwb.to_csv(rec / "uwb.csv", index=False)
    code, _, err = run(capsys, "import", "csv", rec, "--out", tmp_path / "ds", "-q")
    # which file is wrong cannot be told from the spans: both readings are named
    assert code == 2 and one_line(err) and "uwb.csv covers only a small part" in err and "truth.csv is in" in err


def test_coerced_burst_cells_are_counted(tmp_path):
    import pandas as pd

    from physynth.io.importers import import_csv

    rec = write_recording(tmp_path / "rec")
    uwb = pd.read_csv(rec / "uwb.csv")
    uwb["burst"] = np.arange(len(uwb)).astype(object)
    uwb.loc[3, "burst"] = "x"
    uwb.loc[5, "burst"] = 1.5
    uwb.to_csv(rec / "uwb.csv", index=False)
    trace, report = import_csv(rec)
    assert report.repaired["uwb.csv"]["burst_not_a_number"] == 1
    assert report.repaired["uwb.csv"]["burst_not_an_integer"] == 1
    assert (trace.uwb.burst == -1).sum() == 2


def test_calibrate_refuses_to_pool_different_sites(tmp_path, dataset, capsys):
    other = simple_scenario_dict()
    other["anchors"] = [{"id": f"B{i}", "pos_enu_m": [100.0 * i, 20, 3]} for i in range(3)]
    f = write_yaml(tmp_path / "other.yaml", other)
    assert run(capsys, "generate", "-s", f, "-n", 2, "--out", tmp_path / "ds2", "-q")[0] == 0
    code, _, err = run(capsys, "calibrate", dataset, tmp_path / "ds2", "--out", tmp_path / "s.yaml", "-q")
    assert code == 2 and one_line(err) and "no anchor in common" in err and "--allow-mixed" in err


def test_validate_refuses_a_real_dataset_with_too_few_ranges(tmp_path, capsys):
    d = simple_scenario_dict(**{"channel.rate_hz": 0.1, "uwb.burst_rate_hz": 0.1})
    d["anchors"] = d["anchors"][:1]
    d["path"]["waypoints_enu_m"] = [[0, 0, 1], [30, 0, 1]]
    f = write_yaml(tmp_path / "few.yaml", d)
    assert run(capsys, "generate", "-s", f, "-n", 1, "--seed", 3, "--out", tmp_path / "real", "-q")[0] == 0
    code, _, err = run(capsys, "validate", "--real", tmp_path / "real", "--scenario", f, "-n", 1,
                       "--out", tmp_path / "rep", "--no-figures", "-q")
    assert code == 2 and one_line(err) and "need at least 30" in err


# ------------------------------------------------------------------ 7. exit code of a bug
def test_a_bug_is_one_line_exit_3(monkeypatch, capsys):
    import physynth.io.scenario_file as sf

    monkeypatch.setattr(sf, "list_presets", lambda: 1 / 0)
    code, _, err = run(capsys, "scenarios")
    assert code == 3 and one_line(err) and "internal error: ZeroDivisionError" in err


def test_library_errors_have_one_line():
    from physynth.scenario import scenario_from_dict

    with pytest.raises(ScenarioError) as exc:
        scenario_from_dict(simple_scenario_dict(**{"imu.rate_hz": 1e9}))
    assert "\n" not in str(exc.value)
    with pytest.raises(DatasetError):
        read_dataset("/nonexistent")


def test_validate_report_folder_is_refused_or_written_whole(dataset, tmp_path, capsys, monkeypatch):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.txt").write_text("x")
    args = ["validate", "--real", dataset, "--synthetic", dataset, "--no-figures", "-q"]
    code, _, err = run(capsys, *args, "--out", mine, "--overwrite")
    assert code == 2 and one_line(err) and "not a PhySynth report folder" in err
    code, _, err = run(capsys, *args, "--out", mine)
    assert code == 2 and one_line(err) and "refusing to write a report into" in err

    import physynth.validate.render as render
    from physynth.errors import Interrupted

    def interrupted(report, out, **kw):
        (Path(out) / "report.json").write_text("{}")
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(render, "write_report", interrupted)
    code, _, err = run(capsys, *args, "--out", tmp_path / "rep")
    assert code == 143 and one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "mine", "walk.yaml"]
    monkeypatch.undo()
    code, _, err = run(capsys, *args, "--out", tmp_path / "rep")
    assert code == 0, err
    assert (tmp_path / "rep" / "report.json").exists()
    assert run(capsys, *args, "--out", tmp_path / "rep", "--overwrite")[0] == 0


def test_ranges_in_centimetres_are_detected(tmp_path, capsys):
    import pandas as pd

    rec = write_recording(tmp_path / "rec")
    uwb = pd.read_csv(rec / "uwb.csv")
    uwb["range_m"] = uwb["range_m"] * 100.0  # ~1000-3000 cm: below the 5 km median limit
    uwb.to_csv(rec / "uwb.csv", index=False)
    code, _, err = run(capsys, "import", "csv", rec, "--out", tmp_path / "ds", "-q")
    assert code == 2 and one_line(err) and "times the distances" in err and "centimetres" in err


def test_site_rules():
    from physynth.calibrate.sites import Site, check_same_site
    from physynth.errors import MixedSitesError

    walk = Site("walk", "real", "hanyang-uwb", frozenset({"A1", "A2"}))
    cable = Site("cable", "real", "csv", frozenset({"A101", "A103"}))
    imu_only = Site("broad15", "real", "broad", frozenset())
    check_same_site([walk, imu_only])  # docs/calibration.md: UWB from Hanyang + IMU noise from BROAD
    check_same_site([walk, Site("walk2", "real", "hanyang-uwb", frozenset({"A2", "A3"}))])
    with pytest.raises(MixedSitesError, match="no anchor in common"):
        check_same_site([walk, imu_only, cable])
    with pytest.raises(MixedSitesError, match="different recording sources"):
        check_same_site([walk, Site("w", "real", "csv", frozenset({"A1"}))])
    check_same_site([walk, cable], allow_mixed=True)


def test_calibrate_overwrites_only_its_own_files(dataset, tmp_path, capsys):
    mine = tmp_path / "mine.yaml"
    mine.write_text("# my hand-written scenario\nname: x\n")
    code, _, err = run(capsys, "calibrate", dataset, "--out", mine, "--overwrite", "-q")
    assert code == 2 and one_line(err) and "not a scenario file written by physynth calibrate" in err
    assert mine.read_text().startswith("# my hand-written")
    out, rep = tmp_path / "cal.yaml", tmp_path / "fit.json"
    code, _, err = run(capsys, "calibrate", dataset, "--out", out, "--report", rep, "-q")
    assert code == 0, err
    code, _, err = run(capsys, "calibrate", dataset, "--out", out, "--report", rep, "-q", "--overwrite")
    assert code == 0, err
    assert json.loads(rep.read_text())["generator"]["name"] == "physynth"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml", "ds", "fit.json", "mine.yaml", "walk.yaml"]


def test_a_swallowed_interrupt_is_raised_at_the_next_trace(tmp_path):
    """A signal whose exception lands in a finaliser is lost; the writer re-raises it at the next trace."""
    from helpers import simple_scenario

    from physynth.errors import Interrupted
    from physynth.generate import generate_traces
    from physynth.io import safety, write_dataset

    def traces():
        for i, t in enumerate(generate_traces(simple_scenario(), 5, seed=1)):
            if i == 2:
                safety.set_interrupted(signal.SIGTERM)
            yield t

    try:
        with pytest.raises(Interrupted):
            write_dataset(tmp_path / "ds", traces())
    finally:
        safety.clear_interrupted()
    assert list(tmp_path.iterdir()) == []


def test_a_dataset_of_several_shards_is_verified_and_replaceable(tmp_path, small, capsys):
    out = tmp_path / "ds"
    args = ["generate", "-s", small, "-n", 5, "--seed", 3, "--out", out, "-q", "--workers", 1, "--shard-traces", 2]
    assert run(capsys, *args)[0] == 0
    meta = json.loads((out / "dataset.json").read_text())
    assert "truth/part-00002.parquet" in meta["files"] and meta["n_traces"] == 5
    code, stdout, _ = run(capsys, "verify", out)
    assert code == 0 and "12 file(s)" in stdout
    assert len(read_dataset(out)) == 5
    _flip_byte(out / "uwb" / "part-00001.parquet")
    code, _, err = run(capsys, "verify", out)
    assert code == 2 and one_line(err) and "uwb/part-00001.parquet" in err
    code, _, err = run(capsys, *args, "--overwrite")  # the parts folders are PhySynth's own
    assert code == 0, err
    assert run(capsys, "verify", out)[0] == 0


def test_readers_read_the_recorded_files_and_verify_names_stray_ones(tmp_path, small, capsys):
    """A uwb.parquet beside uwb/part-*.parquet, or an extra part, is neither read nor passed by verify."""
    out, other = tmp_path / "ds", tmp_path / "other"
    args = ["generate", "-s", small, "-n", 5, "--seed", 3, "-q", "--workers", 1, "--shard-traces", 2]
    assert run(capsys, *args, "--out", out)[0] == 0
    assert run(capsys, "generate", "-s", small, "-n", 1, "--seed", 9, "-q", "--out", other)[0] == 0
    before = [t.uwb.range_m for t in read_dataset(out)]
    shutil.copy(other / "uwb.parquet", out / "uwb.parquet")
    shutil.copy(out / "uwb" / "part-00000.parquet", out / "uwb" / "part-00099.parquet")
    after = [t.uwb.range_m for t in read_dataset(out)]
    assert len(after) == 5 and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(after, before, strict=True))
    code, _, err = run(capsys, "verify", out)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 2, err
    assert "holds uwb.parquet" in lines[0] and "holds uwb/part-00099.parquet" in lines[1]
    assert "does not list" in lines[0]
    meta = json.loads((out / "dataset.json").read_text())  # without a record (an older PhySynth): as before
    meta.pop("files")
    (out / "dataset.json").write_text(json.dumps(meta))
    (out / "uwb.parquet").unlink()
    (out / "uwb" / "part-00099.parquet").unlink()
    assert len(read_dataset(out)) == 5


@pytest.mark.parametrize("record", ["empty", "partial"])
def test_an_empty_or_partial_integrity_record_is_damage(dataset, capsys, record):
    meta = json.loads((dataset / "dataset.json").read_text())
    meta["files"] = {} if record == "empty" else {k: v for k, v in meta["files"].items() if k != "imu.parquet"}
    (dataset / "dataset.json").write_text(json.dumps(meta))
    code, out, err = run(capsys, "verify", dataset)
    assert code == 2 and out == "" and one_line(err), err
    assert ("is empty" if record == "empty" else "lacks the table(s) imu") in err
    with pytest.raises(IntegrityError, match="integrity record"):
        read_dataset(dataset)


def test_the_memory_budget_holds_for_the_workers_together(tmp_path, capsys, monkeypatch):
    """Issue 44: W worker processes each hold their own traces; the budget is for the run, not per process."""
    from physynth import bounds
    from physynth.io.scenario_file import load_scenario

    f = write_yaml(tmp_path / "s.yaml", simple_scenario_dict())
    one = bounds.estimate_size(load_scenario(str(f)), 8)
    monkeypatch.setattr(bounds, "MEMORY_BUDGET_BYTES", 1.5 * one.peak_memory_bytes)  # one process fits, two do not
    code, _, err = run(capsys, "generate", "-s", f, "-n", 8, "--workers", 2, "--shard-traces", 4,
                       "--out", tmp_path / "o", "-q")
    assert code == 2 and one_line(err) and "GB of memory over 2 processes" in err and "--force" in err
    assert not (tmp_path / "o").exists() and not any(tmp_path.glob(".o*"))
    code, _, err = run(capsys, "generate", "-s", f, "-n", 8, "--workers", 1, "--shard-traces", 4,
                       "--out", tmp_path / "o", "-q")
    assert code == 0, err
