"""CPU time per trace of the importable PhySynth, in memory and written with DatasetWriter; for A/B runs.

    python benchmarks/bench_cpu_per_trace.py [N]
    # against another version, side by side (e.g. the commit this branch started from):
    git archive b0eb964 src | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base/src python benchmarks/bench_cpu_per_trace.py 30; python benchmarks/bench_cpu_per_trace.py 30

Process CPU time (not wall time) is measured, best of three, so that a busy machine disturbs the
comparison less; alternate the two commands a few times and compare the ranges.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import inspect  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import physynth  # noqa: E402
from physynth.generate import compile_scenario, generate_trace  # noqa: E402
from physynth.io.dataset import DatasetWriter  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 30
    cs = compile_scenario(load_scenario("cablecar-descending"))
    generate_trace(cs, 0, 0)
    params = inspect.signature(DatasetWriter).parameters
    kw = {"compact": True, "row_group_traces": 16} if "compact" in params else {}  # as generate writes
    if "column_groups" in params:
        from physynth.io.dataset import generated_column_groups

        kw["column_groups"] = generated_column_groups(cs.scenario.imu_frames)
    best_m = best_p = float("inf")
    size = 0
    for _ in range(3):
        t0 = time.process_time()
        for i in range(n):
            generate_trace(cs, i, 1)
        best_m = min(best_m, time.process_time() - t0)
        tmp = Path(tempfile.mkdtemp())
        t0 = time.process_time()
        with DatasetWriter(tmp / "d", **kw) as w:
            for i in range(n):
                w.add(generate_trace(cs, i, 1), index=i)
        best_p = min(best_p, time.process_time() - t0)
        size = sum(f.stat().st_size for f in (tmp / "d").rglob("*") if f.is_file())
        shutil.rmtree(tmp)
    where = Path(physynth.__file__).parents[1]
    print(f"{where}: CPU per trace {1e3 * best_m / n:.2f} ms in memory, {1e3 * best_p / n:.2f} ms to Parquet, "
          f"{size / n / 1e6:.2f} MB per trace")


if __name__ == "__main__":
    main()
