"""What the libraries alone take of an export, against generating the same traces to Parquet (issue 45).

    python benchmarks/bench_export_floor.py [-n N] [--repeat R] [--dir D] [--exports]

An export cannot be faster than the work it hands to the libraries that write its format. This measures
that work alone, in one run beside the generation it is compared with:

- ``generate``: ``physynth generate -n N --workers 1`` as a whole command (start-up included), as
  ``benchmarks/bench_export.py`` times it;
- ``csv``: polars' ``write_csv`` of every table of the dataset, row group by row group, the tables at the
  same time on threads of their own, into files in ``--dir`` written behind, as the export writes them.
  Left out: the process's start, the check of the input against its integrity record, and the reading
  and decoding of the Parquet files (each part read whole before its writing is timed);
- ``format``: the same into ``/dev/null``: the formatting alone, no file written;
- ``rosbag2``: zstd compression of every chunk of the bags at the export's setting
  (``physynth.io.export.mcap``), on one thread per core as the export compresses, 32 traces at a time.
  Left out: everything else (the message records are built before their compression is timed), and
  nothing is written;
- with ``--exports``: ``physynth export -f csv`` and ``-f rosbag2`` of the same dataset, ``--workers 1``,
  whole commands, as ``benchmarks/bench_export.py`` times them: the floors beside what they bound.

Prints the best wall time of each over ``R`` repetitions (csv, format and rosbag2: summed over the parts
or batches, each timed alone, so that a thread that finishes first waits for the others), its ratio to
the generation's, the target of issue 45 it is held against (CSV no slower than generating; bags at most
twice), and its CPU time (every thread's, system time included) and that time spread evenly over the
cores as a ratio: the shortest the work could take. A floor near or above its target: no export of that
format meets the target on this machine while it writes the same bytes with the same library.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench_export import timed

TARGETS = {"csv": 1.0, "rosbag2": 2.0}


def csv_floor(ds: Path, out: Path | None) -> tuple[float, float]:
    """``(seconds, CPU seconds)`` polars takes to write the tables of ``ds`` as CSV, row group by row group,
    the tables of a part at the same time, each on a thread of its own, as the export writes them: into
    files in the new folder ``out``, written behind as the export writes them (:mod:`physynth.io.pagecache`),
    or None: formatted into ``/dev/null``. The reading of each part (all its row groups, decoded) is not
    timed; CPU: this process's, every thread's, system time included."""
    import polars as pl
    import pyarrow.parquet as pq

    from physynth.io.dataset import TABLES, read_meta, table_files
    from physynth.io.pagecache import WriteBehind

    meta = read_meta(ds)
    files = {name: table_files(ds, name, meta) for name in TABLES}
    if out is not None:
        out.mkdir()
    sinks = {name: open(os.devnull if out is None else out / f"{name}.csv", "wb") for name in TABLES}
    behind = {name: WriteBehind(fh.fileno()) for name, fh in sinks.items()}

    def write(name: str, groups: list[pl.DataFrame], header: bool) -> None:
        fh = sinks[name]
        for i, g in enumerate(groups):
            g.write_csv(fh, include_header=header and i == 0)
            if out is not None:
                fh.flush()
                behind[name].advance(fh.tell())

    wall = cpu = 0.0
    try:
        with ThreadPoolExecutor(len(TABLES)) as pool:
            for k in range(max(len(f) for f in files.values())):
                parts = {name: [pl.from_arrow(pf.read_row_group(g)) for g in range(pf.metadata.num_row_groups)]
                         for name, f in files.items() if k < len(f) for pf in [pq.ParquetFile(f[k])]}
                t0, c0 = time.perf_counter(), os.times()
                list(pool.map(lambda item, first=k == 0: write(*item, header=first), parts.items()))
                c1 = os.times()
                wall += time.perf_counter() - t0
                cpu += c1.user + c1.system - c0.user - c0.system
    finally:
        for fh in sinks.values():
            fh.close()
    return wall, cpu


def zstd_floor(ds: Path, batch: int = 32) -> tuple[float, float, int, int]:
    """``(seconds, CPU seconds, raw bytes, compressed bytes)``: zstd at the export's setting on every chunk
    of the bags of ``ds`` on one thread per core, ``batch`` traces at a time (building their records is not
    timed)."""
    import itertools

    from bench_bag_zstd import chunks_of_trace

    from physynth.io.dataset import iter_traces
    from physynth.io.export import mcap
    from physynth.parallel import available_cores

    compress = mcap._compressor("zstd")
    wall = cpu = 0.0
    raw = packed = 0
    traces = iter_traces(ds)
    with ThreadPoolExecutor(available_cores()) as pool:
        list(pool.map(compress, [b"warm-up"] * available_cores()))  # each thread's context made once
        while chunks := [c for trace in itertools.islice(traces, batch) for c in chunks_of_trace(trace)]:
            t0, c0 = time.perf_counter(), os.times()
            packed += sum(pool.map(lambda c: len(compress(c)), chunks))
            c1 = os.times()
            wall, cpu = wall + time.perf_counter() - t0, cpu + c1.user + c1.system - c0.user - c0.system
            raw += sum(map(len, chunks))
    return wall, cpu, raw, packed


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--dir", default=None, help="where the dataset is written")
    ap.add_argument("--exports", action="store_true", help="also time the exports themselves (whole commands)")
    args = ap.parse_args()
    if args.n < 1 or args.repeat < 1:
        ap.error("-n and --repeat must be at least 1")
    if args.dir is not None and not Path(args.dir).is_dir():
        ap.error(f"--dir {args.dir} is not an existing folder")
    from physynth.bench import OthersCpu

    others = OthersCpu()
    from physynth.parallel import available_cores

    cores = available_cores()
    tmp = Path(tempfile.mkdtemp(prefix="bench-floor-", dir=args.dir))
    best = {k: (float("inf"), 0.0) for k in ("generate", "csv", "format", "rosbag2")}
    exports = {k: float("inf") for k in (("csv", "rosbag2") if args.exports else ())}
    sizes = (0, 0)
    try:
        for r in range(args.repeat):
            ds = tmp / "ds"
            best["generate"] = min(best["generate"], (timed(
                ["generate", "-n", str(args.n), "--seed", str(r), "--out", str(ds), "--overwrite", "-w", "1"], {},
                "generate"), 0.0))
            os.sync()
            best["csv"] = min(best["csv"], csv_floor(ds, tmp / "csv"))
            shutil.rmtree(tmp / "csv")
            best["format"] = min(best["format"], csv_floor(ds, None))
            wall, cpu, *sizes = zstd_floor(ds)
            best["rosbag2"] = min(best["rosbag2"], (wall, cpu))
            for fmt in exports:
                out = tmp / f"out.{fmt}"
                exports[fmt] = min(exports[fmt], timed(["export", str(ds), "-f", fmt, "-o", str(out), "-w", "1"], {},
                                                       fmt))
                shutil.rmtree(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    gen = best["generate"][0]
    print(f"{args.n} traces, best of {args.repeat}")
    print(f"{'generate':9s} {gen:7.2f} s  (physynth generate -w 1, whole command)")
    notes = {"csv": "polars write_csv of the decoded tables, into files",
             "format": "the same into /dev/null (formatting alone)",
             "rosbag2": f"zstd alone, {sizes[0] / args.n / 1e6:.1f} -> {sizes[1] / args.n / 1e6:.2f} MB per trace"}
    for k in ("csv", "format", "rosbag2"):
        wall, cpu = best[k]
        target = TARGETS.get(k, TARGETS["csv"])
        print(f"{k:9s} {wall:7.2f} s  {wall / gen:5.2f}x generate (target {target:.0f}x: "
              f"{'above' if wall / gen > target else 'below'}), {cpu:6.2f} s of CPU = {cpu / cores / gen:4.2f}x "
              f"spread over the {cores} cores  {notes[k]}")
    for fmt, t in exports.items():
        print(f"export {fmt:9s} {t:7.2f} s  {t / gen:5.2f}x generate (physynth export -w 1, whole command)")
    share = others.share()
    if share is not None:
        print(f"other processes: {100 * share:.0f} % of the cores during the run")


if __name__ == "__main__":
    main()
