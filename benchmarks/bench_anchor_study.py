"""Time of the anchor study (``physynth study anchors``): 6 counts x 3 regimes x N traces (default 50)
of the cable-car preset, GDOP and the ls/ekf tracker-error column included (the trackers on the first
``--tracker-traces`` traces of every cell, default as the command line), with 1 worker and with all
cores, and the figure written. A benchmark that prints figures, not a timed test; the target is under
3 minutes on 2 cores.

    python benchmarks/bench_anchor_study.py [--scenario NAME] [-n N] [--tracker-traces T] [--workers W ...]

The numbers are the same for every worker count (checked here); only the time differs.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.studies.anchors import (  # noqa: E402
    TRACKER_TRACES,
    GdopColumn,
    TrackerColumn,
    run_anchor_study,
    write_anchor_study,
)


def _same(a: dict, b: dict) -> bool:
    """Nested dicts of floats equal, NaN equal to NaN."""
    try:
        np.testing.assert_equal(a, b)
    except AssertionError:
        return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cablecar-descending")
    ap.add_argument("-n", type=int, default=50, help="traces per cell")
    ap.add_argument("--tracker-traces", type=int, default=TRACKER_TRACES,
                    help="traces per cell the trackers run on (0: no tracker column)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, os.cpu_count() or 1])
    args = ap.parse_args()
    scn = load_scenario(args.scenario)
    columns = (GdopColumn(),) + ((TrackerColumn(args.tracker_traces),) if args.tracker_traces else ())
    print(f"{args.scenario}: {len(scn.anchors)} counts x 3 regimes x {args.n} traces, trackers on "
          f"{min(args.tracker_traces, args.n)} per cell; {os.cpu_count()} core(s), "
          f"load average {os.getloadavg()[0]:.1f} (a shared machine makes the times noisy)")
    first = None
    for w in args.workers:
        t0 = time.perf_counter()
        study = run_anchor_study(scn, n=args.n, seed=2026, workers=w, columns=columns)
        with tempfile.TemporaryDirectory() as d:
            write_anchor_study(study, d)
        dt = time.perf_counter() - t0
        same = "" if first is None else f"  (numbers identical to {args.workers[0]} worker(s): " \
                                        f"{study.scores == first.scores and _same(study.columns, first.columns)})"
        first = first or study
        print(f"workers {w}: {dt:6.1f} s wall (reference {study.timing_s['reference']:.1f} s, cells "
              f"{study.timing_s['cells']:.1f} s, figure and tables {dt - study.timing_s['total']:.1f} s){same}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS of the parent process {peak:.0f} MB")


if __name__ == "__main__":
    main()
