"""Leave-one-out check of the body-frame IMU (accelerometer and gyroscope) on the shared BROAD trials of
undisturbed motion, through calibration and ``validate --transfer`` as the command line runs them.

    .venv/bin/python tools/broad_body_loo.py [--data ../shared/data/broad-imu/data_mat] [--n 4] [--seed 1]

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
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.io import write_dataset
from physynth.io.importers import import_broad
from physynth.scenario import Scenario
from physynth.workflows import validate_datasets

DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad-imu" / "data_mat"
KEYS = (("imu_error_std_mps2", "ENU acc"), ("acc_body_error_std_mps2", "body acc"), ("gyro_error_std_radps", "gyro"))


def _without_gyro_acc_gain(scn: Scenario) -> Scenario:
    body = scn.body_imu
    gyro = body.gyroscope.model_copy(update={"vibration_acc_var_gain_rad2_per_m": [0.0, 0.0, 0.0]})
    return scn.model_copy(update={"body_imu": body.model_copy(update={"gyroscope": gyro})})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT, help="BROAD data_mat folder")
    ap.add_argument("--n", type=int, default=4, help="synthetic traces per validation")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    files = sorted(args.data.glob("*_undisturbed_*.mat"))
    if len(files) < 2:
        raise SystemExit(f"{args.data}: fewer than two undisturbed BROAD trials")
    traces = [import_broad(f)[0] for f in files]
    print(f"leave-one-out over {len(files)} undisturbed trials, {args.n} synthetic traces, seed {args.seed}; "
          "error-std deviation per axis (x/y/z or E/N/U), %")
    print("| left-out trial | model | gyro acc gain [rad^2/s^2 per m/s^2] | " + " | ".join(k[1] for k in KEYS) + " |")
    print("|---|---|---|" + "---|" * len(KEYS))
    worst = {"as calibrated": 0.0, "constant gyro": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (f, left) in enumerate(zip(files, traces, strict=True)):
            real = Path(tmp) / f.stem
            write_dataset(real, [left], meta={"kind": "real", "source": "broad-imu"})
            res = calibrate([t for j, t in enumerate(traces) if j != i], name=f"loo-without-{f.stem[:2]}")
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


if __name__ == "__main__":
    main()
