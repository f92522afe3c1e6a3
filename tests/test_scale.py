"""Scale: streamed reading, streamed metrics, sharded generation on a real Dask cluster, resume after SIGKILL."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from physynth.errors import PhySynthError
from physynth.evaluate.metrics import MetricsAccumulator, compute_metrics, summarize
from physynth.evaluate.sketch import RELATIVE_ACCURACY, ZERO_TOLERANCE, Moments, QuantileSketch
from physynth.generate import compile_scenario, generate_trace
from physynth.io.dataset import iter_trace_meta, iter_traces, read_dataset
from physynth.io.scenario_file import load_scenario
from physynth.io.shards import partial_dir
from physynth.workflows import generate_dataset, inspect_dataset

SEED = 2026


@pytest.fixture(scope="module")
def scn():
    return load_scenario("cablecar-descending")


def _files(path: Path) -> dict[str, bytes]:
    """Every Parquet file of a dataset, by relative path, and the per-trace metadata."""
    out = {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*.parquet"))}
    out["traces"] = json.dumps(list(iter_trace_meta(path))).encode()
    return out


# ---------------------------------------------------------------- streaming statistics
def test_moments_match_numpy():
    rng = np.random.default_rng(1)
    x = rng.normal(3.0, 2.0, (1000, 3))
    m = Moments(3)
    for part in np.array_split(x, 7):
        m.add(part)
    assert np.allclose(m.std(), x.std(axis=0), rtol=1e-12)


def test_sketch_exact_then_bounded_relative_error():
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.standard_t(3, 200_000), [0.0, 1e-12]])
    exact = QuantileSketch(exact_limit=10**6)
    folded = QuantileSketch(exact_limit=5_000)
    for part in np.array_split(x, 40):
        exact.add(part)
        folded.add(part)
    q = np.array([0.0, 0.01, 0.25, 0.5, 0.95, 0.99, 1.0])
    assert not exact.folded and np.array_equal(exact.quantile(q), np.quantile(x, q))
    assert folded.folded and folded.n == x.size
    # each returned quantile is within the relative accuracy of a sample of (nearly) that rank
    got = folded.quantile(q)
    xs = np.sort(x)
    ranks = np.round(q * (x.size - 1)).astype(int)
    assert np.all(np.abs(got - xs[ranks]) <= RELATIVE_ACCURACY * np.abs(xs[ranks]) + 1e-9)
    # the size is bounded by the dynamic range, not by the number of values
    normal = QuantileSketch(exact_limit=5_000)
    for _ in range(5):
        normal.add(np.clip(rng.normal(0.0, 5.0, 200_000), -40.0, 40.0))
    normal.quantile(0.5)
    per_sign = np.ceil(np.log(40.0 / ZERO_TOLERANCE) / np.log((1 + RELATIVE_ACCURACY) / (1 - RELATIVE_ACCURACY))) + 1
    assert normal.n == 10**6 and normal.nbytes <= 16 * (2 * per_sign + 1) < 8 * normal.n
    assert folded.values(1000).size == 1000


def test_streamed_metrics_equal_exact_for_small_sets_and_close_when_sketched(scn):
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, SEED) for i in range(3)]
    exact = compute_metrics(traces)
    acc = MetricsAccumulator()
    acc.residual = QuantileSketch(exact_limit=1000)
    acc.abs_residual = QuantileSketch(exact_limit=1000)
    for t in traces:
        acc.add(summarize(t))
    sketched = acc.result()
    assert acc.residual.folded
    assert sketched.uwb_ge1_frac == exact.uwb_ge1_frac and sketched.n_residuals == exact.n_residuals
    for key in ("residual_median_m", "abs_residual_p95_m", "abs_residual_p99_m"):
        assert getattr(sketched, key) == pytest.approx(getattr(exact, key), rel=1e-3), key
    assert sketched.residual_std_m == pytest.approx(exact.residual_std_m, rel=1e-12)


# ---------------------------------------------------------------- streamed reading
def test_iter_traces_streams_parts_and_row_groups(scn, tmp_path):
    path, _ = generate_dataset(scn, 7, tmp_path / "ds", seed=SEED, shard_traces=3)
    assert sorted(p.name for p in (path / "uwb").iterdir()) == [f"part-0000{k}.parquet" for k in range(3)]
    cs = compile_scenario(scn)
    streamed = list(iter_traces(path))
    assert [t.meta["spawn_key"] for t in streamed] == [[i] for i in range(7)]
    for i, t in enumerate(streamed):
        ref = generate_trace(cs, i, SEED)
        assert np.array_equal(t.uwb.range_m, ref.uwb.range_m, equal_nan=True)
        assert np.array_equal(t.imu.acc_mps2, ref.imu.acc_mps2.astype(np.float32))  # stored as float32
        assert np.array_equal(t.truth.pos_enu_m, ref.truth.pos_enu_m)
    m, meta = inspect_dataset(path)
    assert meta["n_traces"] == 7 and m.n_traces == 7
    assert m.to_dict() == compute_metrics(read_dataset(path).traces).to_dict()


# ---------------------------------------------------------------- Dask: local cluster and an existing scheduler
def test_workers_on_a_local_cluster_give_the_same_files(scn, tmp_path):
    one, _ = generate_dataset(scn, 7, tmp_path / "one", seed=SEED, shard_traces=2, workers=1)
    two, _ = generate_dataset(scn, 7, tmp_path / "two", seed=SEED, shard_traces=2, workers=2)
    assert _files(one) == _files(two)
    assert not partial_dir(two).exists()


def test_existing_scheduler(scn, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=logging.ERROR) as cluster:
        path, _ = generate_dataset(scn, 5, tmp_path / "remote", seed=SEED, shard_traces=2,
                                   scheduler=cluster.scheduler_address)
    ref, _ = generate_dataset(scn, 5, tmp_path / "ref", seed=SEED, shard_traces=2)
    assert _files(path) == _files(ref)


def test_unreachable_scheduler_is_one_line(scn, tmp_path):
    pytest.importorskip("distributed")
    t0 = time.monotonic()
    with pytest.raises(PhySynthError, match="cannot connect to the Dask scheduler .*connection refused"):
        generate_dataset(scn, 4, tmp_path / "x", seed=1, shard_traces=2, scheduler="tcp://127.0.0.1:9")
    assert time.monotonic() - t0 < 5  # a refused connection fails at once, not after the client's 10 s of retries


# ---------------------------------------------------------------- resume after SIGKILL
def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "physynth.cli", *args]


def test_sigkill_then_resume_completes_identically(scn, tmp_path):
    out = tmp_path / "killed"
    n, shards = 48, 16  # killed after 2 of 16 shards (24 traces ended 0.3 s after the second on a fast machine)
    args = ["generate", "-n", str(n), "--seed", str(SEED), "--shard-traces", "3", "-w", "1", "-q", "--out", str(out)]
    proc = subprocess.Popen(_cli(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    part = partial_dir(out)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            if part.is_dir() and len(list(part.glob("shard-*"))) >= 2:
                break
            if proc.poll() is not None:
                pytest.fail(f"generation ended before it could be killed: {proc.stderr.read().decode()}")
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists(), "a killed run must not leave a dataset that looks finished"
    kept = sorted(p.name for p in part.glob("shard-*"))
    assert 2 <= len(kept) < shards
    # without --resume the unfinished run is not silently discarded
    r = subprocess.run(_cli(*args), capture_output=True, text=True)
    assert r.returncode == 2 and "--resume" in r.stderr and r.stderr.count("\n") == 1
    # a different seed cannot resume it
    bad = subprocess.run(_cli(*[a if a != str(SEED) else "7" for a in args], "--resume"), capture_output=True,
                         text=True)
    assert bad.returncode == 2 and "root_seed" in bad.stderr
    mtimes = {p.name: (p / "dataset.json").stat().st_mtime_ns for p in part.glob("shard-*")}
    done = subprocess.run(_cli(*args, "--resume"), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert not part.exists()
    ref, _ = generate_dataset(scn, n, tmp_path / "ref", seed=SEED, shard_traces=3)
    assert _files(out) == _files(ref)
    meta = json.loads((out / "dataset.json").read_text())
    assert "traces" not in meta and meta["n_traces"] == n  # several shards: per-trace metadata in parts
    assert [i for i, _ in iter_trace_meta(out)] == list(range(n))  # no duplicates, none missing
    assert len(mtimes) == len(kept)


# ---------------------------------------------------------------- resume: damaged shards are written again
def _stopped_run(scn, out: Path, n: int, shard_traces: int, after: int) -> list[str]:
    """A run stopped (as a kill would) once ``after`` traces are written; returns its complete shards."""
    def progress(message, done=None, total=None):
        if done is not None and done >= after:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_dataset(scn, n, out, seed=SEED, shard_traces=shard_traces, progress=progress)
    return sorted(p.name for p in partial_dir(out).glob("shard-*"))


def _damage(shard: Path, how: str) -> None:
    if how == "junk":
        (shard / "imu.parquet").write_text("junk\n")
    elif how == "flipped":  # same size: only the hash tells
        data = bytearray((shard / "uwb.parquet").read_bytes())
        data[len(data) // 2] ^= 0x01
        (shard / "uwb.parquet").write_bytes(bytes(data))
    else:
        (shard / how).unlink()


@pytest.mark.parametrize("how", ["junk", "flipped", "uwb.parquet", "dataset.json"])
def test_resume_writes_damaged_shards_again(tmp_path, capsys, how):
    from helpers import simple_scenario_dict

    from physynth.cli import main
    from physynth.io.scenario_file import load_scenario

    yaml_file = tmp_path / "walk.yaml"
    yaml_file.write_text(json.dumps(simple_scenario_dict()))  # JSON is YAML
    small = load_scenario(yaml_file)
    out = tmp_path / "R"
    kept = _stopped_run(small, out, 12, 2, after=7)
    assert kept[:3] == ["shard-00000", "shard-00001", "shard-00002"]
    _damage(partial_dir(out) / "shard-00001", how)
    with pytest.raises(SystemExit) as e:
        main(["generate", "-s", str(yaml_file), "-n", "12", "--seed", str(SEED), "--shard-traces", "2", "-w", "1",
              "--out", str(out), "--resume", "-q"])
        raise SystemExit(0)
    err = capsys.readouterr().err
    assert e.value.code == 0, err
    assert f"warning: 1 of the {len(kept)} complete shard(s)" in err and "written again" in err and "shard-00001" in err
    assert err.count("\n") == 1
    ref, _ = generate_dataset(small, 12, tmp_path / "ref", seed=SEED, shard_traces=2)
    assert _files(out) == _files(ref)  # byte for byte an uninterrupted run
    with pytest.raises(SystemExit) as e:
        main(["verify", str(out), "-q"])
        raise SystemExit(0)
    assert e.value.code == 0


def test_a_shard_damaged_before_assembly_is_not_assembled(tmp_path, monkeypatch):
    from helpers import simple_scenario

    from physynth.errors import DatasetError
    from physynth.io import shards

    finalize = shards.finalize

    def damaged_then_finalize(out, partial, plan, meta):
        _damage(partial / "shard-00001", "junk")
        return finalize(out, partial, plan, meta)

    monkeypatch.setattr(shards, "finalize", damaged_then_finalize)
    with pytest.raises(DatasetError, match="cannot finish .*shard-00001.*imu.parquet has 5 bytes"):
        generate_dataset(simple_scenario(), 6, tmp_path / "ds", seed=SEED, shard_traces=2)
    assert not (tmp_path / "ds").exists() and partial_dir(tmp_path / "ds").is_dir()  # resumable


def test_a_complete_run_is_recognised_by_resume(tmp_path):
    """What ``resume`` finds in an output that is already complete (:func:`physynth.io.shards.finished_run`)."""
    from helpers import simple_scenario

    from physynth.errors import IntegrityError
    from physynth.io.shards import finished_run
    from physynth.scenario import scenario_to_dict

    scn = simple_scenario()
    out, _ = generate_dataset(scn, 5, tmp_path / "ds", seed=SEED, shard_traces=2)
    d = scenario_to_dict(scn)
    assert finished_run(out, d, SEED, 5, 2) == SEED and finished_run(out, d, None, 5, 2) == SEED
    assert finished_run(tmp_path / "absent", d, SEED, 5, 2) is None
    for args, what in (((SEED + 1, 5, 2), "root_seed"), ((SEED, 6, 2), "n_traces"), ((SEED, 5, 3), "shard_traces")):
        with pytest.raises(PhySynthError, match=f"complete dataset, of a run that differs in {what}$"):
            finished_run(out, d, *args)
    with pytest.raises(PhySynthError, match="differs in scenario"):
        finished_run(out, {**d, "name": "other"}, SEED, 5, 2)
    _damage(out / "uwb", "part-00001.parquet")
    with pytest.raises(IntegrityError, match="uwb/part-00001.parquet is missing"):
        finished_run(out, d, SEED, 5, 2)


# ---------------------------------------------------------------- the command line in 80 columns
def test_inspect_and_scenarios_fit_80_columns(scn, tmp_path, capsys, monkeypatch):
    from physynth.cli import main

    monkeypatch.chdir(tmp_path)  # a short dataset path: the path itself is the user's
    generate_dataset(scn, 2, "ds", seed=SEED)
    for argv in (["inspect", "ds", "-q"], ["scenarios"], ["--version"]):
        try:
            main(argv)
        except SystemExit as e:
            assert e.code in (0, None)
        out = capsys.readouterr().out
        assert out.strip() and max(len(line) for line in out.splitlines()) <= 80, out
    assert out.startswith("physynth ")  # --version


def test_workers_without_dask_name_the_extra(tmp_path, capsys, monkeypatch):
    from physynth.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)  # as if Dask were not installed
    with pytest.raises(SystemExit) as e:
        main(["generate", "-n", "4", "--shard-traces", "2", "-w", "2", "--seed", "1", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "physynth[scale]" in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())  # nothing written, no unfinished run left behind
