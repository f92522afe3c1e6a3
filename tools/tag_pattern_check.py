"""Does the ranging error of the shared Hanyang walks follow the anchors' bearing from the walker's heading?

    .venv/bin/python tools/tag_pattern_check.py [--data ../shared/data/hanyang-uwb]

1. The fit ``physynth calibrate`` makes (:func:`physynth.calibrate.tag_pattern.fit_tag_pattern`): the
   pattern c1 cos(phi) + s1 sin(phi) + c2 cos(2 phi) + s2 sin(2 phi), phi the anchor's bearing relative to
   the direction of travel, on the four runs together and on each alone, with the jackknife standard
   errors and the Wald statistic.
2. The steps at the turns: the median residual of each anchor 1.5-3.5 s after each turn of >= 60 deg
   (between east-west legs, where the anchors lie ahead or behind, and north-south legs, where they lie
   beside the walker) minus its median 1.5-3.5 s before, averaged over the anchors; the walker moves
   about 3 m in between, so a position-bound error barely changes while a heading-bound one steps by
   about 2 c2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.calibrate.uwb_fit import corrected_residuals
from physynth.io.importers import import_hanyang

RUNS = (("LOS", "Case_1"), ("LOS", "Case_2"), ("NLOS", "Case_1"), ("NLOS", "Case_2"))
DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"


def _turn_steps(trace, lag_s: float) -> dict[str, list[float]]:
    """Mean over anchors of the median residual after minus before each turn, by kind of turn [m]."""
    truth = trace.truth
    v = truth.vel_enu_mps
    speed, hd = np.hypot(v[:, 0], v[:, 1]), np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    k = int(round(1.5 / np.median(np.diff(truth.t_s))))
    dh = np.zeros_like(hd)
    dh[k:-k] = hd[2 * k:] - hd[:-2 * k]
    turns: list[int] = []
    for i in np.flatnonzero((np.abs(dh) > np.radians(60)) & (speed > 0.5)):  # one turn per 5 s: its sharpest
        if turns and truth.t_s[i] - truth.t_s[turns[-1]] <= 5.0:
            if abs(dh[i]) > abs(dh[turns[-1]]):
                turns[-1] = i
        else:
            turns.append(i)
    r = corrected_residuals(trace, lag_s)
    out: dict[str, list[float]] = {"east-west to north-south": [], "north-south to east-west": []}
    for i in turns:
        t0 = truth.t_s[i]
        ew_before = abs(np.cos(np.interp(t0 - 2.5, truth.t_s, hd))) > 0.7
        ew_after = abs(np.cos(np.interp(t0 + 2.5, truth.t_s, hd))) > 0.7
        if ew_before == ew_after:
            continue
        tt = r.t_s - lag_s
        steps = []
        for a in np.unique(r.anchor):
            m = r.anchor == a
            before = m & (tt > t0 - 3.5) & (tt < t0 - 1.5)
            after = m & (tt > t0 + 1.5) & (tt < t0 + 3.5)
            if before.sum() > 5 and after.sum() > 5:
                step = float(np.median(r.residual_m[after]) - np.median(r.residual_m[before]))
                if abs(step) < 0.3:  # an NLOS episode on one side is no step of the pattern
                    steps.append(step)
        if steps:
            out["east-west to north-south" if ew_before else "north-south to east-west"].append(float(np.mean(steps)))
    return out


def _row(label: str, rep: dict) -> str:
    c, se = np.asarray(rep["fitted_coef_m"]) * 100, np.asarray(rep["std_error_m"]) * 100
    cells = " | ".join(f"{x:+.2f} +- {s:.2f}" for x, s in zip(c, se, strict=True))
    return f"| {label} | {cells} | {rep['wald']:.1f} | {', '.join(rep['terms_kept']) or '-'} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="hanyang-uwb folder")
    args = ap.parse_args()
    runs = {f"{env} {case}": import_hanyang(args.data / "Dynamic_measurements" / env / "Trajectory_A" / case,
                                            crop_to_uwb=True)[0] for env, case in RUNS}
    print("pattern fitted by calibrate [cm], jackknife standard errors")
    print("| runs | cos phi | sin phi | cos 2 phi | sin 2 phi | Wald | terms kept |")
    print("|---|---|---|---|---|---|---|")
    fit = calibrate(list(runs.values()))
    print(_row("all four", fit.report["tag_pattern"]))
    lags = {}
    for name, tr in runs.items():
        one = calibrate(tr)
        lags[name] = one.scenario.uwb.time_offset_s
        print(_row(name, one.report["tag_pattern"]))
    print("\nresidual step at the turns [cm], mean over the anchors, per turn")
    print("| run | east-west to north-south | north-south to east-west |")
    print("|---|---|---|")
    for name, tr in runs.items():
        steps = _turn_steps(tr, lags[name])
        cells = [f"{100 * np.mean(s):+.1f} (se {100 * np.std(s, ddof=1) / np.sqrt(len(s)):.1f}, {len(s)} turns)"
                 for s in steps.values()]
        print(f"| {name} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
