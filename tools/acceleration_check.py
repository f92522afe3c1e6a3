"""Accelerations of calibrated walks and lab motions, real against synthetic, with and without the
calibrated acceleration limit (``motion.max_acc_mps2``).

    .venv/bin/python tools/acceleration_check.py [--n 5] [--seed 1]

Calibrates (1) Hanyang LOS Trajectory_A Case_1 and (2) BROAD trials 10 and 15 together, generates
``--n`` traces of each scenario as calibrated and with the limit removed, and prints quantiles of the
truth acceleration magnitude |dv/dt| (numerical derivative of the truth velocity) per trace, next to
those of the real recordings; and the curvature of each fitted path against that of the smoothed real
track it was fitted to.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.calibrate.geometry import summarize_track
from physynth.generate import generate_traces
from physynth.io.importers import import_broad, import_hanyang
from physynth.models.motion import curvature
from physynth.models.path import compile_path

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
Q = (0.5, 0.99, 0.999, 1.0)


def _acc(trace) -> np.ndarray:
    v, t = trace.truth.vel_enu_mps, trace.truth.t_s
    ok = np.all(np.isfinite(v), axis=1)
    return np.linalg.norm(np.gradient(v[ok], t[ok], axis=0), axis=1)


def _row(label: str, a: np.ndarray, extra: str = "") -> str:
    return f"  {label:34s} " + " ".join(f"{x:7.2f}" for x in np.quantile(a, Q)) + extra


def _curvatures(scn, real) -> None:
    """Curvature [1/m] of the fitted path against that of the smoothed real track (moving samples)."""
    geo = compile_path(scn.path)
    _, d1, d2 = geo.evaluate_cf(np.linspace(0.0, geo.length_m, 200_001))
    track = summarize_track(real, "real")
    v = np.gradient(track.pos_m, track.t_s, axis=0)
    a = np.gradient(v, track.t_s, axis=0)
    moving = np.linalg.norm(v, axis=1) > 0.5 * track.peak_speed_mps
    k_real = curvature(v[moving].T, a[moving].T)
    print("  curvature [1/m] 0.99 / 0.999 quantile / max: fitted path "
          + " / ".join(f"{x:.2f}" for x in np.quantile(curvature(d1, d2), (0.99, 0.999, 1.0)))
          + "; smoothed real track, moving at over half its peak speed "
          + " / ".join(f"{x:.2f}" for x in np.quantile(k_real, (0.99, 0.999, 1.0))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    han = DATA / "hanyang-uwb" / "Dynamic_measurements" / "LOS" / "Trajectory_A" / "Case_1"
    broad = DATA / "broad-imu" / "data_mat"
    sites = {"Hanyang LOS Case_1": [import_hanyang(han, crop_to_uwb=True)[0]],
             "BROAD trials 10 + 15": [import_broad(broad / f"{k}.mat")[0] for k in
                                      ("10_undisturbed_slow_translation_A", "15_undisturbed_fast_translation_A")]}
    print(f"|a| [m/s^2] quantiles {', '.join(f'{q:g}' for q in Q)}; synthetic: {args.n} traces, seed {args.seed}")
    for name, real in sites.items():
        scn = calibrate(real, name="acc").scenario
        print(f"{name}: motion.max_acc_mps2 = {scn.motion.max_acc_mps2}")
        _curvatures(scn, real[0])
        for i, tr in enumerate(real):
            print(_row(f"real {i}", _acc(tr)))
        free = scn.model_copy(update={"motion": scn.motion.model_copy(update={"max_acc_mps2": None})})
        for label, s in (("limit", scn), ("no limit", free)):
            for i, tr in enumerate(generate_traces(s, args.n, seed=args.seed)):
                print(_row(f"synthetic, {label}, trace {i}", _acc(tr), f"   trip+dwell {tr.duration_s:7.2f} s"))


if __name__ == "__main__":
    main()
