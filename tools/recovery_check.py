"""Does calibration recover what generated the data? (issue 12 item 6)

Generates ``-n`` traces of a preset (root seed 11), calibrates on them, generates ``-n`` traces of the
calibrated scenario (seed 12) and compares the section-5 metrics with ``-n`` traces of the preset
itself (seed 12), beside the preset's seed-to-seed spread (relative std over root seeds 11-14).

    .venv/bin/python tools/recovery_check.py cablecar-descending -n 8
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from physynth.calibrate import calibrate
from physynth.evaluate.metrics import compute_metrics, relative_deviation_pct
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario

KEYS = ("uwb_ge1_frac", "uwb_ge2_frac", "residual_std_m", "residual_median_m", "abs_residual_p95_m",
        "abs_residual_p99_m", "mean_aoi_s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset")
    ap.add_argument("-n", type=int, default=8)
    args = ap.parse_args()
    cs = compile_scenario(load_scenario(args.preset))
    t0 = time.perf_counter()
    per_seed = {seed: compute_metrics([generate_trace(cs, i, seed) for i in range(args.n)])
                for seed in (11, 12, 13, 14)}
    res = calibrate([generate_trace(cs, i, 11) for i in range(args.n)], name="recovered")
    m_recal = compute_metrics([generate_trace(compile_scenario(res.scenario), i, 12) for i in range(args.n)])
    print(f"{args.preset}: {args.n} traces; calibrated on seed 11, compared at seed 12 "
          f"({time.perf_counter() - t0:.0f} s)")
    print("| metric | preset | recalibrated | dev. % | seed-to-seed rel. std % |")
    print("|---|---|---|---|---|")
    for k in KEYS:
        vals = np.array([getattr(m, k) for m in per_seed.values()])
        spread = 100.0 * vals.std(ddof=1) / abs(vals.mean())
        a, b = getattr(per_seed[12], k), getattr(m_recal, k)
        print(f"| {k} | {a:.4f} | {b:.4f} | {relative_deviation_pct(a, b):.1f} | {spread:.1f} |")


if __name__ == "__main__":
    main()
