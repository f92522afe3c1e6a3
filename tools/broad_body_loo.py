"""Leave-one-out check of the body-frame IMU (accelerometer and gyroscope) on the shared BROAD trials of
undisturbed motion, through calibration and ``validate --transfer`` as the command line runs them.

    .venv/bin/python tools/broad_body_loo.py [--data ../shared/data/broad-imu/data_mat] [--n 4] [--seed 1] [--bins]

For each undisturbed trial in turn: calibrate on the other undisturbed trials (``physynth calibrate``
on IMU-only recordings), then validate with ``--transfer`` on the left-out trial (the scenario's IMU
models run along the trial's own optical truth), exactly as

    physynth import broad TRIAL.mat --out DIR                   # for each trial
    physynth calibrate DIR_b DIR_c --out loo.yaml
    physynth validate --real DIR_a --scenario loo.yaml --transfer -n 4 --seed 1 --out report_a

and print the per-axis error-std deviation (synthetic / real - 1, %) of the ENU accelerometer, the
body accelerometer and the gyroscope. Each fold is run twice: as calibrated, and with the gyroscope's
acceleration-scaled vibration (``body_imu.gyroscope.vibration_acc_var_gain_rad2_per_m``) set to 0,
the constant gyro model calibration wrote before it existed, so the two are compared side by side.

Then each fold is validated without ``--transfer`` (synthetic traces move as the scenario says), as
calibrated (a motion in place: jitter around a point, ``motion.jitter``) and with the path and motion
calibration wrote before (a path fitted through the folded strokes, driven by a speed profile, no
jitter), and with the Ornstein-Uhlenbeck tumble that calibration wrote before the smooth one; the
median truth acceleration |a| of the synthetic traces is printed next to the real trial's.

``--bins`` first prints, per trial, the gyro residual (gyro minus the fitted matrix times the truth body
rate, low-passed at 10 Hz, on all undisturbed trials) binned by the body rate |w|, with the mean truth
acceleration |a| of each bin: what the acceleration-scaled law rests on.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate, fit_motion, fit_path
from physynth.calibrate.held_out import leave_one_out
from physynth.generate import generate_traces
from physynth.io import write_dataset
from physynth.io.importers import import_broad
from physynth.scenario import PerturbationParams, Scenario
from physynth.workflows import validate_datasets

DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad-imu" / "data_mat"
KEYS = (("imu_error_std_mps2", "ENU acc"), ("acc_body_error_std_mps2", "body acc"), ("gyro_error_std_radps", "gyro"))


def _folded_path(scn: Scenario, train: list) -> Scenario:
    """The scenario with the path and motion of a path fitted through the strokes (no jitter)."""
    path = fit_path(train)
    motion = fit_motion(train, path_length_m=path.diagnostics["length_m"]).params
    return scn.model_copy(update={"path": path.params.model_copy(update={"perturbation": PerturbationParams(
        lateral_std_m=0.0, sag_std_m=0.0)}), "motion": motion})


def _median_acc(traces) -> float:
    a = [np.linalg.norm(np.gradient(t.truth.vel_enu_mps, t.truth.t_s, axis=0), axis=1) for t in traces]
    return float(np.nanmedian(np.concatenate(a)))


def _gyro_bins(files, traces) -> None:
    from physynth.calibrate.imu_only import _body_truth_parts, fit_body_imu

    fit = fit_body_imu(traces, cutoff_hz=10.0).diagnostics
    m, b = np.asarray(fit["gyroscope_matrix"]), np.asarray(fit["gyroscope_bias_radps"])
    print("gyro residual RMS [rad/s] binned by |w| [rad/s] (mean |a| [m/s^2] of the bin), and at rest")
    for f, tr in zip(files, traces, strict=True):
        a_w, _, w, ok, calm = _body_truth_parts(tr, 10.0, 0.0, None)
        ok &= np.all(np.isfinite(tr.imu.gyro_body_radps), axis=1)
        r2 = np.sum((tr.imu.gyro_body_radps - (w @ m.T + b)) ** 2, axis=1) / 3.0
        w_abs, a_abs = np.linalg.norm(w, axis=1), np.linalg.norm(a_w, axis=1)
        cells = [f"rest {np.sqrt(np.mean(r2[calm & ok])):.3f}"]
        for lo, hi in ((0.2, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 5.0)):
            sel = ok & (w_abs >= lo) & (w_abs < hi)
            if sel.sum() > 100:
                cells.append(f"|w| {lo:g}-{hi:g}: {np.sqrt(np.mean(r2[sel])):.3f} ({np.mean(a_abs[sel]):.1f})")
        print(f"  {f.stem}: " + ", ".join(cells))


def _without_gyro_acc_gain(scn: Scenario) -> Scenario:
    body = scn.body_imu
    gyro = body.gyroscope.model_copy(update={"vibration_acc_var_gain_rad2_per_m": [0.0, 0.0, 0.0]})
    return scn.model_copy(update={"body_imu": body.model_copy(update={"gyroscope": gyro})})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT, help="BROAD data_mat folder")
    ap.add_argument("--n", type=int, default=4, help="synthetic traces per validation")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bins", action="store_true", help="first print the gyro residual binned by the motion")
    args = ap.parse_args()
    files = sorted(args.data.glob("*_undisturbed_*.mat"))
    if len(files) < 2:
        raise SystemExit(f"{args.data}: fewer than two undisturbed BROAD trials")
    traces = [import_broad(f)[0] for f in files]
    if args.bins:
        _gyro_bins(files, traces)
    print(f"leave-one-out over {len(files)} undisturbed trials, {args.n} synthetic traces, seed {args.seed}; "
          "error-std deviation per axis (x/y/z or E/N/U), %")
    print("| left-out trial | model | gyro acc gain [rad^2/s^2 per m/s^2] | " + " | ".join(k[1] for k in KEYS) + " |")
    print("|---|---|---|" + "---|" * len(KEYS))
    worst = {"as calibrated": 0.0, "constant gyro": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for i, left, others in leave_one_out(traces):
            f = files[i]
            real = Path(tmp) / f.stem
            write_dataset(real, [left], meta={"kind": "real", "source": "broad-imu"})
            res = calibrate(others, name=f"loo-without-{f.stem[:2]}")
            variants = (("as calibrated", res.scenario), ("constant gyro", _without_gyro_acc_gain(res.scenario)))
            for label, scn in variants:
                rep = validate_datasets(real, scenario=scn, n=args.n, seed=args.seed, transfer=True).to_dict()
                dev = rep["relative_deviation_pct"]
                cells = [" / ".join(f"{x:+.0f}" for x in dev[k]) for k, _ in KEYS]
                worst[label] = max(worst[label], float(np.max(np.abs(dev["gyro_error_std_radps"]))))
                gain = scn.body_imu.gyroscope.vibration_acc_var_gain_rad2_per_m
                print(f"| {f.stem} | {label} | {', '.join(f'{g:.2e}' for g in gain)} | " + " | ".join(cells) + " |")
    print("largest gyro deviation over folds and axes: "
          + ", ".join(f"{k} {v:.0f} %" for k, v in worst.items()))
    _free_motion(files, traces, args)


def _free_motion(files, traces, args) -> None:
    print("\nwithout --transfer (each synthetic trace moves as the scenario says): error-std deviation per axis, %, "
          "and the median |a| of the truth [m/s^2]")
    print("| left-out trial | motion | ENU acc | gyro | median abs(a), synthetic (real) |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for i, left, train in leave_one_out(traces):
            f = files[i]
            real = Path(tmp) / f.stem
            write_dataset(real, [left], meta={"kind": "real", "source": "broad-imu"})
            scn = calibrate(train, name=f"loo-without-{f.stem[:2]}").scenario
            ou = scn.model_copy(update={"attitude": scn.attitude.model_copy(update={"tumble_spectrum": "ou"})})
            for label, s in (("in place + jitter", scn), ("folded path", _folded_path(scn, train)),
                             ("in place, OU tumble", ou)):
                rep = validate_datasets(real, scenario=s, n=args.n, seed=args.seed)
                dev = rep.to_dict()["relative_deviation_pct"]
                med = _median_acc(generate_traces(s, args.n, seed=args.seed))
                cells = " | ".join(" / ".join(f"{x:+.0f}" for x in dev[k])
                                   for k in ("imu_error_std_mps2", "gyro_error_std_radps"))
                print(f"| {f.stem} | {label} | {cells} | {med:.2f} ({_median_acc([left]):.2f}) |")


if __name__ == "__main__":
    main()
