"""Where a network trained on synthetic traces fails on a real run: the sim-to-real gap, split up.

One fold of the tracking study (``physynth study tracking --quick``): the network is pre-trained on
synthetic traces of the calibration on the training runs (SYNTH_PHY, then fine-tuned on them), and
scored on

- ``real``: the left-out real run;
- ``synthetic``: fresh synthetic traces of the same calibration (root seed 777, never trained on): what
  the network can do on data like its training data;
- ``twin``: synthetic traces of a calibration on the left-out run alone: the real run's own generator.

and the constant-velocity EKF on the same three. Each error is split into radial (along the line from
the anchor centroid to the tag), lateral (across it) and vertical parts, into grid steps where some
anchor has not ranged for more than a second (an outage) and the others, and by the tag's distance from
the anchor centroid. If the network does much better on ``synthetic`` than on ``real``, the generator
misses something the real run has; if about as well, the learner (its size, schedule, amount of data)
is the limit; the split says which part of the error differs.

    .venv/bin/python tools/tracking_gap.py [--test 1] [--seed 0] [--n-eval 4] [--no-tag-nlos]

``--no-tag-nlos`` sets each calibration's tag-side NLOS fraction (``uwb.tag_nlos_prob``, which the
calibration fits and puts in: docs/calibration.md) to 0, the model before it.

``--test`` is the index of the left-out run in LOS Case_1, LOS Case_2, NLOS Case_1, NLOS Case_2
(the three others train). About 4 min on one core.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from physynth.calibrate import calibrate  # noqa: E402
from physynth.generate import generate_trace  # noqa: E402
from physynth.studies.tracking import (  # noqa: E402
    _synth_phy,
    _time_offset,
    hanyang_default_runs,
    quick_config,
)
from physynth.track import require_torch  # noqa: E402
from physynth.track.inputs import track_input  # noqa: E402
from physynth.track.trackers import make_tracker  # noqa: E402

BINS_M = (0, 10, 20, 30, 40, 60)
STALE_S = 1.0


def _without_tag(res):
    """The calibrated scenario without its tag-side NLOS (``uwb.tag_nlos_prob`` 0)."""
    s = res.scenario
    return s.model_copy(update={"uwb": s.uwb.model_copy(update={"tag_nlos_prob": 0.0})})


def _split(est: np.ndarray, inp) -> np.ndarray:
    """Rows (radial, lateral, vertical error, distance, stale) of the scored grid steps of one trace."""
    pos, mask = inp.pos_enu_m, inp.eval_mask()
    centre = inp.anchor_pos_enu_m.mean(axis=0)
    err = est - pos
    r = pos[:, :2] - centre[:2]
    dist = np.linalg.norm(r, axis=1)
    u = r / np.maximum(dist[:, None], 1e-9)
    radial = np.sum(err[:, :2] * u, axis=1)
    lateral = err[:, 1] * u[:, 0] - err[:, 0] * u[:, 1]
    stale = np.nanmax(np.where(np.isfinite(inp.aoi_s), inp.aoi_s, np.inf), axis=1) > STALE_S
    return np.c_[radial, lateral, err[:, 2], dist, stale][mask & np.all(np.isfinite(est), axis=1)]


def _row(name: str, rows: np.ndarray) -> str:
    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")

    total = np.linalg.norm(rows[:, :3], axis=1)
    stale = rows[:, 4] > 0
    bins = [rms(np.linalg.norm(rows[(rows[:, 3] >= lo) & (rows[:, 3] < hi), :2], axis=1))
            for lo, hi in zip(BINS_M, BINS_M[1:], strict=False)]
    return (f"| {name} | {rms(total):.2f} | {rms(rows[:, 0]):.2f} | {rms(rows[:, 1]):.2f} | {rms(rows[:, 2]):.2f} "
            f"| {100 * stale.mean():.0f} % | {rms(total[stale]):.2f} | {rms(total[~stale]):.2f} | "
            + " | ".join(f"{b:.2f}" for b in bins) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--test", type=int, default=1, choices=range(4), help="index of the left-out run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-eval", type=int, default=4, help="synthetic traces scored per synthetic set")
    ap.add_argument("--no-tag-nlos", action="store_true", help="the calibrations without their tag-side NLOS")
    args = ap.parse_args()
    require_torch().set_num_threads(1)
    train3, last = hanyang_default_runs()
    runs = [*train3, last]
    test = runs[args.test]
    train = [r for i, r in enumerate(runs) if i != args.test]
    lag, _ = _time_offset([r.trace for r in train])
    train_inputs = [track_input(r.trace, time_offset_s=lag, label=r.label) for r in train]
    scn = calibrate([r.trace for r in train], name="tracking-study-calibrated", anchor_policy="per-run")
    twin = calibrate([test.trace], name="twin")
    scn, twin = (_without_tag(r) if args.no_tag_nlos else r.scenario for r in (scn, twin))
    sets = {"real": [track_input(test.trace, time_offset_s=lag)],
            "synthetic": [track_input(generate_trace(scn, i, 777), time_offset_s=lag) for i in range(args.n_eval)],
            "twin": [track_input(generate_trace(twin, i, 777), time_offset_s=lag) for i in range(args.n_eval)]}
    for inputs in sets.values():  # the real runs have no IMU: no tracker sees one
        for inp in inputs:
            object.__setattr__(inp, "acc_mps2", None)
    scored: dict[tuple[str, str], np.ndarray] = {}

    def score(name: str, tracker) -> None:
        for key, inputs in sets.items():
            scored[(name, key)] = np.concatenate([_split(tracker.predict(i), i) for i in inputs])

    net = _synth_phy(train, [r.trace for r in train], train_inputs, scn, quick_config(seed=args.seed),
                     {"use_imu": False}, lambda *_: None, {}, score)
    score("SYNTH_PHY", net)
    score("ekf", make_tracker("ekf").fit(train_inputs))
    print(f"test run {test.label}, seed {args.seed}: RMSE (m); outage = some anchor silent > {STALE_S:g} s")
    print("| tracker on | total | radial | lateral | vertical | in outage | outage | rest | "
          + " | ".join(f"{lo}-{hi} m" for lo, hi in zip(BINS_M, BINS_M[1:], strict=False)) + " |")
    print("|---|" + "---|" * (7 + len(BINS_M) - 1))
    for (name, key), rows in scored.items():
        print(_row(f"{name}, {key}", rows))


if __name__ == "__main__":
    main()
