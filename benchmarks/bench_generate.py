"""Generation throughput of the default preset: traces per second in memory and written to Parquet,
and peak memory. A benchmark that prints figures, not a timed test.

    python benchmarks/bench_generate.py [--scenario NAME] [-n N] [--repeat R]

Runs on one core (the generator is single-threaded; BLAS threads are pinned to 1 below).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from physynth.generate import compile_scenario, generate_trace  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.workflows import generate_dataset  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cablecar-descending")
    ap.add_argument("-n", type=int, default=500, help="traces per measurement")
    ap.add_argument("--repeat", type=int, default=3, help="measurements; the best is reported")
    args = ap.parse_args()

    scn = load_scenario(args.scenario)
    cs = compile_scenario(scn)
    generate_trace(cs, 0, 0)  # warm-up (imports, caches)
    t = generate_trace(cs, 0, 0)
    print(f"scenario {scn.name}: one trace = {t.duration_s:.1f} s, {t.imu.t_s.size} IMU samples at "
          f"{scn.imu.rate_hz:.0f} Hz, {len(t.uwb)} UWB rows, {t.truth.t_s.size} truth rows")

    best_mem = 0.0
    for r in range(args.repeat):
        t0 = time.perf_counter()
        for i in range(args.n):
            generate_trace(cs, i, r)
        best_mem = max(best_mem, args.n / (time.perf_counter() - t0))
    print(f"in memory : {best_mem:8.1f} traces/s  ({1e3 / best_mem:.2f} ms per trace, "
          f"best of {args.repeat} x {args.n})")

    tmp = Path(tempfile.mkdtemp(prefix="physynth-bench-"))
    best_pq = 0.0
    size = 0
    try:
        for r in range(args.repeat):
            out = tmp / f"ds{r}"
            t0 = time.perf_counter()
            generate_dataset(scn, args.n, out, seed=r)
            best_pq = max(best_pq, args.n / (time.perf_counter() - t0))
            size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
            shutil.rmtree(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"to Parquet: {best_pq:8.1f} traces/s  ({size / args.n / 1e6:.2f} MB per trace on disk)")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory (max RSS of this process): {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
