"""Does calibration recover what generated the data?

Generates ``-n`` traces of a preset (root seed 11), calibrates on them, generates ``-n`` traces of the
calibrated scenario (seed 12) and compares the section-5 metrics with ``-n`` traces of the preset
itself (seed 12), beside the preset's seed-to-seed spread (relative std over ``--spread-seeds`` root
seeds from 11). With ``--bias-seeds K`` the calibrated scenario is also generated at root seeds 12 ..
11 + K and the mean of its metrics is compared with the mean of the preset's over the same seeds: the
bias of the recovery, with its standard error (the seed spread x sqrt(2 / K)).

    .venv/bin/python tools/recovery_check.py cablecar-descending -n 8 [--spread-seeds 12] [--bias-seeds 8]
                                             [--calib-seeds K]

``--calib-seeds K`` also calibrates on K independent datasets (root seeds 101 .. 100 + K), generates
each result at seed 12 + j and compares with the preset at the same seed: the mean deviation over the
K calibrations and its standard error (their std / sqrt(K)) include the sampling noise of the data a
calibration sees, which ``--bias-seeds`` (one calibration, many generation seeds) does not.
"""

from __future__ import annotations

import argparse
import sys
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
    ap.add_argument("--spread-seeds", type=int, default=12, help="root seeds 11.. for the seed-to-seed spread")
    ap.add_argument("--bias-seeds", type=int, default=0, help="also average the recalibrated metrics over seeds 12..")
    ap.add_argument("--calib-seeds", type=int, default=0,
                    help="also calibrate on K independent datasets (root seeds 101..) and average their deviations")
    args = ap.parse_args()
    if args.calib_seeds == 1 or args.calib_seeds < 0:
        ap.error("--calib-seeds needs 0 (off) or at least 2 calibrations (a standard error needs two)")
    cs = compile_scenario(load_scenario(args.preset))
    t0 = time.perf_counter()
    seeds = range(11, 11 + max(args.spread_seeds, 2, args.bias_seeds + 1))
    per_seed = {seed: compute_metrics([generate_trace(cs, i, seed) for i in range(args.n)]) for seed in seeds}
    res = calibrate([generate_trace(cs, i, 11) for i in range(args.n)], name="recovered")
    again = compile_scenario(res.scenario)
    bias_seeds = list(range(12, 12 + args.bias_seeds))
    recal = {seed: compute_metrics([generate_trace(again, i, seed) for i in range(args.n)])
             for seed in (bias_seeds or [12])}
    print(f"{args.preset}: {args.n} traces; calibrated on seed 11, compared at seed 12; seed spread over "
          f"{args.spread_seeds} root seeds ({time.perf_counter() - t0:.0f} s)")
    calib_devs = calibration_deviations(cs, args.n, args.calib_seeds, per_seed) if args.calib_seeds else {}
    head = "| metric | preset | recalibrated | dev. % | seed-to-seed rel. std % |"
    if bias_seeds:
        head += f" mean dev. over seeds 12-{bias_seeds[-1]} % | its s.e. % |"
    if args.calib_seeds:
        head += f" mean dev. over {args.calib_seeds} calibrations % | its s.e. % |"
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    for k in KEYS:
        vals = np.array([getattr(per_seed[s], k) for s in list(seeds)[:args.spread_seeds]])
        spread = 100.0 * vals.std(ddof=1) / abs(vals.mean())
        a, b = getattr(per_seed[12], k), getattr(recal[12], k)
        line = f"| {k} | {a:.4f} | {b:.4f} | {relative_deviation_pct(a, b):.1f} | {spread:.1f} |"
        if bias_seeds:
            ma = np.mean([getattr(per_seed[s], k) for s in bias_seeds])
            mb = np.mean([getattr(recal[s], k) for s in bias_seeds])
            line += f" {100.0 * (mb - ma) / abs(ma):+.1f} | {spread * np.sqrt(2.0 / len(bias_seeds)):.1f} |"
        if args.calib_seeds:
            d = np.array(calib_devs[k])
            line += f" {d.mean():+.1f} | {d.std(ddof=1) / np.sqrt(d.size):.1f} |"
        print(line)


def calibration_deviations(cs, n: int, k: int, preset_metrics: dict) -> dict[str, list[float]]:
    """Relative deviations [%] of every metric of K recalibrations, each on its own dataset (root seeds
    101 .. 100 + K) and generated at seed 12 + j, against the preset generated at the same seed: their
    spread holds the calibration data's own sampling noise, which one calibration seed cannot show.
    ``preset_metrics``: the preset's metrics by root seed already computed (reused, not generated again)."""
    devs: dict[str, list[float]] = {key: [] for key in KEYS}
    for j in range(k):
        rec = calibrate([generate_trace(cs, i, 101 + j) for i in range(n)], name=f"recovered-{101 + j}").scenario
        again = compile_scenario(rec)
        m_rec = compute_metrics([generate_trace(again, i, 12 + j) for i in range(n)])
        m_pre = preset_metrics.get(12 + j) or compute_metrics([generate_trace(cs, i, 12 + j) for i in range(n)])
        for key in KEYS:
            a, b = getattr(m_pre, key), getattr(m_rec, key)
            devs[key].append(100.0 * (b - a) / abs(a))
        print(f"calibration {j + 1}/{k} done", file=sys.stderr, flush=True)
    return devs


if __name__ == "__main__":
    main()
