"""Peak memory and time of ``physynth inspect`` on a large dataset (streamed: memory must not grow with it).

    python benchmarks/bench_inspect.py DATASET            # an existing dataset
    python benchmarks/bench_inspect.py --generate 10000   # generate it first (all cores), then inspect

Runs ``physynth inspect DATASET --json --quiet`` as a child process and prints its wall time and peak
resident memory (the child's ru_maxrss), with the number of traces and the machine's load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

PHYSYNTH = [sys.executable, "-m", "physynth.cli"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", type=Path, default=Path("runs/bench-inspect"))
    ap.add_argument("--generate", type=int, default=0, help="generate this many default traces first")
    ap.add_argument("--seed", type=int, default=2026)
    args = ap.parse_args()
    if args.generate:
        t0 = time.perf_counter()
        subprocess.run([*PHYSYNTH, "generate", "-n", str(args.generate), "--seed", str(args.seed), "-q",
                        "--out", str(args.dataset), "--overwrite"], check=True)
        print(f"generated {args.generate} traces in {time.perf_counter() - t0:.0f} s")
    size = sum(f.stat().st_size for f in args.dataset.rglob("*") if f.is_file())
    t0 = time.perf_counter()
    out = subprocess.run([*PHYSYNTH, "inspect", str(args.dataset), "--json", "-q"], check=True,
                         capture_output=True, text=True).stdout
    wall = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    m = json.loads(out)
    n = json.loads((args.dataset / "dataset.json").read_text())["n_traces"]
    print(f"inspect {args.dataset}: {n} traces, {size / 1e9:.1f} GB on disk")
    print(f"  wall time {wall:.0f} s ({n / wall:.0f} traces/s), peak RSS {peak_mb:.0f} MB")
    print(f"  uwb_ge1_frac {m['uwb_ge1_frac']:.4f}, residual median {m['residual_median_m']:.4f} m, "
          f"abs P95 {m['abs_residual_p95_m']:.3f} m")
    print(f"  machine: {os.cpu_count()} core(s), load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
