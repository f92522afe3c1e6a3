"""Held-out evidence per calibration component: what generating its optional effect gains on a run left out.

For each shared Hanyang Trajectory_A run in turn (or those of ``--runs``): calibrate on the three others,
validate with transfer on the left-out run the scenario as calibrated and, for every component whose
optional effect the calibration fitted (``Component.without`` in ``physynth.calibrate.pipeline.COMPONENTS``:
late stamps, run-to-run spreads, antenna sway, tag-side NLOS, the link budget with ``--link-budget``), the
scenario without it. The loop is the library's :func:`physynth.calibrate.held_out.held_out_evidence` (the one
``physynth calibrate --select-components evidence`` runs on its own input runs). The evidence is computed the
same way for every component: how much each deviation from the left-out run (KS statistic x 100, UWB >= 1
and mean AoI relative deviations in %, the absolute signed-median difference in cm) grows when the effect
is taken out; positive: the component earns its place on that measure. The last rows give each component's
mean gain, its combined gain (the mean over the measures) and the keep/drop decision of
``physynth.calibrate.held_out.DROP_RULE``.

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

from physynth.calibrate.held_out import MEASURES, held_out_evidence

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _hanyang import import_runs, loo_arguments  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    loo_arguments(ap, n=20)
    ap.add_argument("--runs", default="0,1,2,3", help="indices of the left-out runs (LOS 1, LOS 2, NLOS 1, NLOS 2)")
    ap.add_argument("--components", default=None, help="only these components (names, comma-separated)")
    ap.add_argument("--link-budget", action="store_true", help="calibrate with link_budget=True (static sweeps)")
    args = ap.parse_args()
    print(f"held-out evidence, {args.n} synthetic traces per validation, seed {args.seed}; gain = deviation "
          "without the component - with it (positive: it helps)")
    print("| left-out run | component | " + " | ".join(f"{m} with / gain" for m in MEASURES) + " |")
    print("|---|---|" + "---|" * len(MEASURES))

    def row(left, res, with_dev, gains) -> None:  # noqa: ARG001
        for name, gain in gains.items():
            if isinstance(gain, str):
                print(f"| {left} | {name} | {gain} |")
            else:
                print(f"| {left} | {name} | "
                      + " | ".join(f"{w:.2f} / {g:+.2f}" for w, g in zip(with_dev, gain, strict=True)) + " |")

    with tempfile.TemporaryDirectory() as tmp:
        _, traces = import_runs(args.data, Path(tmp))
        ev = held_out_evidence(list(traces.values()), labels=list(traces), n=args.n, seed=args.seed,
                               left_out=[int(x) for x in args.runs.split(",")],
                               components=None if args.components is None else args.components.split(","),
                               link_budget=args.link_budget,
                               static_sweeps=args.data / "Static_measurements" if args.link_budget else None,
                               on_run=row)
    for name, c in ev.components.items():
        if c.mean_gain is not None:
            print(f"| mean over {len(c.gains)} run(s) | {name} | " + " | ".join(f"{x:+.2f}" for x in c.mean_gain)
                  + f" | combined {c.combined:+.2f}: {c.decision} |")
        else:
            print(f"| no run | {name} | no evidence: kept |")


if __name__ == "__main__":
    main()
