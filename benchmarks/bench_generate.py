"""Generation throughput of the default preset: traces per second in memory and written to Parquet,
and peak memory; and the CPU time of writing alone. A benchmark that prints figures, not a timed test.

    python benchmarks/bench_generate.py [--scenario NAME] [-n N] [--repeat R] [--body]

``--body`` also measures the same scenario with the body-frame IMU (``imu_frames`` ENU + body, and
body only; tangent attitude), interleaved with the ENU-only runs so that all see the same load.

Runs on one core (the generator is single-threaded; BLAS threads are pinned to 1 below). On a shared
machine the wall-clock rate drops with the load; the rate by CPU time of this process (printed too)
is closer to what one free core gives.
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
from physynth.scenario import scenario_from_dict, scenario_to_dict  # noqa: E402
from physynth.workflows import generate_dataset  # noqa: E402

WRITE_TRACES = 128
"""Traces of the write-only measurement (one shard of ``generate``), held in memory."""


def write_ms(scn, cs, n: int, repeat: int) -> float:
    """CPU time [ms] per trace of writing ``n`` traces generated beforehand as one shard (what
    ``generate`` does per shard: Parquet tables, SHA-256 records, atomic swap), best of ``repeat``."""
    from physynth.io.shards import write_shard

    traces = [generate_trace(cs, i, 0) for i in range(n)]
    meta = {"imu_frames": list(scn.imu_frames)}
    best = float("inf")
    with tempfile.TemporaryDirectory(prefix="physynth-bench-") as tmp:
        for r in range(repeat):
            (Path(tmp) / f"p{r}").mkdir()
            c0 = time.process_time()
            write_shard(Path(tmp) / f"p{r}", 0, enumerate(traces), meta)
            best = min(best, time.process_time() - c0)
    return 1e3 * best / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cablecar-descending")
    ap.add_argument("-n", type=int, default=500, help="traces per measurement")
    ap.add_argument("--repeat", type=int, default=3, help="measurements; the best is reported")
    ap.add_argument("--body", action="store_true", help="also measure with the body-frame IMU (side by side)")
    args = ap.parse_args()

    scn = load_scenario(args.scenario)
    cs = compile_scenario(scn)
    generate_trace(cs, 0, 0)  # warm-up (imports, caches)
    t = generate_trace(cs, 0, 0)
    print(f"scenario {scn.name}: one trace = {t.duration_s:.1f} s, {t.imu.t_s.size} IMU samples at "
          f"{scn.imu.rate_hz:.0f} Hz, {len(t.uwb)} UWB rows, {t.truth.t_s.size} truth rows")

    variants = {"enu": cs}
    if args.body:
        d = scenario_to_dict(scn)
        d["imu_frames"] = ["enu-gravity-free", "body-flu"]
        variants["enu+body"] = compile_scenario(scenario_from_dict(d, "bench"))
        d["imu_frames"] = ["body-flu"]
        variants["body"] = compile_scenario(scenario_from_dict(d, "bench"))
        for c in variants.values():
            generate_trace(c, 0, 0)
    best = dict.fromkeys(variants, 0.0)
    best_cpu = dict.fromkeys(variants, 0.0)
    for r in range(args.repeat):
        for name, c in variants.items():  # interleaved: both variants see the same load
            t0, c0 = time.perf_counter(), time.process_time()
            for i in range(args.n):
                generate_trace(c, i, r)
            best[name] = max(best[name], args.n / (time.perf_counter() - t0))
            best_cpu[name] = max(best_cpu[name], args.n / (time.process_time() - c0))
    for name, rate in best.items():
        print(f"in memory ({name:8s}): {rate:8.1f} traces/s  ({1e3 / rate:.2f} ms per trace, "
              f"best of {args.repeat} x {args.n}); by CPU time of this process {best_cpu[name]:8.1f} traces/s")
    if args.body:
        print(f"ratio enu+body / enu: {best['enu+body'] / best['enu']:.2f}, body / enu: "
              f"{best['body'] / best['enu']:.2f}")

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
    n_w = min(args.n, WRITE_TRACES)  # measured after the peak memory above: it holds its traces
    print(f"writing alone (one shard of {n_w} traces generated beforehand): "
          f"{write_ms(scn, cs, n_w, args.repeat):.2f} ms CPU per trace (best of {args.repeat})")


if __name__ == "__main__":
    main()
