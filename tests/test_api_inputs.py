"""Bad arguments to the Python API: one clear PhySynthError at the call, nothing written, nothing left behind."""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from helpers import simple_scenario, simple_scenario_dict

import physynth
from physynth import Anchors, Trace, Truth, Uwb
from physynth.errors import ArgumentError, PhySynthError, ScenarioError
from physynth.evaluate.metrics import compute_metrics
from physynth.generate import compile_scenario, generate_trace, generate_traces
from physynth.io.dataset import read_dataset, write_dataset
from physynth.io.importers import import_csv, import_hanyang
from physynth.io.scenario_file import load_scenario, save_scenario
from physynth.io.shards import partial_dir
from physynth.scenario import scenario_to_dict
from physynth.workflows import calibrate_datasets, generate_dataset, inspect_dataset, validate_datasets

SHORT_PATH = [[0, 0, 1], [30, 4, 1], [60, 0, 1]]  # a 20 s walk past the three anchors: traces in milliseconds


@pytest.fixture(scope="module")
def scn():
    return simple_scenario(**{"path.waypoints_enu_m": SHORT_PATH, "name": "short"})


@pytest.fixture(scope="module")
def traces(scn):
    return list(generate_traces(scn, 2, seed=1))


def _same(a: Trace, b: Trace) -> bool:
    return np.array_equal(a.uwb.range_m, b.uwb.range_m, equal_nan=True) and np.array_equal(a.truth.t_s, b.truth.t_s)


# ------------------------------------------------------------------ 1. seeds, indices and counts are integers
@pytest.mark.parametrize(("index", "seed", "match"), [
    (0, 1.7, r"^root_seed must be an integer \(the root seed\), got 1\.7 \(float\)$"),
    (1.9, 7, r"^index must be an integer \(the index of the trace\), got 1\.9"),
    (0, True, r"^root_seed must be an integer"),
    (-1, 1, r"^index must be >= 0 \(the index of the trace\), got -1$"),
    (0, -1, r"^root_seed must be >= 0"),
])
def test_generate_trace_refuses_float_bool_and_negative_seed_or_index(scn, index, seed, match):
    with pytest.raises(ArgumentError, match=match):
        generate_trace(scn, index, seed)


def test_numpy_integers_are_integers(scn):
    assert _same(generate_trace(scn, np.int64(1), np.uint32(7)), generate_trace(scn, 1, 7))
    assert _same(next(generate_traces(scn, np.int16(1), seed=np.int64(3))), generate_trace(scn, 0, 3))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n": 2, "seed": -1}, r"^seed must be >= 0 \(the root seed\), got -1$"),
    ({"n": 2, "seed": 1.5}, r"^seed must be an integer"),
    ({"n": "3", "seed": 1}, r"^n must be an integer \(the number of traces\), got '3' \(str\)$"),
    ({"n": 2.5, "seed": 1}, r"^n must be an integer \(the number of traces\), got 2\.5"),
    ({"n": 1, "seed": 1, "start": 0.5}, r"^start must be an integer"),
])
def test_generate_traces_refuses_bad_arguments_at_the_call(scn, kwargs, match):
    with pytest.raises(ArgumentError, match=match):  # not a lazy iterator failing at its first next()
        generate_traces(scn, **kwargs)
    with pytest.raises(ValueError):  # as before these were checked
        generate_traces(scn, **kwargs)


# ------------------------------------------------------------------ 2. generate_dataset: nothing written on bad input
@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n": 2.5}, r"^n must be an integer"),
    ({"n": 2, "shard_traces": 1.5}, r"^shard_traces must be an integer"),
    ({"n": 2, "seed": 1.5}, r"^seed must be an integer \(the root seed\)"),
    ({"n": 2, "seed": True}, r"^seed must be an integer"),
    ({"n": 2, "workers": 2.0}, r"^workers must be an integer"),
    ({"n": "2"}, r"^n must be an integer"),
])
def test_generate_dataset_checks_every_argument_before_writing(scn, tmp_path, kwargs, match):
    out = tmp_path / "ds"
    with pytest.raises(ArgumentError, match=match):
        generate_dataset(scn, out=out, **({"seed": 1} | kwargs))
    assert list(tmp_path.iterdir()) == []  # no output, no .ds.partial, no lock
    path, root = generate_dataset(scn, 2, out, seed=1)  # the next, correct call is not blocked
    assert root == 1 and len(read_dataset(path)) == 2


def test_a_worker_of_an_unguarded_script_refuses_before_touching_the_output(scn, tmp_path, monkeypatch):
    monkeypatch.setattr(multiprocessing.current_process(), "_inheriting", True, raising=False)  # as spawn sets it
    with pytest.raises(PhySynthError, match=r'if __name__ == "__main__":'):
        generate_dataset(scn, 4, tmp_path / "ds", seed=1, shard_traces=2, workers=2)
    assert list(tmp_path.iterdir()) == []


def test_workers_that_do_not_start_are_one_line_and_leave_nothing_to_resume(scn, tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")

    def nanny_fails(*args, **kwargs):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", nanny_fails)
    out = tmp_path / "ds"
    with pytest.raises(PhySynthError, match=r"^the Dask worker processes did not start \(Nanny failed to start\.\); "
                                            r"a script .* `if __name__ == \"__main__\":`"):
        generate_dataset(scn, 4, out, seed=1, shard_traces=2, workers=2)
    assert list(tmp_path.iterdir()) == []  # no .ds.partial holding only run.json
    generate_dataset(scn, 4, out, seed=1, shard_traces=2)  # no "unfinished run" in the way
    assert len(read_dataset(out)) == 4


def test_unguarded_script_with_workers_fails_with_the_guard_in_the_message(tmp_path):
    pytest.importorskip("distributed")
    save_scenario(simple_scenario(**{"path.waypoints_enu_m": SHORT_PATH, "name": "short"}), tmp_path / "s.yaml")
    script = tmp_path / "unguarded.py"
    script.write_text(textwrap.dedent(f"""
        import physynth
        physynth.generate_dataset({str(tmp_path / "s.yaml")!r}, 4, {str(tmp_path / "ds")!r}, seed=1,
                                  shard_traces=2, workers=2)
    """))
    log = tmp_path.parent / f"{tmp_path.name}-workers.log"  # the workers' own output goes to PHYSYNTH_LOG
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                          env={**os.environ, "PHYSYNTH_LOG": str(log)})
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]  # the calling process's error
    assert last.startswith("physynth.errors.PhySynthError: the Dask worker processes did not start"), proc.stderr
    assert last.endswith('if __name__ == "__main__":`, since each worker process imports the script again')
    assert "a worker process still starting up" not in proc.stderr  # the workers' tracebacks stay off stderr
    assert "a worker process still starting up" in log.read_text()  # and are in the log: what each worker said
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.yaml", "unguarded.py"]


def test_a_failure_after_a_shard_keeps_the_run_resumable(scn, tmp_path, monkeypatch):
    import physynth.workflows as wf

    real_run_shards = wf.run_shards

    def first_shard_then_fail(scn_, root, partial, plan, todo, meta, **kwargs):
        real_run_shards(scn_, root, partial, plan, todo[:1], meta)
        raise RuntimeError("worker lost")

    monkeypatch.setattr(wf, "run_shards", first_shard_then_fail)
    out = tmp_path / "ds"
    with pytest.raises(RuntimeError, match="worker lost"):
        generate_dataset(scn, 4, out, seed=1, shard_traces=2)
    assert sorted(p.name for p in partial_dir(out).iterdir()) == ["run.json", "shard-00000"]
    monkeypatch.setattr(wf, "run_shards", real_run_shards)
    generate_dataset(scn, 4, out, shard_traces=2, resume=True)  # the seed from run.json
    ds = read_dataset(out)
    assert ds.meta["root_seed"] == 1 and all(_same(t, generate_trace(scn, i, 1)) for i, t in enumerate(ds.traces))


# ------------------------------------------------------------------ 3. compute_metrics and write_dataset arguments
@pytest.mark.parametrize("rate", [0, -100, math.nan, math.inf, "100"])
def test_compute_metrics_refuses_a_rate_that_is_not_positive_and_finite(traces, rate):
    with pytest.raises(ArgumentError, match=r"^rate_hz must be"):
        compute_metrics(traces, rate_hz=rate)


def test_compute_metrics_without_traces_or_with_one_trace(traces, tmp_path):
    with pytest.raises(PhySynthError, match=r"^no traces to compute metrics on$"):
        compute_metrics([])
    with pytest.raises(ArgumentError, match=r"got a single Trace \(pass \[trace\]\)"):
        compute_metrics(traces[0])
    with pytest.raises(ArgumentError, match=r"got a single Trace \(pass \[trace\]\)"):
        write_dataset(tmp_path / "ds", traces[0])
    assert list(tmp_path.iterdir()) == []
    assert compute_metrics([traces[0]]).n_traces == 1


# ------------------------------------------------------------------ 4. the grid rate a dataset or scenario records
@pytest.fixture(scope="module")
def grid10(tmp_path_factory):
    """A synthetic dataset of a 10 Hz-grid scenario, and the same traces written as if imported (no scenario)."""
    d = tmp_path_factory.mktemp("grid10")
    scn = simple_scenario(**{"path.waypoints_enu_m": SHORT_PATH, "name": "grid10", "grid_rate_hz": 10.0,
                             "uwb.burst_rate_hz": 2.0, "channel.rate_hz": 2.0})
    generate_dataset(scn, 2, d / "synth", seed=1)
    write_dataset(d / "real", list(generate_traces(scn, 2, seed=5)), meta={"kind": "real"})
    return scn, d


def test_inspect_uses_the_recorded_grid_rate(grid10):
    scn, d = grid10
    at = {rate: compute_metrics(physynth.iter_traces(d / "synth"), rate).uwb_ge1_frac for rate in (10.0, 100.0)}
    assert at[10.0] != at[100.0]
    assert inspect_dataset(d / "synth")[0].uwb_ge1_frac == at[10.0]
    assert inspect_dataset(d / "synth", rate_hz=100)[0].uwb_ge1_frac == at[100.0]  # an explicit rate wins
    real = compute_metrics(physynth.iter_traces(d / "real"), 100.0).uwb_ge1_frac
    assert inspect_dataset(d / "real")[0].uwb_ge1_frac == real  # no scenario recorded: 100 Hz
    with pytest.raises(ArgumentError, match=r"^rate_hz must be positive"):
        inspect_dataset(d / "synth", rate_hz=0)


def test_validate_uses_the_scenario_or_synthetic_grid_rate_for_both_sides(grid10):
    scn, d = grid10
    by_scenario = validate_datasets(d / "real", scenario=scn, n=2, seed=1)
    by_dataset = validate_datasets(d / "real", synthetic=d / "synth")
    explicit = validate_datasets(d / "real", synthetic=d / "synth", rate_hz=100.0)
    assert by_scenario.inputs["grid_rate_hz"] == by_dataset.inputs["grid_rate_hz"] == 10.0
    assert explicit.inputs["grid_rate_hz"] == 100.0
    real_at_10 = compute_metrics(physynth.iter_traces(d / "real"), 10.0).uwb_ge1_frac
    assert by_dataset.real["uwb_ge1_frac"] == by_scenario.real["uwb_ge1_frac"] == real_at_10
    assert by_dataset.synthetic["uwb_ge1_frac"] == compute_metrics(physynth.iter_traces(d / "synth"), 10.0).uwb_ge1_frac
    assert validate_datasets(d / "real", synthetic=d / "real").inputs["grid_rate_hz"] == 100.0  # none recorded
    with pytest.raises(ArgumentError, match=r"^rate_hz must be a finite number"):
        validate_datasets(d / "real", synthetic=d / "synth", rate_hz=math.nan)


# ------------------------------------------------------------------ 5. records refuse what they cannot hold
def _walk(n: int = 1000):
    tt = np.arange(n) * 0.01
    return Truth(t_s=tt, pos_enu_m=np.c_[tt, 0 * tt, 0 * tt], vel_enu_mps=np.c_[1 + 0 * tt, 0 * tt, 0 * tt])


def test_trace_refuses_a_negative_anchor_index_and_an_empty_truth():
    anchors = Anchors(ids=("A", "B"), pos_enu_m=[[0, 5, 0], [10, 5, 0]])
    tu = np.arange(0.05, 9.9, 0.1)
    with pytest.raises(ValueError, match=r"outside the anchor layout \(0 \.\. 1\): -1 \.\. 1"):
        Trace(truth=_walk(), anchors=anchors, uwb=Uwb(t_s=tu, anchor=np.r_[-1, np.ones(tu.size - 1)],
                                                      range_m=np.full(tu.size, 5.0)))
    with pytest.raises(ValueError, match=r"^truth: no samples"):
        Truth(t_s=[], pos_enu_m=np.zeros((0, 3)), vel_enu_mps=np.zeros((0, 3)))
    ok = Trace(truth=_walk(), anchors=anchors, uwb=Uwb(t_s=tu, anchor=np.ones(tu.size), range_m=np.full(tu.size, 5.0)))
    assert ok.duration_s == pytest.approx(9.99)


# ------------------------------------------------------------------ 6. a trip too short for a trace, refused everywhere
def test_generate_traces_refuses_the_short_trip_generate_dataset_refuses(tmp_path):
    d = simple_scenario_dict(**{"path.waypoints_enu_m": [[0, 0, 0], [0.005, 0, 0], [0.01, 0, 0]]})
    short = load_scenario(d)
    with pytest.raises(ScenarioError) as by_dataset:
        generate_dataset(short, 1, tmp_path / "ds", seed=1)
    assert "fewer than 10" in str(by_dataset.value)
    for call in (lambda: generate_traces(short, 1, seed=1), lambda: generate_trace(short, 0, 1),
                 lambda: compile_scenario(short)):
        with pytest.raises(ScenarioError) as refused:
            call()
        assert str(refused.value) == str(by_dataset.value)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ 7. no empty datasets
def test_write_dataset_refuses_no_traces_and_writes_nothing(tmp_path):
    for empty in ([], iter(()), (t for t in [])):
        with pytest.raises(ArgumentError, match=r"^no traces to write to .*: a dataset holds at least one trace$"):
            write_dataset(tmp_path / "ds", empty)
    assert list(tmp_path.iterdir()) == []


def test_write_dataset_streams_a_generator(scn, tmp_path):
    write_dataset(tmp_path / "ds", generate_traces(scn, 2, seed=4))
    assert [t.meta["spawn_key"] for t in read_dataset(tmp_path / "ds").traces] == [[0], [1]]


# ------------------------------------------------------------------ 8. scenario names, files, mappings; one dataset
def test_calibrate_datasets_takes_one_path(traces, tmp_path, monkeypatch):
    import physynth.calibrate

    write_dataset(tmp_path / "ds", traces)
    seen = {}
    monkeypatch.setattr(physynth.calibrate, "calibrate",
                        lambda trs, sources, **kw: seen.setdefault(len(seen), (len(trs), sources)))
    for given in (str(tmp_path / "ds"), tmp_path / "ds", [tmp_path / "ds"]):
        calibrate_datasets(given)
    assert list(seen.values()) == [(2, [str(tmp_path / "ds")])] * 3


def test_generation_takes_a_preset_name_a_file_or_a_mapping(scn, tmp_path):
    save_scenario(scn, tmp_path / "s.yaml")
    as_dict = scenario_to_dict(scn)
    for given in (tmp_path / "s.yaml", str(tmp_path / "s.yaml"), as_dict):
        assert _same(next(physynth.generate_traces(given, 1, seed=2)), generate_trace(scn, 0, 2))
        assert _same(physynth.generate_trace(given, 1, 2), generate_trace(scn, 1, 2))
    preset = next(physynth.generate_traces("cablecar-descending", 1, seed=2))
    assert _same(preset, generate_trace(load_scenario("cablecar-descending"), 0, 2))
    path, _ = generate_dataset(str(tmp_path / "s.yaml"), 1, tmp_path / "ds", seed=2)
    assert json.loads((path / "dataset.json").read_text())["scenario_name"] == "short"
    with pytest.raises(ScenarioError, match=r"^expected a Scenario, got str \(physynth.load_scenario"):
        generate_traces("cablecar-descending", 1, seed=1)  # physynth.generate's own takes Scenario objects


def test_load_scenario_takes_a_mapping_and_refuses_other_types(scn):
    assert load_scenario(scenario_to_dict(scn)) == scn
    assert load_scenario(scn) is scn
    assert physynth.scenario_from_dict(scenario_to_dict(scn)) == scn
    bad = scenario_to_dict(scn)
    bad["channel"]["los_std_m"] = -1
    with pytest.raises(ScenarioError, match=r"^scenario <dict>: field channel\.los_std_m"):
        load_scenario(bad)
    bad["channel"]["los_std_m"] = math.nan
    with pytest.raises(ScenarioError, match=r"^scenario <dict>: field channel\.los_std_m: must be a finite number"):
        load_scenario(bad)
    for other in (123, None, ["cablecar-descending"]):
        with pytest.raises(ScenarioError, match=r"^a scenario is a preset name, a scenario file, a mapping or a "
                                                r"Scenario, got "):
            load_scenario(other)


# ------------------------------------------------------------------ 9. importer parameters
@pytest.mark.parametrize(("kwargs", "match"), [
    ({"tag_height_offset_m": math.nan}, r"^tag_height_offset_m must be a finite number, got nan m$"),
    ({"burst_gap_s": -1}, r"^burst_gap_s must be positive, got -1 s$"),
    ({"burst_gap_s": 0.0}, r"^burst_gap_s must be positive"),
    ({"burst_gap_s": math.inf}, r"^burst_gap_s must be a finite number"),
    ({"velocity_window_s": 0}, r"^velocity_window_s must be positive"),
])
def test_import_hanyang_checks_its_parameters_before_reading(tmp_path, kwargs, match):
    with pytest.raises(ArgumentError, match=match):
        import_hanyang(tmp_path / "no-such-run", **kwargs)


def test_import_csv_checks_its_parameters_before_reading(tmp_path):
    with pytest.raises(ArgumentError, match=r"^burst_gap_s must be positive"):
        import_csv(tmp_path / "no-such-recording", burst_gap_s=0)
    with pytest.raises(ArgumentError, match=r"^velocity_window_s must be a finite number"):
        import_csv(tmp_path / "no-such-recording", velocity_window_s=math.nan)


def test_argument_errors_are_phys_synth_errors_and_value_errors():
    assert issubclass(ArgumentError, PhySynthError) and issubclass(ArgumentError, ValueError)
