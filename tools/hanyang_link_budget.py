"""Print the link budget fitted to the Hanyang static sweeps (docs/anchors.md), LOS and NLOS, and check
its first-path power against the dynamic runs it never saw.

    python tools/hanyang_link_budget.py [STATIC_DIR] [--power rssi_fp_dbm|rssi_dbm] [--json]
                                        [--dynamic DYNAMIC_DIR] [--lag 0.18]

STATIC_DIR defaults to ../shared/data/hanyang-uwb/Static_measurements. Two fits per environment: the
tag antenna's height above the ground fitted from the interference nulls (the default), and held at
1.0 m (the former fit). The YAML block printed after the table is ready to paste under ``channel:`` (or
one anchor of ``channel_per_anchor``) of a scenario.

Then, for every anchor placement of the dynamic runs below DYNAMIC_DIR (default
../shared/data/hanyang-uwb/Dynamic_measurements; the raw files carry ``field.rssi_fp``), the median
real first-path power per band of horizontal distance against the power the LOS static fit predicts
from the anchor's height, the tag at the fitted height, and the distance (the truth read ``--lag``
seconds before each UWB stamp), with each fit's rms difference over all cells.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from physynth._json import jsonable
from physynth.calibrate.link_budget import fit_link_budget_hanyang_static, path_loss_model

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
BANDS_M = (0.0, 10.0, 20.0, 30.0, 40.0, 45.0, 50.0, 55.0, 70.0)
"""Edges of the bands of horizontal tag-anchor distance [m] of the dynamic check."""
BANDS = tuple(zip(BANDS_M[:-1], BANDS_M[1:], strict=True))
MIN_ROWS = 20
"""A band with fewer ranges is left blank."""


def _dynamic_rows(run: Path, lag_s: float):
    """(anchor id, anchor height, horizontal distance (N,), first-path power (N,)) per anchor file."""
    import pandas as pd

    traj = pd.read_csv(run / "trajectory.csv")
    tt = traj["timestamp"].to_numpy(float) / 1e9
    for f in sorted(run.glob("A*.csv"), key=lambda p: int(p.stem[1:])):
        raw = pd.read_csv(f)
        t = raw["field.stamp"].to_numpy(float) / 1e9 - lag_s
        inside = (t >= tt[0]) & (t <= tt[-1]) & np.isfinite(raw["field.rssi_fp"].to_numpy(float))
        x = np.interp(t[inside], tt, traj["x"].to_numpy(float))
        y = np.interp(t[inside], tt, traj["y"].to_numpy(float))
        horiz = np.hypot(x - raw["field.x"].to_numpy(float)[inside], y - raw["field.y"].to_numpy(float)[inside])
        yield f.stem, float(raw["field.z"].iloc[0]), horiz, raw["field.rssi_fp"].to_numpy(float)[inside]


def dynamic_check(dyn: Path, fits: dict[str, dict], lag_s: float) -> None:
    """Print real against predicted first-path power per placement and distance band."""
    names = list(fits)
    print(f"\nfirst-path power of the dynamic runs (dBm), real / predicted by the LOS static fit "
          f"({' / '.join(names)}), by horizontal distance (m):")
    print("| run | anchor | height (m) | " + " | ".join(f"{a:g}-{b:g}" for a, b in BANDS)
          + " |")
    print("|---|---|---|" + "---|" * len(BANDS))
    diffs: dict[str, list[float]] = {n: [] for n in names}
    for run in sorted(p for p in dyn.glob("*/*/Case_*") if p.is_dir()):
        for anchor, height, horiz, fp in _dynamic_rows(run, lag_s):
            pred = {n: path_loss_model(fit["x"], horiz, np.full(horiz.size, height), fit["tag_height_m"],
                                       fit["wavelength_m"]) for n, fit in fits.items()}
            cells = []
            for lo, hi in BANDS:
                k = (horiz >= lo) & (horiz < hi)
                if k.sum() < MIN_ROWS:
                    cells.append("")
                    continue
                real = float(np.median(fp[k]))
                p_n = {n: float(np.median(pred[n][k])) for n in names}
                for n in names:
                    diffs[n].append(p_n[n] - real)
                cells.append(f"{real:.0f} / " + " / ".join(f"{p_n[n]:.0f}" for n in names))
            label = f"{run.parent.parent.name} {run.name}"
            print(f"| {label} | {anchor} | {height:.2f} | " + " | ".join(cells) + " |")
    for n in names:
        d = np.asarray(diffs[n])
        print(f"{n}: predicted minus real over {d.size} cells: rms {np.sqrt(np.mean(d**2)):.2f} dB, "
              f"worst {d[np.argmax(np.abs(d))]:+.1f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("static_dir", nargs="?", type=Path, default=DATA / "Static_measurements")
    ap.add_argument("--power", default="rssi_fp_dbm", choices=("rssi_fp_dbm", "rssi_dbm"))
    ap.add_argument("--json", action="store_true", help="print the full fit reports as JSON")
    ap.add_argument("--dynamic", type=Path, default=DATA / "Dynamic_measurements",
                    help="Hanyang Dynamic_measurements folder for the check (skipped if absent)")
    ap.add_argument("--lag", type=float, default=0.18, help="UWB stamps' lag behind the truth [s]")
    args = ap.parse_args()
    out: dict = {}
    fits: dict[str, dict] = {}
    print("| | tag height (m) | P0 at 1 m (dBm) | n | ground reflection | saturation (dBm) | shadowing (dB) "
          "| sensitivity (dBm) | rms (dB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for env in ("LOS", "NLOS"):
        for label, tag_h in (("tag height fitted", None), ("tag at 1.0 m", 1.0)):
            params, rep = fit_link_budget_hanyang_static(args.static_dir, environment=env, power=args.power,
                                                         tag_height_m=tag_h)
            out[f"{env}, {label}"] = {"params": params, "report": rep}
            pl = rep["path_loss"]
            print(f"| {env}, {label} | {pl['tag_height_m']:.3f} | {pl['ref_power_dbm']:.1f} "
                  f"| {pl['path_loss_exponent']:.2f} | {pl['ground_reflection']:.2f} | {pl['saturation_dbm']:.1f} "
                  f"| {pl['shadowing_std_db']:.2f} | {params.sensitivity_dbm:.1f} | {pl['rms_db']:.2f} |")
            if env == "LOS":
                fits[label] = {"x": np.array([pl["ref_power_dbm"], pl["path_loss_exponent"], pl["ground_reflection"],
                                              pl["saturation_dbm"]]),
                               "tag_height_m": pl["tag_height_m"], "wavelength_m": pl["wavelength_m"]}
    if args.json:
        print(json.dumps(jsonable(out), indent=1))
    los = out["LOS, tag height fitted"]["params"]
    print("\nlink_budget: {" + ", ".join(f"{k}: {v}" for k, v in los.model_dump().items()) + "}")
    if args.dynamic.is_dir():
        dynamic_check(args.dynamic, fits, args.lag)


if __name__ == "__main__":
    main()
