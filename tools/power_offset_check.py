"""Per-run LOS range offset against the received first-path power, on the shared Hanyang runs.

The four Trajectory_A runs read different mean ranges at the same geometry (per-run offsets, fitted
by ``physynth calibrate`` as ``uwb.run_offset_std_m``). The raw anchor files also carry the first-path
power (``field.rssi_fp``, dBm), which the PhySynth data model does not keep. This tool prints, per run,
the median residual of the LOS-like rows (|residual| < 0.3 m) and their median first-path power, per
anchor and range bin and pooled, to show whether the runs that read short are the runs received louder
(the received-power bias of leading-edge timing; docs/calibration.md, "Range bias").

    .venv/bin/python tools/power_offset_check.py [--data ../shared/data/hanyang-uwb] [--lag 0.17]

Residuals come from the importer and ``physynth.evaluate.metrics.residuals`` (the trace's UWB stamps
moved back by ``--lag`` seconds: they lag the RTK track by ~0.17 s); each range's power is read from
its anchor file at the same stamp.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from physynth.evaluate.metrics import residuals
from physynth.io.importers import import_hanyang

RUNS = (("LOS", "Case_1"), ("LOS", "Case_2"), ("NLOS", "Case_1"), ("NLOS", "Case_2"))
BINS_M = ((0, 10), (10, 20), (20, 35), (35, 70))
DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"


def run_rows(folder: Path, lag_s: float) -> pd.DataFrame:
    """One row per LOS-like range (|residual| < 0.3 m) of one run: anchor, range and residual [m], first-path
    power [dBm]."""
    trace, _ = import_hanyang(folder, crop_to_uwb=True)
    trace = dataclasses.replace(trace, uwb=dataclasses.replace(trace.uwb, t_s=trace.uwb.t_s - lag_s))
    res, idx, t = residuals(trace)
    rows = []
    origin = trace.meta["time_origin_unix_s"]
    for k, aid in enumerate(trace.anchors.ids):
        raw = pd.read_csv(folder / f"{aid}.csv", usecols=["field.stamp", "field.rssi_fp"]).sort_values("field.stamp")
        raw_t = raw["field.stamp"].to_numpy(float) * 1e-9 - origin - lag_s
        sel = idx == k
        j = np.clip(np.searchsorted(raw_t, t[sel]), 1, raw_t.size - 1)
        j -= np.abs(raw_t[j - 1] - t[sel]) < np.abs(raw_t[j] - t[sel])  # the nearest stamp
        geom = np.linalg.norm(trace.truth.position_at(t[sel]) - trace.anchors.pos_enu_m[k], axis=1)
        ok = np.abs(res[sel]) < 0.3
        rows.append(pd.DataFrame({"anchor": aid, "range_m": geom[ok], "residual_m": res[sel][ok],
                                  "fp_dbm": raw["field.rssi_fp"].to_numpy(float)[j][ok]}))
    return pd.concat(rows, ignore_index=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="hanyang-uwb folder")
    ap.add_argument("--lag", type=float, default=0.17, help="UWB stamp lag behind the track [s]")
    args = ap.parse_args()
    if not (args.data / "Dynamic_measurements").is_dir():
        raise SystemExit(f"--data: {args.data} has no Dynamic_measurements folder (the hanyang-uwb dataset)")
    cells, pooled = [], []
    for env, case in RUNS:
        df = run_rows(args.data / "Dynamic_measurements" / env / "Trajectory_A" / case, args.lag)
        name = f"{env} {case}"
        pooled.append({"run": name, "median residual cm": 100 * df["residual_m"].median(),
                       "median first-path power dBm": df["fp_dbm"].median(), "rows": len(df)})
        df["bin"] = pd.cut(df["range_m"], [b[0] for b in BINS_M] + [BINS_M[-1][1]], right=False)
        g = df.groupby(["anchor", "bin"], observed=True).agg(res=("residual_m", "median"), fp=("fp_dbm", "median"),
                                                             n=("residual_m", "size"))
        cells.append(g[g["n"] >= 20].assign(run=name))
    table = pd.concat(cells).reset_index()
    table["res"] *= 100
    with pd.option_context("display.width", 200, "display.max_rows", 100, "display.max_columns", 20):
        print(table.pivot_table(index=["anchor", "bin"], columns="run", values=["res", "fp"], observed=True).round(1))
        print(pd.DataFrame(pooled).round(2).to_string(index=False))
    # within each anchor and range bin, the slope of the residual against the power over the runs
    x = table["fp"] - table.groupby(["anchor", "bin"], observed=True)["fp"].transform("mean")
    y = table["res"] - table.groupby(["anchor", "bin"], observed=True)["res"].transform("mean")
    print(f"within-cell slope: {float((x * y).sum() / (x * x).sum()):+.2f} cm per dB over {len(table)} cells "
          f"(correlation {float(np.corrcoef(x, y)[0, 1]):+.2f})")


if __name__ == "__main__":
    main()
