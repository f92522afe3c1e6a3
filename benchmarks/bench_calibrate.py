"""Calibration time on the four Hanyang Trajectory_A runs (LOS Case_1/2, NLOS Case_1/2), pooled.

    python benchmarks/bench_calibrate.py [--repeat R] [--data ../shared/data/hanyang-uwb]

Times the library call :func:`physynth.calibrate.calibrate` (the runs are imported first, outside the
timing; the import time is printed separately) on one core (BLAS threads pinned to 1 below). The
anchors were moved between the runs (``anchor_policy="per-run"``: each run against its own layout,
the first run's layout written, run-to-run offsets fitted). Target: under 30 s.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from physynth.calibrate import calibrate  # noqa: E402
from physynth.data import HANYANG_TRAJECTORY_A_RUNS as RUNS  # noqa: E402
from physynth.io.importers import import_hanyang  # noqa: E402

TARGET_S = 30.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions (the best is reported)")
    ap.add_argument("--data", type=Path,
                    default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb")
    args = ap.parse_args()
    dyn = args.data / "Dynamic_measurements"
    t0 = time.perf_counter()
    traces = [import_hanyang(dyn / run)[0] for run in RUNS]
    t_import = time.perf_counter() - t0
    n_rows = sum(len(t.uwb) for t in traces)
    times = []
    for _ in range(args.repeat):  # a few timed repetitions
        t0 = time.perf_counter()
        res = calibrate(traces, name="hanyang-trajectory-a", anchor_policy="per-run")
        times.append(time.perf_counter() - t0)
    best = min(times)
    s = res.scenario
    print(f"import of {len(RUNS)} runs: {t_import:.2f} s ({n_rows} UWB rows)")
    print(f"calibrate on {len(RUNS)} Hanyang Trajectory_A runs: best {best:.2f} s, "
          f"all {', '.join(f'{t:.2f}' for t in times)} s (target < {TARGET_S:.0f} s: "
          f"{'OK' if best < TARGET_S else 'TOO SLOW'})")
    print(f"  time offset {s.uwb.time_offset_s:.4f} s, burst rate {s.uwb.burst_rate_hz:.3f} Hz, "
          f"tag outage onset {s.availability.tag_outage_onset_prob:.2e}/burst "
          f"(mean {s.availability.tag_outage_mean_s:.1f} s), path {s.path.kind} "
          f"({res.report['path']['rmse_m']:.3f} m RMSE), profile {s.motion.profile.kind}")
    for a in s.anchor_ids:
        c, av = s.channel_for(a), s.availability_for(a)
        print(f"  {a}: LOS {c.los_mean_m:+.3f} m + {c.range_bias_per_m * 100:.2f} cm/m, sigma {c.los_std_m:.3f} m, "
              f"NLOS {c.nlos_prob:.3f}; dropout {av.dropout_prob:.3f}, outage onset {av.outage_onset_prob:.3f}, "
              f"mean {av.outage_mean_s:.2f} s")


if __name__ == "__main__":
    main()
