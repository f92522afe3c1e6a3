"""Each export against generating the same traces to Parquet, as whole commands, side by side (issue 45).

    python benchmarks/bench_export.py [-n N] [--repeat R] [--workers W]

Per repetition: ``physynth generate -n N`` (to Parquet, ``--workers W``), then ``physynth export`` of that
dataset to hdf5, csv and rosbag2 (MCAP, the default storage) with ``--workers W``, each a process of its
own (start-up and imports included, as a user runs them); every output is removed once timed. Prints the
best time of each over the repetitions and its ratio to the generation's. ``physynth bench --exports``
measures the same in one process (no start-up).
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "physynth", *argv, "-q"], check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    formats = [f for f, m in (("hdf5", "h5py"), ("csv", None), ("rosbag2", "rosbags"))
               if m is None or importlib.util.find_spec(m) is not None]
    tmp = Path(tempfile.mkdtemp(prefix="bench-export-"))
    best = {k: float("inf") for k in ("parquet", *formats)}
    try:
        for r in range(args.repeat):
            ds = tmp / "ds"
            best["parquet"] = min(best["parquet"], timed(["generate", "-n", str(args.n), "--seed", str(r), "--out",
                                                          str(ds), "--overwrite", "-w", str(args.workers)]))
            for fmt in formats:
                out = tmp / f"out.{fmt}"
                best[fmt] = min(best[fmt], timed(["export", str(ds), "-f", fmt, "-o", str(out), "-w",
                                                  str(args.workers)]))
                shutil.rmtree(out) if out.is_dir() else out.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{args.n} traces, {args.workers} worker(s), whole commands, best of {args.repeat}")
    for k, v in best.items():
        print(f"{k:10s} {v:8.2f} s  {v / best['parquet']:5.2f}x generate to Parquet")


if __name__ == "__main__":
    main()
