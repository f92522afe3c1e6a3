"""Time structure of the ranging errors on Hanyang runs left out of the calibration: with the antenna sway,
and with white LOS errors of the same spread (the model before it), side by side.

    .venv/bin/python tools/sway_check.py [--n 10] [--seed 1] [--data ../shared/data/hanyang-uwb]

For each of the four shared Trajectory_A runs: calibrate on the three others, transfer the scenario
onto the left-out run (``validate --transfer``'s scenario), generate ``--n`` traces; then on both sides
the residuals of the ranges within 0.5 m of the run's median residual (the outliers left out: they
dominate the report's ``residual_acf``, whose 0.65 / 0.33 / 0.04 is the outliers' 0.3 s holding), each
taken against the truth at the stamp minus the lag (the calibrated one on the real side, the trace's own
on the synthetic side), their (anchor) means removed: the autocorrelation one, two, five, ten and twenty
attempts of one anchor apart (about 0.1, 0.2, 0.5, 1 and 2 s), and the mean correlation between the
anchors' residuals at the same burst. "white" is the same scenario with ``uwb.antenna_sway_std_m`` 0 and
each anchor's ``los_std_m`` given back the swaying part (the total LOS spread unchanged).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate, transfer_scenario
from physynth.generate import generate_traces
from physynth.io.importers import import_hanyang
from physynth.records import Trace
from physynth.scenario import Scenario, scenario_from_dict, scenario_to_dict

RUNS = ("LOS/Trajectory_A/Case_1", "LOS/Trajectory_A/Case_2", "NLOS/Trajectory_A/Case_1", "NLOS/Trajectory_A/Case_2")
DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
LAGS = (1, 2, 5, 10, 20)


def inlier_residuals(t: Trace, lag_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(residual, anchor, burst) of the delivered ranges within 0.5 m of the median, against the truth at
    the stamp minus ``lag_s``, each anchor's mean removed."""
    u = t.uwb
    ok = u.valid & np.isfinite(u.range_m)
    a = u.anchor[ok].astype(np.intp)
    p = t.truth.position_at(u.t_s[ok] - lag_s)
    r = u.range_m[ok] - np.linalg.norm(p - t.anchors.pos_enu_m[a], axis=1)
    keep = np.isfinite(r) & (np.abs(r - np.nanmedian(r)) < 0.5)
    r, a = r[keep], a[keep]
    b = (u.burst[ok][keep] if u.burst is not None else np.arange(r.size))
    r = r - (np.bincount(a, weights=r) / np.maximum(np.bincount(a), 1))[a]
    return r, a, b


def structure(traces: list[Trace], lags: list[float]) -> tuple[np.ndarray, float]:
    """Pooled autocorrelation at LAGS (attempts of one anchor) and the mean cross-anchor correlation."""
    num, den, cross = np.zeros(len(LAGS)), 0.0, []
    for t, lag in zip(traces, lags, strict=True):
        r, a, b = inlier_residuals(t, lag)
        order = np.lexsort((b, a))
        x, aa = r[order], a[order]
        den += float(x @ x)
        for j, k in enumerate(LAGS):
            same = aa[k:] == aa[:-k]
            num[j] += float(x[k:][same] @ x[:-k][same])
        ids = np.unique(a)
        grid = np.full((int(b.max()) + 1 if b.size else 0, ids.size), np.nan)
        for i, aid in enumerate(ids):
            grid[b[a == aid], i] = r[a == aid]
        for i in range(ids.size):
            for k in range(i + 1, ids.size):
                m = np.isfinite(grid[:, i]) & np.isfinite(grid[:, k])
                if m.sum() > 50:
                    cross.append(float(np.corrcoef(grid[m, i], grid[m, k])[0, 1]))
    return num / den, float(np.mean(cross)) if cross else float("nan")


def white_twin(scn: Scenario, slow_share: float) -> Scenario:
    """The scenario without the sway, each LOS std given back the swaying part."""
    d = scenario_to_dict(scn)
    f = 1.0 / np.sqrt(1.0 - slow_share)
    d["uwb"]["antenna_sway_std_m"] = 0.0
    d["channel"]["los_std_m"] *= f
    for over in d["channel_per_anchor"].values():
        if over.get("los_std_m"):
            over["los_std_m"] *= f
    return scenario_from_dict(d, "white twin")


def _scale(fit: dict) -> str:
    """The fitted sway's scale on its clock: tau on the time clock, length (and turn) on the walker's motion."""
    if fit.get("tau_s") is not None:
        return f"tau {fit['tau_s']:.2f} s"
    turn = f", turn {fit['turn_rad']:.2f} rad" if fit.get("turn_rad") is not None else ""
    return f"length {fit['length_m']:.1f} m{turn}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT, help="hanyang-uwb folder")
    ap.add_argument("--n", type=int, default=10, help="synthetic traces per left-out run")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    runs = {r: import_hanyang(args.data / "Dynamic_measurements" / r, crop_to_uwb=True)[0] for r in RUNS}
    head = " / ".join(f"{k}" for k in LAGS)
    print(f"autocorrelation at {head} attempts apart; cross-anchor correlation")
    print("| left-out run | sway fitted (std; tau, or length and turn) | real | with the sway | white (before) |")
    print("|---|---|---|---|---|")
    for left, real in runs.items():
        res = calibrate([t for r, t in runs.items() if r != left], name="sway-check")
        fit = res.report["sections"]["antenna_sway"] if "sections" in res.report else res.report["antenna_sway"]
        scn = transfer_scenario(res.scenario, [real])
        cells = [structure([real], [scn.uwb.time_offset_s])]
        for s in (scn, white_twin(scn, fit["slow_share"]) if fit["identifiable"] else scn):
            syn = list(generate_traces(s, args.n, seed=args.seed))
            cells.append(structure(syn, [t.meta.get("uwb_time_offset_s", s.uwb.time_offset_s) for t in syn]))
        text = [" / ".join(f"{x:.2f}" for x in acf) + f"; {cross:.2f}" for acf, cross in cells]
        sway = f"{fit['std_m']:.3f} m, {_scale(fit)}" if fit["identifiable"] else "none"
        print(f"| {left.replace('/Trajectory_A/', ' ')} | {sway} | " + " | ".join(text) + " |")


if __name__ == "__main__":
    main()
