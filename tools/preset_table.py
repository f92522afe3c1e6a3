"""Section-5 metrics of a preset against the paper's real column (README table).

    python tools/preset_table.py cablecar-descending -n 20 --seed 2026
"""

from __future__ import annotations

import argparse

import numpy as np

from physynth.evaluate.metrics import compute_metrics, relative_deviation_pct
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario

REAL = {  # the paper's real columns, Tables I-II
    "cablecar-descending": dict(duration_s=102.1, uwb_ge1_frac=0.178, uwb_ge2_frac=0.112, residual_std_m=7.485,
                                residual_median_m=0.947, abs_residual_p95_m=18.12, abs_residual_p99_m=21.29,
                                mean_aoi_s=14.6, imu_std_mps2=(1.616, 0.880, 1.066)),
    "cablecar-ascending": dict(duration_s=113.1, uwb_ge1_frac=0.183, uwb_ge2_frac=0.127, residual_std_m=0.407,
                               residual_median_m=0.235, abs_residual_p95_m=0.830, abs_residual_p99_m=1.208,
                               mean_aoi_s=14.6),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("preset", choices=sorted(REAL))
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2026)
    args = ap.parse_args()
    cs = compile_scenario(load_scenario(args.preset))
    m = compute_metrics([generate_trace(cs, i, args.seed) for i in range(args.n)])
    print(f"{args.preset}: {args.n} traces, seed {args.seed}")
    for key, real in REAL[args.preset].items():
        synth = getattr(m, key)
        if key == "imu_std_mps2":
            dev = [relative_deviation_pct(r, s) for r, s in zip(real, synth, strict=True)]
            print(f"  {key:20s} real {np.round(real, 3)}  synth {np.round(synth, 3)}  ({np.round(dev, 1)} %)")
        else:
            print(f"  {key:20s} real {real:8.3f}  synth {synth:8.3f}  ({relative_deviation_pct(real, synth):5.1f} %)")


if __name__ == "__main__":
    main()
