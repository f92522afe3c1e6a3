"""Print the link budget fitted to the Hanyang static sweeps (docs/anchors.md), LOS and NLOS.

    python tools/hanyang_link_budget.py [STATIC_DIR] [--power rssi_fp_dbm|rssi_dbm] [--json]

STATIC_DIR defaults to ../shared/data/hanyang-uwb/Static_measurements. The YAML block printed last is
ready to paste under ``channel:`` (or one anchor of ``channel_per_anchor``) of a scenario.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from physynth._json import jsonable
from physynth.calibrate.link_budget import fit_link_budget_hanyang_static

DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Static_measurements"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("static_dir", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--power", default="rssi_fp_dbm", choices=("rssi_fp_dbm", "rssi_dbm"))
    ap.add_argument("--json", action="store_true", help="print the full fit reports as JSON")
    args = ap.parse_args()
    out = {}
    print("| | P0 at 1 m (dBm) | n | ground reflection | saturation (dBm) | shadowing (dB) | sensitivity (dBm) |")
    print("|---|---|---|---|---|---|---|")
    for env in ("LOS", "NLOS"):
        params, rep = fit_link_budget_hanyang_static(args.static_dir, environment=env, power=args.power)
        out[env] = {"params": params, "report": rep}
        pl = rep["path_loss"]
        print(f"| {env} | {pl['ref_power_dbm']:.1f} | {pl['path_loss_exponent']:.2f} | {pl['ground_reflection']:.2f} "
              f"| {pl['saturation_dbm']:.1f} | {pl['shadowing_std_db']:.2f} | {params.sensitivity_dbm:.1f} |")
    if args.json:
        print(json.dumps(jsonable(out), indent=1))
    los = out["LOS"]["params"]
    print("\nlink_budget: {" + ", ".join(f"{k}: {v}" for k, v in los.model_dump().items()) + "}")


if __name__ == "__main__":
    main()
