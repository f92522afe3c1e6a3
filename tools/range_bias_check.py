"""How the LOS ranging bias grows with range on the shared Hanyang data: log10 of the range or the range.

    .venv/bin/python tools/range_bias_check.py [--n 10] [--seed 1]

1. The static sweeps (2-60 m, LOS, ten antenna heights): least squares through the per-file median
   errors, one intercept per height, against the distance and against its log10; the residual rms of
   each (``physynth.calibrate.fit_static_range_bias``).
2. Leave-one-out on the four dynamic Trajectory_A runs, for each law (``calibrate(...,
   range_bias_law=...)`` on three runs, the fourth's geometry with ``transfer_scenario``, ``--n``
   synthetic traces): the median residual in range bins of 5-60 m, synthetic minus real, after removing
   the median of those differences (the run's own offset, which no calibration on other runs knows);
   its rms over the bins is the error in the *shape* of the bias against range.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate, fit_static_range_bias
from physynth.calibrate.geometry import transfer_scenario
from physynth.calibrate.uwb_fit import RANGE_BIAS_LAWS, corrected_residuals
from physynth.generate import generate_traces
from physynth.io.importers import import_hanyang

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
RUNS = (("LOS", "Case_1"), ("LOS", "Case_2"), ("NLOS", "Case_1"), ("NLOS", "Case_2"))
BINS_M = np.array([0, 5, 8, 12, 16, 20, 25, 30, 35, 40, 45, 60])
MIN_ROWS = 50


def binned_median(residual_m: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Median residual per range bin of :data:`BINS_M` (NaN with fewer than MIN_ROWS rows)."""
    idx = np.digitize(range_m, BINS_M)
    return np.array([np.median(residual_m[idx == i]) if (idx == i).sum() >= MIN_ROWS else np.nan
                     for i in range(1, BINS_M.size)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="hanyang-uwb folder")
    ap.add_argument("--n", type=int, default=10, help="synthetic traces per left-out run")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    st = fit_static_range_bias(args.data / "Static_measurements")
    rms = st["residual_std_per_law_m"]
    print(f"static sweeps ({st['n_files']} files, {st['distance_range_m'][0]:.0f}-{st['distance_range_m'][1]:.0f} m): "
          f"{100 * st['range_bias_per_m']:.3f} cm/m leaves {100 * rms['range_bias_per_m']:.1f} cm rms; "
          f"{100 * st['range_bias_per_decade_m']:.1f} cm per decade leaves "
          f"{100 * rms['range_bias_per_decade_m']:.1f} cm rms")
    runs = {f"{e} {c}": import_hanyang(args.data / "Dynamic_measurements" / e / "Trajectory_A" / c, crop_to_uwb=True)[0]
            for e, c in RUNS}
    print(f"leave-one-out bias shape (synthetic minus real median residual per range bin, run offset removed), "
          f"{args.n} traces, seed {args.seed}; bins {BINS_M.tolist()} m")
    for law in RANGE_BIAS_LAWS:
        shape = []
        for left, real in runs.items():
            scn = calibrate([t for k, t in runs.items() if k != left], name="loo", range_bias_law=law).scenario
            res = corrected_residuals(real, scn.uwb.time_offset_s)
            r_real = binned_median(res.residual_m, res.range_m)
            err, rng = [], []
            for t in generate_traces(transfer_scenario(scn, real), n=args.n, seed=args.seed):
                ok = t.uwb.valid
                err.append(t.uwb.range_m[ok] - t.uwb.true_range_m[ok])
                rng.append(t.uwb.true_range_m[ok])
            d = binned_median(np.concatenate(err), np.concatenate(rng)) - r_real
            d -= np.nanmedian(d)
            shape.append(float(np.sqrt(np.nanmean(d**2))))
            print(f"  {law:6s} {left:12s} rms {100 * shape[-1]:.1f} cm: {' '.join(f'{100 * x:+.0f}' for x in d)} cm")
        print(f"  {law:6s} mean over the four runs: {100 * np.mean(shape):.1f} cm")


if __name__ == "__main__":
    main()
