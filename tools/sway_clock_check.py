"""What the slow ranging error of the shared Hanyang walks follows: time, distance travelled or turning.

For the four shared Trajectory_A runs: each anchor's ranges against the truth (positions interpolated
at the UWB stamps minus the lag the calibration fits, about 0.17 s), rows within 0.3 m of the anchor's
median (LOS-like), the anchor's mean removed; pairs of one anchor's rows up to 3 s apart, pooled over
anchors and runs. Prints their semivariogram gamma = E (x_i - x_j)^2 / 2 [m^2]

- of the pairs between which the tag travelled under 5 cm (it stood), by time apart, next to what the
  calibrated time clock predicts;
- of the moving pairs, by distance travelled (rows) and angle turned (columns);

then calibrates on the four runs and prints each clock's fit (``antenna_sway.fits`` of the report).

    .venv/bin/python tools/sway_clock_check.py [--data ../shared/data/hanyang-uwb]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.io.importers import import_hanyang
from physynth.models.uwb import travelled_m, turned_rad

RUNS = (("LOS", "Case_1"), ("LOS", "Case_2"), ("NLOS", "Case_1"), ("NLOS", "Case_2"))
DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
LAG_S = 0.17
DIST_EDGES = [0.05, 0.5, 1.0, 1.5, 2.0, 3.0]
TURN_EDGES = [0.1, 0.3, 0.6, 1.0]


def pairs(trace) -> np.ndarray:
    """(dt, distance, angle, squared difference / 2) of every pair of one anchor's rows up to 3 s apart."""
    u, tr = trace.uwb, trace.truth
    dist = travelled_m(tr.t_s, tr.vel_enu_mps)
    turn = turned_rad(tr.t_s, tr.vel_enu_mps, tr.omega_body_radps)
    out = []
    for a in range(len(trace.anchors)):
        m = u.valid & (u.anchor == a)
        t = u.t_s[m] - LAG_S
        pos = np.stack([np.interp(t, tr.t_s, tr.pos_enu_m[:, k]) for k in range(3)], axis=1)
        r = u.range_m[m] - np.linalg.norm(pos - trace.anchors.pos_enu_m[a], axis=1)
        keep = np.abs(r - np.median(r)) < 0.3
        t, r = t[keep], r[keep] - r[keep].mean()
        c, h = np.interp(t, tr.t_s, dist), np.interp(t, tr.t_s, turn)
        for k in range(1, 60):
            dt = t[k:] - t[:-k]
            s = dt <= 3.0
            if not s.any():
                break
            out.append(np.column_stack([dt[s], (c[k:] - c[:-k])[s], (h[k:] - h[:-k])[s],
                                        0.5 * ((r[k:] - r[:-k]) ** 2)[s]]))
    return np.vstack(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="hanyang-uwb folder")
    args = ap.parse_args()
    traces = [import_hanyang(args.data / "Dynamic_measurements" / env / "Trajectory_A" / case, crop_to_uwb=True)[0]
              for env, case in RUNS]
    p = np.vstack([pairs(t) for t in traces])
    dt, dc, dh, g = p.T
    fit = calibrate(traces).report["antenna_sway"]
    time_fit = fit["fits"].get("time")
    print(f"{p.shape[0]} pairs of rows up to 3 s apart, four runs; semivariogram [m^2]")
    print("\nstanding (under 5 cm travelled), by time apart; the time clock's prediction var0 - s^2 exp(-dt/tau):")
    for lo, hi in ((0.2, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.0)):
        s = (dc < 0.05) & (dt >= lo) & (dt < hi)
        pred = (fit["var_m2"] - time_fit["std_m"] ** 2 * np.exp(-0.5 * (lo + hi) / time_fit["tau_s"])
                if time_fit else float("nan"))
        print(f"  {lo:.1f}-{hi:.1f} s: {g[s].mean():.5f} ({int(s.sum())} pairs); time clock {pred:.5f}")
    print("\nmoving, by distance travelled (rows) and angle turned (columns):")
    heads = ["<0.1", "0.1-0.3", "0.3-0.6", "0.6-1", ">1 rad"]
    print("  " + " " * 10 + "".join(f"{h:>17s}" for h in heads))
    bd, bh = np.digitize(dc, DIST_EDGES), np.digitize(dh, TURN_EDGES)
    labels = ["<0.05", "0.05-0.5", "0.5-1", "1-1.5", "1.5-2", "2-3", ">3"]
    for i in range(1, len(labels)):
        cells = []
        for j in range(len(heads)):
            s = (bd == i) & (bh == j)
            cells.append(f"{g[s].mean():.5f} ({int(s.sum()):5d})" if s.sum() >= 30 else "-")
        print(f"  {labels[i] + ' m':10s}" + "".join(f"{c:>17s}" for c in cells))
    print(f"\ncalibrated on the four runs: clock {fit['clock']}, std {fit['std_m']:.4f} m, "
          f"var0 {fit['var_m2']:.5f} m^2")
    for k, v in fit["fits"].items():
        print(f"  {k}: " + ", ".join(f"{q} {z:.4g}" for q, z in v.items() if z is not None))


if __name__ == "__main__":
    main()
