"""Leave-one-run-out tracking study on the four shared Hanyang Trajectory_A runs.

Each run in turn is the test run; the three others are the training runs (the real training data of
NOAUG and AUG_GAN, and the runs SYNTH_PHY's scenario is calibrated on). Every fold is the command

    physynth study tracking --quick --seed S --train A --train B --train C --test D \\
        --methods NOAUG,AUG_GAN,SYNTH_PHY,ekf --out DIR

on datasets made by ``physynth import hanyang RUN --crop-to-uwb``. With ``--long-outages`` (or
``--tag-pattern``, ``--run-slopes``, ``--link-budget``, ``--trusted-truth``) each fold also calibrates its
training runs with ``physynth calibrate --long-outages`` (``--tag-pattern``, ``--run-slopes``, ``--link-budget
--static-sweeps`` the Static_measurements folder beside ``--data``, ``--trusted-truth``) and trains SYNTH_PHY
on that scenario (``--scenario``): rows ``+long`` (``+pattern``, ``+slopes``, ``+budget``, ``+trusted``).
Prints one table: RMSE (m) per fold and seed, the mean over all, and
how often each method beats NOAUG of the same fold and seed.

    .venv/bin/python tools/tracking_cv.py [--seeds 0,1] [--jobs 2] [--long-outages] [--tag-pattern] [--frame F]
                                          [--run-slopes] [--link-budget] [--trusted-truth]
                                          [--turn-test DEG] [--mirror-test] [--methods M,...] [--trusted-score]
                                          [--ensemble] [--study-args "OPTIONS"] [--runs R,R,...] [--out DIR]

``--ensemble`` also prints the seed ensemble: per fold, each method's estimates (the studies'
``estimates.npz``) averaged over the seeds and scored like one study's row, beside the mean of the seeds
scored one by one; then the RMSE by ensemble size K = 1 .. number of seeds (mean over the folds and over
every subset of K seeds).

``--turn-test DEG`` / ``--mirror-test`` pass the same options to every study: each left-out run is scored
turned by DEG about the vertical through its anchor centroid (and mirrored): the same ranges in a world
laid out in another direction (:func:`physynth.transform.turn_trace`), a real run along a direction no
training run took.
``--runs LOS/Case_1,LOS/Case_2,NLOS/Case_1`` leaves each of those runs out in turn and trains on the
others of the list only: leave-one-run-out *inside* the default study's training runs, NLOS Case_2 never
used (how schedule changes are chosen without looking at the four-run table; docs/tracking.md).
``--frame route|turned|compass`` passes ``--frame`` to every study (default turned, as the study's:
randomly turned windows; route: networks in each run's own route frame; compass: the recorded world,
where networks learn the training runs' heading).

Each study takes 2-4 min on one core (quick schedule, one torch thread); ``--jobs`` runs that many
at once (the default 2 suits a 2-core machine: 4 folds x 2 seeds in about 20 min).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from itertools import combinations
from pathlib import Path

import numpy as np

from physynth.data import HANYANG_TRAJECTORY_A_RUNS, hanyang_run_label

RUN_PATHS = {hanyang_run_label(r): r for r in HANYANG_TRAJECTORY_A_RUNS}
"""The runs by their ``--runs`` label (``LOS/Case_1``) -> path under ``Dynamic_measurements``."""
RUNS = tuple(RUN_PATHS)
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"
CLI = [sys.executable, "-m", "physynth.cli"]
ORDER = ("NOAUG", "AUG_GAN", "SYNTH_PHY (synthetic only)", "SYNTH_PHY", "bilstm", "ls", "ekf", "ekf prior",
         "ref: authors' ESKF")


def _run(cmd: list[str], log: Path) -> None:
    with log.open("w") as fh:
        done = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, check=False)
    if done.returncode != 0:
        raise SystemExit(f"failed ({done.returncode}): {' '.join(cmd)}; see {log}")


VARIANTS = (("+long", "--long-outages"), ("+pattern", "--tag-pattern"), ("+slopes", "--run-slopes"),
            ("+budget", "--link-budget"), ("+trusted", "--trusted-truth"))
"""Calibration variants: the row suffix and the ``physynth calibrate`` option."""


def _name(run: str) -> str:
    return run.replace("/", "-")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="Hanyang Dynamic_measurements folder")
    ap.add_argument("--seeds", default="0,1", help="comma-separated seeds")
    ap.add_argument("--jobs", type=int, default=2, help="studies run at once")
    ap.add_argument("--long-outages", action="store_true", help="also SYNTH_PHY on --long-outages scenarios")
    ap.add_argument("--tag-pattern", action="store_true", help="also SYNTH_PHY on --tag-pattern scenarios")
    ap.add_argument("--run-slopes", action="store_true", help="also SYNTH_PHY on --run-slopes scenarios")
    ap.add_argument("--link-budget", action="store_true",
                    help="also SYNTH_PHY on --link-budget scenarios (static sweeps beside the --data folder)")
    ap.add_argument("--trusted-truth", action="store_true",
                    help="also SYNTH_PHY on --trusted-truth scenarios (ranging fitted where the RTK truth is fixed)")
    ap.add_argument("--trusted-score", action="store_true",
                    help="print the RMSE over the steps where the test run's truth is trusted (rmse_trusted_m; "
                         "the RTK fix of the Hanyang runs) instead of over every step")
    ap.add_argument("--ensemble", action="store_true",
                    help="also score the seed ensemble: each method's estimates averaged over the seeds "
                         "(from each study's estimates.npz)")
    ap.add_argument("--frame", choices=("route", "turned", "compass"), default="turned",
                    help="the networks' frame (physynth study tracking --frame)")
    ap.add_argument("--turn-test", type=float, default=0.0, help="turn each test run by this many degrees")
    ap.add_argument("--mirror-test", action="store_true", help="mirror each test run (before the turn)")
    ap.add_argument("--methods", default="NOAUG,AUG_GAN,SYNTH_PHY,ekf")
    ap.add_argument("--runs", default=",".join(RUNS),
                    help="the runs left out in turn, each trained on the others of this list (e.g. "
                         "LOS/Case_1,LOS/Case_2,NLOS/Case_1: leave-one-run-out inside the default training runs)")
    ap.add_argument("--study-args", default="",
                    help='more options for every study, e.g. "--n-synth 96 --pretrain-epochs 15"')
    ap.add_argument("--out", type=Path, default=Path("runs/tracking-cv"))
    return ap


def main() -> None:
    args = _parser().parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    runs = tuple(r.strip() for r in args.runs.split(",") if r.strip())
    if len(runs) < 2 or len(set(runs)) < len(runs) or not set(runs) <= set(RUNS):
        raise SystemExit(f"--runs: two or more distinct runs of {', '.join(RUNS)}, got '{args.runs}'")
    args.out.mkdir(parents=True, exist_ok=True)
    ds = {}
    for run in runs:  # the runs as datasets
        ds[run] = args.out / "data" / _name(run)
        if not (ds[run] / "dataset.json").is_file():
            _run(CLI + ["import", "hanyang", str(args.data / RUN_PATHS[run]), "--crop-to-uwb",
                        "--out", str(ds[run]), "--quiet"], args.out / f"import-{_name(run)}.log")
    extra = ["--frame", args.frame]
    if args.turn_test:
        extra += ["--turn-test", f"{args.turn_test:g}"]
    if args.mirror_test:
        extra += ["--mirror-test"]
    extra += shlex.split(args.study_args)
    jobs = []
    for test in runs:
        train = [r for r in runs if r != test]
        train_args = [a for r in train for a in ("--train", str(ds[r]))]
        scenarios = {}  # the calibrate variants: tag -> scenario calibrated on this fold's training runs
        for tag, flag in VARIANTS:
            if getattr(args, flag[2:].replace("-", "_")):
                scn = args.out / f"{tag[1:]}-without-{_name(test)}.yaml"
                more = ["--static-sweeps", str(args.data.parent / "Static_measurements")] if tag == "+budget" else []
                if not scn.is_file():
                    _run(CLI + ["calibrate", *[str(ds[r]) for r in train], flag, *more, "--out", str(scn),
                                "--quiet"], args.out / f"calibrate-{tag[1:]}-{_name(test)}.log")
                scenarios[tag] = scn
        for seed in seeds:
            base = ["study", "tracking", "--quick", "--seed", str(seed), *train_args, "--test", str(ds[test]),
                    *extra, "--quiet"]
            out = args.out / f"{_name(test)}-s{seed}"
            jobs.append((test, seed, "", CLI + base + ["--methods", args.methods, "--out", str(out)]))
            for tag, scn in scenarios.items():
                out = args.out / f"{_name(test)}-s{seed}-{tag[1:]}"
                jobs.append((test, seed, tag, CLI + base + ["--scenario", str(scn), "--methods", "SYNTH_PHY",
                                                            "--out", str(out)]))

    def one(job: tuple[str, int, str, list[str]]) -> tuple[str, int, str, list[dict]]:
        test, seed, tag, cmd = job
        out = Path(cmd[cmd.index("--out") + 1])
        if not (out / "results.json").is_file():
            _run(cmd, out.with_suffix(".log"))
        print(f"done: test {test}, seed {seed}{tag}", file=sys.stderr)
        return test, seed, tag, json.loads((out / "results.json").read_text())["rows"]

    with ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        results = list(pool.map(one, jobs))
    table: dict[str, dict[tuple[str, int], float]] = {}
    for test, seed, tag, rows in results:
        for r in rows:
            if tag and r["key"].startswith("ref:"):
                continue  # the reference rows do not depend on the scenario
            value = r.get("rmse_trusted_m") if args.trusted_score else r["rmse_m"]
            table.setdefault(r["key"] + tag, {})[(test, seed)] = np.nan if value is None else value
    keys = [k for base in ORDER for k in (base, *(base + tag for tag, _ in VARIANTS)) if k in table]
    what = "RMSE where the test run's truth is trusted" if args.trusted_score else "RMSE"
    print(f"leave-one-run-out, quick schedule, seeds {args.seeds}: {what} (m) per test run, seed by seed")
    print("| method | " + " | ".join(r.replace("/", " ") for r in runs) + " | mean | beats NOAUG |")
    print("|---|" + "---|" * (len(runs) + 2))
    for k in keys:
        v = table[k]
        cells = [" / ".join(f"{v[(r, s)]:.3f}" for s in seeds) for r in runs]
        ref = table.get("NOAUG", {})
        wins = sum((r, s) in ref and v[(r, s)] < ref[(r, s)] for r in runs for s in seeds)
        beats = f"{wins}/{len(runs) * len(seeds)}" if ref else "-"  # NOAUG not among --methods
        print(f"| {k} | " + " | ".join(cells) + f" | {np.mean([v[(r, s)] for r in runs for s in seeds]):.3f} "
              f"| {beats} |")
    if args.ensemble:
        _print_ensemble(args.out, runs, seeds, trusted=args.trusted_score)


def _rmse(est: np.ndarray, truth: np.ndarray, ok: np.ndarray) -> float:
    from physynth.track.scoring import error_stats  # as the study scores (steps without an estimate left out)

    return error_stats(est, truth, ok)["rmse_m"]


def _print_ensemble(out: Path, runs: tuple[str, ...], seeds: list[int], *, trusted: bool) -> None:
    """The seed ensemble: per fold, every method's estimate averaged over the seeds' studies (their
    ``estimates.npz``), scored as the studies score (over ``scored``, and ``trusted`` with --trusted-score)."""
    if len(seeds) < 2:
        raise SystemExit("--ensemble needs two or more --seeds")
    table: dict[str, dict[str, tuple[float, float]]] = {}
    curve: dict[str, dict[int, list[float]]] = {}  # method -> ensemble size -> per fold, mean over subsets
    for run in runs:
        files = [out / f"{_name(run)}-s{s}" / "estimates.npz" for s in seeds]
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise SystemExit(f"--ensemble: no estimates.npz in {', '.join(missing)} (studies of an older release?)")
        loaded = [np.load(f) for f in files]
        ok = loaded[0]["scored"] & (loaded[0]["trusted"] if trusted else True)
        truth = loaded[0]["truth_enu_m"]
        for key in (k for k in loaded[0].files if k.startswith("estimate/")):
            ests = [d[key] for d in loaded]
            single = float(np.mean([_rmse(e, truth, ok) for e in ests]))
            table.setdefault(key.split("/", 1)[1], {})[run] = (single, _rmse(np.mean(ests, axis=0), truth, ok))
            by_size = curve.setdefault(key.split("/", 1)[1], {})
            for k in range(1, len(seeds) + 1):  # every subset of k seeds, so no seed order is favoured
                by_size.setdefault(k, []).append(np.mean([_rmse(np.mean([ests[i] for i in sub], axis=0), truth, ok)
                                                          for sub in combinations(range(len(seeds)), k)]))
    print(f"\nseed ensemble (estimates averaged over seeds {','.join(map(str, seeds))}): RMSE (m) of the "
          "ensemble, with the mean of the single seeds in brackets")
    print("| method | " + " | ".join(r.replace("/", " ") for r in runs) + " | mean |")
    print("|---|" + "---|" * (len(runs) + 1))
    for k, v in table.items():
        cells = [f"{v[r][1]:.3f} ({v[r][0]:.3f})" for r in runs]
        print(f"| {k} | " + " | ".join(cells) + f" | {np.mean([v[r][1] for r in runs]):.3f} "
              f"({np.mean([v[r][0] for r in runs]):.3f}) |")
    sizes = range(1, len(seeds) + 1)
    print("\nby ensemble size K: mean RMSE (m) over the folds and over every subset of K of the seeds")
    print("| method | " + " | ".join(f"K = {k}" for k in sizes) + " |")
    print("|---|" + "---|" * len(sizes))
    for name, by_size in curve.items():
        print(f"| {name} | " + " | ".join(f"{np.mean(by_size[k]):.3f}" for k in sizes) + " |")


if __name__ == "__main__":
    main()
