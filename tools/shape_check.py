"""Do the learned trackers follow a route of another shape? A synthetic loop at the Hanyang site.

Every shared real run walks Trajectory_A (out east of the anchors in a zig-zag and back), so no real run
can say how a network trained on them does on a route of another shape. This check makes one: the
scenario calibrated on three real runs (LOS Case_1, LOS Case_2, NLOS Case_1; their channel, availability
and motion), the anchors of NLOS Case_2, and a loop of about 100 m east of the anchors instead of the
real path (``physynth generate`` of that scenario, trace 0, seed 7). Then, for each ``--frame``,

    physynth study tracking --quick --seed S --train A --train B --train C --test LOOP --frame F \\
        --methods NOAUG,SYNTH_PHY,ekf --out DIR

on datasets made by ``physynth import hanyang RUN --crop-to-uwb``, and one RMSE table.

    .venv/bin/python tools/shape_check.py [--seed 0] [--frames turned,route,compass] [--jobs 2]
                                          [--study-args "OPTIONS"] [--out DIR]

Each study takes 3-5 min on one core.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"
TRAIN = ("LOS/Case_1", "LOS/Case_2", "NLOS/Case_1")
LAYOUT = "NLOS/Case_2"
LOOP_ENU_M = ((3, 0, 1.1), (20, 14, 1.1), (38, 4, 1.1), (30, -14, 1.1), (10, -10, 1.1), (3, 0, 1.1))
"""Waypoints of the loop [m], in the anchor frame of the runs (tag antenna about 1.1 m above the ground)."""
CLI = [sys.executable, "-m", "physynth.cli"]


def _run(cmd: list[str]) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stderr}")


def _loop_dataset(data: Path, out: Path) -> tuple[list[Path], Path]:
    from physynth.calibrate import calibrate
    from physynth.io.dataset import read_dataset
    from physynth.scenario import scenario_from_dict, scenario_to_dict

    ds = {}
    for run in (*TRAIN, LAYOUT):
        env, case = run.split("/")
        ds[run] = out / "data" / f"{env}-{case}"
        if not (ds[run] / "dataset.json").is_file():
            _run(CLI + ["import", "hanyang", str(data / env / "Trajectory_A" / case), "--crop-to-uwb",
                        "--out", str(ds[run]), "--quiet"])
    loop = out / "data" / "loop"
    if not (loop / "dataset.json").is_file():
        scn = calibrate([read_dataset(ds[r]).traces[0] for r in TRAIN]).scenario
        d = scenario_to_dict(scn)
        lay = read_dataset(ds[LAYOUT]).traces[0].anchors
        d["anchors"] = [{"id": a, "pos_enu_m": [float(v) for v in p]}
                        for a, p in zip(lay.ids, lay.pos_enu_m, strict=True)]
        d["path"] = {"kind": "waypoints", "waypoints_enu_m": [list(p) for p in LOOP_ENU_M],
                     "perturbation": {"lateral_std_m": 0.5, "sag_std_m": 0.0}}
        d["name"] = "hanyang-loop"
        (out / "loop.yaml").parent.mkdir(parents=True, exist_ok=True)
        import yaml

        (out / "loop.yaml").write_text(yaml.safe_dump(scenario_to_dict(scenario_from_dict(d, "loop"))))
        _run(CLI + ["generate", "--scenario", str(out / "loop.yaml"), "-n", "1", "--seed", "7", "--workers", "1",
                    "--out", str(loop), "--quiet"])
    return [ds[r] for r in TRAIN], loop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="Hanyang Dynamic_measurements folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", default="turned,route,compass")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--methods", default="NOAUG,SYNTH_PHY,ekf")
    ap.add_argument("--study-args", default="",
                    help='more options for every study, e.g. "--ekf-prior none" (use another --out)')
    ap.add_argument("--out", type=Path, default=Path("runs/shape-check"))
    args = ap.parse_args()
    train, loop = _loop_dataset(args.data, args.out)
    frames = [f.strip() for f in args.frames.split(",") if f.strip()]

    def study(frame: str) -> dict:
        out = args.out / f"loop-{frame}-s{args.seed}"
        if not (out / "results.json").is_file():
            _run(CLI + ["study", "tracking", "--quick", "--seed", str(args.seed),
                        *[a for t in train for a in ("--train", str(t))], "--test", str(loop), "--frame", frame,
                        "--methods", args.methods, *shlex.split(args.study_args), "--out", str(out), "--quiet"])
        rows = json.loads((out / "results.json").read_text())["rows"]
        return {r["method"].split(" (")[0]: r["rmse_m"] for r in rows}

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        res = dict(zip(frames, pool.map(study, frames), strict=True))
    methods = list(next(iter(res.values())))
    print(f"synthetic loop at the Hanyang site, seed {args.seed}: RMSE (m) per --frame")
    print("| method | " + " | ".join(frames) + " |")
    print("|---|" + "---|" * len(frames))
    for m in methods:
        print(f"| {m} | " + " | ".join(f"{res[f].get(m, float('nan')):.3f}" for f in frames) + " |")


if __name__ == "__main__":
    main()
