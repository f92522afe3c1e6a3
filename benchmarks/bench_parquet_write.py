"""What each change to the Parquet writing of ``generate`` gives, side by side in one run (issue 45).

    python benchmarks/bench_parquet_write.py [-n N] [--repeat R]

Variants, alternated ``R`` times (best of each kept), each generating the same ``N`` traces to Parquet in
this process (one shard, ``generate_dataset(workers=1, shard_traces=N)``), against generating them in
memory:

- ``rg16+reread``: row groups of 16 traces, tables hashed by reading them again at close (before 2026-12-05);
- ``rg64+reread``: row groups of 64 traces;
- ``rg16+stream``: the SHA-256 taken while writing, row group by row group (``DatasetWriter.hash_while_writing``
  now; read back right behind pyarrow's own file, ``integrity.TrailingHash``);
- ``rg64+stream``: both;
- ``rg64+stream+thread``: and the row groups encoded and written in a writer thread while the next traces
  are made (``DatasetWriter.write_in_thread``);
- ``rg16+stream+thread``, ``rg32+stream+thread``: the same with row groups of 16 and 32 traces (the last
  row group of a shard is written after its last trace is made, while nothing else runs: the smaller, the
  less of the writing is left without a trace to overlap);
- ``rg16+process``: what ``generate`` on one worker does for 500 traces or more where a core is to spare: this
  process generates, a writer process of its own (:mod:`physynth.io.writer_process`, started by the run)
  writes, with row groups of 16 traces and the streamed hash, here whatever ``N`` (``generate`` itself hands
  runs of fewer than :data:`~physynth.io.writer_process.MIN_TRACES` traces to the writer thread instead, as
  ``rg16+stream+thread``). The variants above write in this process (``generate_dataset(writer_process=False)``).

Prints the wall-clock and CPU time (this process; for ``rg16+process`` also the writer process's, which
includes its start) per trace and the rate to Parquet as a fraction of the in-memory rate. On a shared
machine prefer the CPU figures; the writer process only pays where the other core is free.
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
from physynth.io import shards, writer_process  # noqa: E402
from physynth.io.dataset import DatasetWriter  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.workflows import generate_dataset  # noqa: E402

VARIANTS = {"rg16+reread": (16, False, False), "rg64+reread": (64, False, False),
            "rg16+stream": (16, True, False), "rg64+stream": (64, True, False), "rg64+stream+thread": (64, True, True),
            "rg16+stream+thread": (16, True, True), "rg32+stream+thread": (32, True, True),
            "rg16+process": (16, True, True)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    scn = load_scenario("cablecar-descending")
    cs = compile_scenario(scn)
    generate_trace(cs, 0, 0)
    tmp = Path(tempfile.mkdtemp(prefix="bench-pq-"))
    best = {k: (float("inf"), float("inf")) for k in ("memory", *VARIANTS)}
    child_cpu = float("inf")
    try:
        generate_dataset(scn, 2, tmp / "warm", seed=1)
        for r in range(args.repeat):
            for name in ("memory", *VARIANTS):
                w0, c0, k0 = time.perf_counter(), time.process_time(), _children_cpu()
                if name == "memory":
                    for i in range(args.n):
                        generate_trace(cs, i, r)
                else:
                    (shards.ROW_GROUP_TRACES, DatasetWriter.hash_while_writing,
                     DatasetWriter.write_in_thread) = VARIANTS[name]
                    writer_process.MIN_TRACES = 1  # the process for any N (only +process asks for it)
                    path, _ = generate_dataset(scn, args.n, tmp / name, seed=r, shard_traces=args.n,
                                               writer_process=name.endswith("+process"))
                    shutil.rmtree(path)
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                if name.endswith("+process"):
                    child_cpu = min(child_cpu, _children_cpu() - k0)
                best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    mem_wall, mem_cpu = best["memory"]
    print(f"{args.n} traces, best of {args.repeat}, load {os.getloadavg()[0]:.1f}")
    print(f"{'variant':19s} {'wall ms/trace':>14s} {'cpu ms/trace':>13s} {'rate/memory wall':>17s} {'cpu':>6s}")
    for name, (wall, cpu) in best.items():
        print(f"{name:19s} {1e3 * wall / args.n:14.1f} {1e3 * cpu / args.n:13.1f} {mem_wall / wall:17.2f} "
              f"{mem_cpu / cpu:6.2f}")
    print(f"{'(writer process)':19s} {'':14s} {1e3 * child_cpu / args.n:13.1f}")


def _children_cpu() -> float:
    """CPU time of the child processes that ended (the writer process of each run)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


if __name__ == "__main__":
    main()
