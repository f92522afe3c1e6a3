"""How the ranging errors of the anchors of one burst move together, real against synthetic.

For each shared Hanyang Trajectory_A run in turn: calibrate on the three others (as the tracking study
does), generate ``--n`` traces of that calibration, and print for the real run and the synthetic traces

- the within-burst deviation std (each row's residual minus the mean of its burst, bursts of 3+ anchors,
  rows within 0.5 m of the anchor's median) and the std of the burst means, by distance of the tag: the
  deviation is what moves range DIFFERENCES, which carry the direction to a far tag;
- the correlation of the residuals of two anchors ranged in the same burst where one of them is beyond
  0.15 m (the wide errors), and the std of their difference beyond 25 m;
- the tag-side NLOS fraction the calibration estimates (report section ``tag_nlos``).

    .venv/bin/python tools/cross_anchor_check.py [--n 6] [--tag P]

``--tag P`` generates with ``uwb.tag_nlos_prob`` = P instead of 0 (the calibrated scenarios' value);
``--tag fit`` with each calibration's own estimate.
"""

from __future__ import annotations

import argparse

import numpy as np

from physynth.calibrate import calibrate
from physynth.generate import generate_trace
from physynth.studies.tracking import hanyang_default_runs
from physynth.track.gan import range_residuals

BINS = (0, 10, 20, 30, 40, 60)


def _rows(trace, lag: float):
    rows, geo, res = range_residuals(trace, lag)
    anchor, t = trace.uwb.anchor[rows], trace.uwb.t_s[rows]
    for k in np.unique(anchor):
        res[anchor == k] -= np.median(res[anchor == k])
    return geo, res, np.concatenate([[0], np.cumsum(np.diff(t) > 0.03)])


def _deviation(trace, lag: float):
    geo, res, burst = _rows(trace, lag)
    ok = np.abs(res) < 0.5
    geo, res, burst = geo[ok], res[ok], burst[ok]
    n = np.bincount(burst)
    mean = np.bincount(burst, res) / np.maximum(n, 1)
    multi = n[burst] >= 3
    dev = (res - mean[burst])[multi] * np.sqrt(n[burst][multi] / (n[burst][multi] - 1))
    first = np.concatenate([[True], np.diff(burst) != 0]) & multi
    return geo[multi], dev, geo[first], mean[burst][first]


def _pairs(trace, lag: float):
    geo, res, burst = _rows(trace, lag)
    keep = np.abs(res) < 1.0
    res, burst, geo = res[keep], burst[keep], geo[keep]
    i = np.flatnonzero(burst[1:] == burst[:-1])
    return res[i], res[i + 1], geo[i]


def _line(label: str, traces, lag: float) -> str:
    d = [_deviation(t, lag) for t in traces]
    g, dev = np.concatenate([x[0] for x in d]), np.concatenate([x[1] for x in d])
    gc, cm = np.concatenate([x[2] for x in d]), np.concatenate([x[3] for x in d])
    cells = [f"{np.std(dev[(g >= lo) & (g < hi)]) * 100:4.1f}/{np.std(cm[(gc >= lo) & (gc < hi)]) * 100:4.1f}"
             for lo, hi in zip(BINS, BINS[1:], strict=False)]
    p = [_pairs(t, lag) for t in traces]
    x, y, gp = (np.concatenate([q[k] for q in p]) for k in range(3))
    wide = (np.abs(x) > 0.15) | (np.abs(y) > 0.15)
    far = gp > 25
    return (f"| {label} | " + " | ".join(cells) + f" | {np.corrcoef(x[wide], y[wide])[0, 1]:.2f} | "
            f"{np.std(x[far] - y[far]) * 100:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6, help="synthetic traces per left-out run")
    ap.add_argument("--tag", default="0", help="uwb.tag_nlos_prob of the synthetic traces: a number, or fit")
    args = ap.parse_args()
    train, last = hanyang_default_runs()
    runs = [*train, last]
    print("within-burst deviation std / burst-mean std (cm) by tag distance (m); wide-error correlation; "
          "difference std beyond 25 m (cm)")
    print("| run | " + " | ".join(f"{lo}-{hi}" for lo, hi in zip(BINS, BINS[1:], strict=False))
          + " | corr (>0.15 m) | diff std |")
    print("|---|" + "---|" * (len(BINS) + 1))
    for k, test in enumerate(runs):
        res = calibrate([r.trace for i, r in enumerate(runs) if i != k], anchor_policy="per-run")
        scn, lag = res.scenario, res.scenario.uwb.time_offset_s
        fit = res.report["tag_nlos"]["prob"]
        p = fit if args.tag == "fit" else float(args.tag)
        scn = scn.model_copy(update={"uwb": scn.uwb.model_copy(update={"tag_nlos_prob": p})})
        name = test.label.replace("/Trajectory_A/", " ")
        print(_line(f"{name}, real", [test.trace], lag))
        print(_line(f"{name}, synthetic (tag {p:.4f}; estimated {fit:.4f})",
                    [generate_trace(scn, i, 5) for i in range(args.n)], lag))


if __name__ == "__main__":
    main()
