"""Held-out evidence per calibration component: what generating its optional effect gains on a run left out.

For each shared Hanyang Trajectory_A run in turn (or those of ``--runs``): calibrate on the three others,
validate with ``--transfer`` on the left-out run the scenario as calibrated and, for every component
whose optional effect the calibration fitted (``Component.without`` in
``physynth.calibrate.pipeline.COMPONENTS``: late stamps, run-to-run spreads, antenna sway, tag-side NLOS,
the link budget with ``--link-budget``), the scenario without it. The evidence is computed the same way
for every component: how much each deviation from the left-out run (KS statistic x 100, UWB >= 1 and
mean AoI relative deviations in %, the absolute signed-median difference in cm) grows when the effect
is taken out; positive: the component earns its place on that measure.

    .venv/bin/python tools/component_evidence.py [--n 20] [--seed 1] [--runs 0,1,2,3] [--components a,b]
                                                 [--link-budget] [--data ../shared/data/hanyang-uwb]

Each left-out run costs one calibration and one validation per component plus one (about 10 s each at
``--n 20`` on one core).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from physynth.calibrate import calibrate
from physynth.calibrate.pipeline import COMPONENTS
from physynth.workflows import validate_datasets

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _hanyang import import_runs, loo_arguments  # noqa: E402

MEASURES = ("KS x 100", "UWB>=1 dev. %", "mean AoI dev. %", "|median diff.| cm")


def deviations(rep) -> np.ndarray:
    """The validation's deviations from the real run, in the units of :data:`MEASURES` (smaller: closer)."""
    c = rep.comparison
    return np.array([100.0 * rep.ks_statistic, abs(c["uwb_ge1_frac"]["deviation"]), abs(c["mean_aoi_s"]["deviation"]),
                     100.0 * abs(c["residual_median_m"]["deviation"])])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    loo_arguments(ap, n=20)
    ap.add_argument("--runs", default="0,1,2,3", help="indices of the left-out runs (LOS 1, LOS 2, NLOS 1, NLOS 2)")
    ap.add_argument("--components", default=None, help="only these components (names, comma-separated)")
    ap.add_argument("--link-budget", action="store_true", help="calibrate with link_budget=True (static sweeps)")
    args = ap.parse_args()
    chosen = [c for c in COMPONENTS if c.without is not None
              and (args.components is None or c.name in args.components.split(","))]
    gains: dict[str, list[np.ndarray]] = {c.name: [] for c in chosen}
    print(f"held-out evidence, {args.n} synthetic traces per validation, seed {args.seed}; gain = deviation "
          "without the component - with it (positive: it helps)")
    print("| left-out run | component | " + " | ".join(f"{m} with / gain" for m in MEASURES) + " |")
    print("|---|---|" + "---|" * len(MEASURES))
    with tempfile.TemporaryDirectory() as tmp:
        dirs, traces = import_runs(args.data, Path(tmp))
        names = list(traces)
        for k in (int(x) for x in args.runs.split(",")):
            left = names[k]
            res = calibrate([traces[o] for o in names if o != left], name="evidence", link_budget=args.link_budget,
                            static_sweeps=args.data / "Static_measurements" if args.link_budget else None)
            with_dev = deviations(validate_datasets(dirs[left], scenario=res.scenario, n=args.n, seed=args.seed,
                                                    transfer=True))
            for comp in chosen:
                if not res.report["components"][comp.name]["fitted"]:
                    print(f"| {left} | {comp.name} | not fitted: {res.report['components'][comp.name].get('why')} |")
                    continue
                without = comp.without(res.scenario, res.report)
                if without == res.scenario:
                    print(f"| {left} | {comp.name} | nothing generated to take out |")
                    continue
                gain = deviations(validate_datasets(dirs[left], scenario=without, n=args.n, seed=args.seed,
                                                    transfer=True)) - with_dev
                gains[comp.name].append(gain)
                print(f"| {left} | {comp.name} | "
                      + " | ".join(f"{w:.2f} / {g:+.2f}" for w, g in zip(with_dev, gain, strict=True)) + " |")
    for name, g in gains.items():
        if g:
            mean = np.mean(g, axis=0)
            print(f"| mean over {len(g)} run(s) | {name} | " + " | ".join(f"{x:+.2f}" for x in mean) + " |")


if __name__ == "__main__":
    main()
