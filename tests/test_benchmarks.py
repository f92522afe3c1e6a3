"""The benchmarks run: each on a tiny size (a smoke test, as navlie runs its examples), so that none rots
unseen. They print figures and assert nothing about speed (performance is read from their output, not
tested); here each must finish, exit 0 and print the line it promises. The ones that need an optional
package the test install lacks (imusim), the shared real data or minutes of work only start with
``--help``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
ALL = sorted(p.stem for p in BENCH.glob("bench_*.py"))

# benchmark -> (arguments of a run on a tiny size, a text its output must hold)
TINY = {
    "bench_export": (["-n", "2", "--repeat", "1", "--formats", "hdf5,csv"], "x generate to Parquet"),
    "bench_parquet_write": (["-n", "2", "--repeat", "1"], "rg16+stream+thread"),
    "bench_cpu_per_trace": (["2"], "CPU per trace"),
    "bench_stages": (["-n", "2"], "traces/s per core"),
    "bench_variation": (["-n", "2", "--rounds", "1"], "CPU ms per trace"),
    "bench_generate": (["-n", "2", "--repeat", "1"], "to Parquet:"),
    "bench_validate": (["-n", "2", "--repeat", "1"], "generate + reduce + statistics"),
    "bench_cli": (["--repeat", "1"], "first trace"),
    "bench_bag_zstd": (["-n", "1", "--repeat", "1"], "ms CPU per trace"),
    "bench_export_floor": (["-n", "2", "--repeat", "1", "--exports"], "export rosbag2"),
    "bench_writer_interference": (["-n", "2", "--repeat", "1", "--settle", "0.2"], "process"),
}
HELP_ONLY = {"bench_anchor_study", "bench_calibrate", "bench_dask_overhead", "bench_imu_vs_imusim", "bench_inspect"}


def _run(name: str, *args: str, cwd: Path) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, str(BENCH / f"{name}.py"), *args], capture_output=True, text=True,
                         timeout=300, cwd=cwd, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_every_benchmark_is_run_here():
    assert ALL, "no benchmarks found"
    assert set(ALL) == set(TINY) | HELP_ONLY, sorted(set(ALL) ^ (set(TINY) | HELP_ONLY))


@pytest.mark.parametrize("name", sorted(TINY))
def test_benchmark_on_a_tiny_size(name, tmp_path):
    args, promised = TINY[name]
    out = _run(name, *args, cwd=tmp_path)
    assert promised in out, out[-2000:]


@pytest.mark.parametrize("name", sorted(HELP_ONLY))
def test_benchmark_help(name, tmp_path):
    assert "usage" in _run(name, "--help", cwd=tmp_path).lower()
