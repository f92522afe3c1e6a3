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
from scipy.signal import welch

from physynth.calibrate import calibrate
from physynth.calibrate.imu_fit import fit_imu, imu_error, simulate_imu_on, truth_acceleration
from physynth.generate import compile_scenario, generate_trace
from physynth.importers import import_broad, import_hanyang
from physynth.metrics import compute_metrics, relative_deviation_pct
from physynth.records import Trace

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
    fc = fit.diagnostics["truth_cutoff_hz"]
    tg, acc, valid = truth_acceleration(real.truth.t_s, real.truth.pos_enu_m, cutoff_hz=fc)
    filled = np.stack([np.interp(tg, tg[valid], acc[valid, k]) for k in range(3)], axis=1)
    imu = simulate_imu_on(tg, filled, fit.params, rng=np.random.default_rng(20240611))
    synth = Trace(truth=real.truth, uwb=real.uwb, anchors=real.anchors, imu=imu)
    e_r, ok_r, _ = imu_error(real, fc)
    e_s, ok_s, _ = imu_error(synth, fc)
    sr, ss = np.std(e_r[ok_r], axis=0), np.std(e_s[ok_s], axis=0)
    fs = fit.params.rate_hz
    f, p_r = welch(np.where(ok_r[:, None], e_r, 0.0), fs=fs, nperseg=8192, axis=0)
    _, p_s = welch(np.where(ok_s[:, None], e_s, 0.0), fs=fs, nperseg=8192, axis=0)
    band = (f > 0.2) & (f < 0.95 * fs / 2)
    print("BROAD trial 15, IMU error (IMU minus truth-derived acceleration)")
    for k, axis in enumerate("ENU"):
        lr, ls = np.log10(p_r[band, k]), np.log10(p_s[band, k])
        lsd = float(np.sqrt(np.mean((10.0 * (lr - ls)) ** 2)))
        print(f"  {axis}: std real {sr[k]:.3f}  synth {ss[k]:.3f} m/s^2 ({(ss[k] / sr[k] - 1) * 100:+.1f} %), "
              f"log-PSD correlation {np.corrcoef(lr, ls)[0, 1]:.3f}, log-spectral distance {lsd:.2f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
    args = ap.parse_args()
    hanyang(args.data)
    broad(args.data)


if __name__ == "__main__":
    main()
