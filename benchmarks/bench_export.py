"""Each export against generating the same traces to Parquet, as whole commands, side by side (issue 45).

    python benchmarks/bench_export.py [-n N] [--repeat R] [--workers W] [--formats hdf5,csv,rosbag2] [--dir D]

Per repetition: ``physynth generate -n N`` (to Parquet, ``--workers W``), then ``physynth export`` of that
dataset to hdf5, csv and rosbag2 (MCAP, the default storage) with ``--workers W``, each a process of its
own (start-up and imports included, as a user runs them); every output is removed once timed. Prints the
best time of each over the repetitions, its ratio to the generation's, and the peak resident memory of
the command's whole process tree (workers, Dask scheduler and nannies included; sampled every 0.1 s on
a thread of its own: the time is taken when the command ends, not at the next sample), and how quiet
the machine was: the share of the cores' time other processes took during the run
(``physynth.bench.OthersCpu``).
Every command starts after ``sync`` (what the one before wrote is on disk: no command pays for another's
writeback); the files go to a new folder in ``--dir`` (default: the system's temporary folder).
``physynth bench --exports`` measures the same in one process (no start-up).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil


def tree_rss(proc: psutil.Process) -> int:
    """Resident bytes of ``proc`` and every process below it (workers, the Dask scheduler and nannies)."""
    total = 0
    for p in (proc, *proc.children(recursive=True)):
        try:
            total += p.memory_info().rss
        except psutil.Error:  # ended meanwhile
            pass
    return total


def timed(argv: list[str], peaks: dict[str, float], key: str) -> float:
    """Run ``physynth argv`` as a process of its own; its wall time, and the peak of its process tree's
    resident memory (sampled every 0.1 s) kept in ``peaks[key]`` [GB]."""
    os.sync()  # the writes of the command before on disk first
    t0 = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "physynth", *argv, "-q"])
    proc, peak, done = psutil.Process(child.pid), [0], threading.Event()

    def sample() -> None:  # on a thread, so that the end of the command is seen at once, not at the next sample
        while True:
            try:
                peak[0] = max(peak[0], tree_rss(proc))
            except psutil.Error:  # the command ended meanwhile
                return
            if done.wait(0.1):
                return

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    child.wait()
    wall = time.perf_counter() - t0
    done.set()
    sampler.join()
    peak = peak[0]
    if child.returncode:
        raise SystemExit(f"physynth {' '.join(argv)} failed (exit {child.returncode})")
    peaks[key] = max(peaks.get(key, 0.0), peak / 1e9)
    return wall


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--formats", default="hdf5,csv,rosbag2", help="the exports to time (comma-separated)")
    ap.add_argument("--dir", default=None, help="where the datasets and exports are written")
    args = ap.parse_args()
    formats = [f for f, m in (("hdf5", "h5py"), ("csv", None), ("rosbag2", "rosbags"))
               if f in args.formats.split(",") and (m is None or importlib.util.find_spec(m) is not None)]
    from physynth.bench import OthersCpu

    others = OthersCpu()
    tmp = Path(tempfile.mkdtemp(prefix="bench-export-", dir=args.dir))
    best = {k: float("inf") for k in ("parquet", *formats)}
    peaks: dict[str, float] = {}
    try:
        for r in range(args.repeat):
            ds = tmp / "ds"
            best["parquet"] = min(best["parquet"], timed(["generate", "-n", str(args.n), "--seed", str(r), "--out",
                                                          str(ds), "--overwrite", "-w", str(args.workers)],
                                                         peaks, "parquet"))
            for fmt in formats:
                out = tmp / f"out.{fmt}"
                best[fmt] = min(best[fmt], timed(["export", str(ds), "-f", fmt, "-o", str(out), "-w",
                                                  str(args.workers)], peaks, fmt))
                shutil.rmtree(out) if out.is_dir() else out.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{args.n} traces, {args.workers} worker(s), whole commands, best of {args.repeat}")
    for k, v in best.items():
        print(f"{k:10s} {v:8.2f} s  {v / best['parquet']:5.2f}x generate to Parquet   peak memory {peaks[k]:.2f} GB")
    share = others.share()  # the commands are this process's children, waited for: their time is its own
    if share is not None:
        print(f"other processes: {100 * share:.0f} % of the cores during the run")


if __name__ == "__main__":
    main()
