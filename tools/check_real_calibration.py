"""The real-data calibration checks of tests/test_calibrate_real.py, printed as tables.

    python tools/check_real_calibration.py [--data ../shared/data]

Hanyang LOS Trajectory_A Case_1: calibrate, generate 10 traces, compare the section-5 metrics (and the
worst deviation over seeds 1-7). BROAD trial 15: calibrate the IMU noise, apply it along the trial's
own truth, compare the per-axis IMU error std and the log-PSD shape.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.calibrate.imu_fit import compare_imu_along_truth, fit_imu
from physynth.evaluate.metrics import compute_metrics, relative_deviation_pct
from physynth.generate import compile_scenario, generate_trace
from physynth.io.importers import import_broad, import_hanyang

KEYS = ("uwb_ge1_frac", "uwb_ge2_frac", "residual_median_m", "abs_residual_p95_m", "mean_aoi_s")


def hanyang(data: Path) -> None:
    trace, _ = import_hanyang(data / "hanyang-uwb/Dynamic_measurements/LOS/Trajectory_A/Case_1", crop_to_uwb=True)
    res = calibrate([trace])
    real = compute_metrics([trace])
    cs = compile_scenario(res.scenario)
    m = compute_metrics([generate_trace(cs, i, 20240611) for i in range(10)])
    print("Hanyang LOS Trajectory_A Case_1, 10 traces, seed 20240611")
    for k in KEYS:
        r, s = getattr(real, k), getattr(m, k)
        print(f"  {k:20s} real {r:.4f}  synth {s:.4f}  ({relative_deviation_pct(r, s):.1f} %)")
    worst = []
    for seed in range(1, 8):
        ms = compute_metrics([generate_trace(cs, i, seed) for i in range(10)])
        worst.append(max(relative_deviation_pct(getattr(real, k), getattr(ms, k)) for k in KEYS))
    print(f"  worst deviation over seeds 1-7: {np.round(worst, 1)} %")


def broad(data: Path) -> None:
    real, _ = import_broad(data / "broad-imu/data_mat/15_undisturbed_fast_translation_A.mat")
    fit = fit_imu(real)
    c = compare_imu_along_truth(real, fit.params, fit.diagnostics["truth_cutoff_hz"],
                                rng=np.random.default_rng(20240611))
    print("BROAD trial 15, IMU error (IMU minus truth-derived acceleration)")
    for k, axis in enumerate("ENU"):
        sr, ss = c["std_real"][k], c["std_synth"][k]
        print(f"  {axis}: std real {sr:.3f}  synth {ss:.3f} m/s^2 ({(ss / sr - 1) * 100:+.1f} %), "
              f"log-PSD correlation {c['log_psd_corr'][k]:.3f}, log-spectral distance {c['lsd_db'][k]:.2f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
    args = ap.parse_args()
    hanyang(args.data)
    broad(args.data)


if __name__ == "__main__":
    main()
