"""How much a Parquet writer slows the generating thread beside it: as a thread of the same process, or as
a process of its own (the measurement behind docs/experiments.md, 2026-12-06).

    python benchmarks/bench_writer_interference.py [-n N] [--repeat R] [--settle S]

Generates ``N`` default traces in memory, timed, three ways, alternated ``R`` times:

- ``alone``: nothing else runs;
- ``thread``: a thread of this process writes Parquet tables in a loop meanwhile (the tables of a few
  generated traces, with the dataset's column options, each file hashed with SHA-256 after it is written:
  what ``DatasetWriter``'s writer thread does, without pause);
- ``process``: a process of its own does the same writes.

Prints, per way, the wall-clock and CPU time (the generating thread) per trace, best and worst of the
repetitions. On the 2-core machine the writing thread slowed generation by about 40 % and the writing
process not at all: threads of one process slow each other down where processes do not.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import multiprocessing as mp  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

SCENARIO = "cablecar-descending"
TABLES = ("imu", "truth", "uwb")


def write_loop(source: str, out: str, stop) -> None:  # noqa: ANN001 (a threading or multiprocessing Event)
    """Write the tables of the dataset ``source`` into ``out`` again and again, hashing each file, until
    ``stop`` is set."""
    import pyarrow.parquet as pq

    from physynth.io.tables import _column_options

    tables = {n: pq.read_table(Path(source) / f"{n}.parquet") for n in TABLES}
    options = {n: _column_options(t.schema, True) for n, t in tables.items()}
    k = 0
    while not stop.is_set():
        for name, table in tables.items():
            path = Path(out) / f"{name}{k % 4}.parquet"
            pq.write_table(table, path, **options[name])
            digest = hashlib.sha256()
            with open(path, "rb") as f:
                while block := f.read(1 << 20):
                    digest.update(block)
        k += 1


def timed(cs, n: int, seed: int) -> tuple[float, float]:  # noqa: ANN001
    from physynth.generate import generate_trace

    t0, c0 = time.perf_counter(), time.thread_time()
    for i in range(n):
        generate_trace(cs, i, seed)
    return (time.perf_counter() - t0) / n, (time.thread_time() - c0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", type=int, default=150, help="traces generated per measurement")
    ap.add_argument("--repeat", type=int, default=3, help="alternations of the three ways")
    ap.add_argument("--settle", type=float, default=2.0, help="seconds the writer runs before the timing starts")
    args = ap.parse_args()

    from physynth.generate import compile_scenario, generate_trace
    from physynth.io.scenario_file import load_scenario
    from physynth.workflows import generate_dataset

    scn = load_scenario(SCENARIO)
    work = Path(tempfile.mkdtemp(prefix="physynth-interference-"))
    try:
        source, _ = generate_dataset(scn, 8, work / "source", seed=0, workers=1)  # what the writer writes
        cs = compile_scenario(scn)
        generate_trace(cs, 0, 0)  # warm-up
        ctx = mp.get_context("spawn")
        rows: dict[str, list[tuple[float, float]]] = {"alone": [], "thread": [], "process": []}
        for r in range(args.repeat):
            for way in rows:
                out = work / f"out-{way}-{r}"
                out.mkdir()
                stop = ctx.Event() if way == "process" else threading.Event()
                runner = None
                if way != "alone":
                    kind = ctx.Process if way == "process" else threading.Thread
                    runner = kind(target=write_loop, args=(str(source), str(out), stop))
                    runner.start()
                    time.sleep(args.settle)  # the writer up and writing (a process imports pyarrow first)
                rows[way].append(timed(cs, args.n, r + 1))
                stop.set()
                if runner is not None:
                    runner.join()
                shutil.rmtree(out)
        print(f"{args.n} traces of {SCENARIO} generated in memory, {args.repeat} alternations, ms per trace")
        print(f"{'beside':10s} {'wall':>15s} {'CPU':>15s}")
        for way, got in rows.items():
            wall = sorted(1e3 * w for w, _ in got)
            cpu = sorted(1e3 * c for _, c in got)
            print(f"{way:10s} {wall[0]:6.2f} - {wall[-1]:6.2f} {cpu[0]:6.2f} - {cpu[-1]:6.2f}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
