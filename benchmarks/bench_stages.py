"""CPU time per trace of each stage of ``generate_trace``, and the floor set by the Gaussian draws.

    python benchmarks/bench_stages.py [-n 60] [--scenario cablecar-descending] [--body]

Runs the stages of :func:`physynth.generate.generate_trace` one by one (path and motion draws,
kinematics, attitude, IMU, UWB attempts, availability, the UWB record) on ``-n`` traces and prints
the process CPU time per trace of each, best of two passes. ``--body`` adds the body-frame IMU
(accelerometer and gyroscope) to the scenario's ENU one. The last lines time the white-noise draws
alone (every IMU sample of one trace, nothing else) with the sampler the IMU uses
(:func:`physynth.rng.standard_normal_rows`, Box-Muller) and, side by side, with NumPy's
``Generator.standard_normal``: no IMU model can be cheaper than its draws, whatever else it does.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from physynth.constants import IMU_BODY_FRAME, IMU_FRAME  # noqa: E402
from physynth.generate import _imu, compile_scenario  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.models.attitude import simulate_attitude  # noqa: E402
from physynth.models.availability import simulate_availability  # noqa: E402
from physynth.models.motion import draw_run, kinematics  # noqa: E402
from physynth.models.path import draw_perturbation  # noqa: E402
from physynth.models.uwb import simulate_uwb, uwb_record  # noqa: E402
from physynth.rng import component_rng, standard_normal_rows  # noqa: E402


def _one_pass(cs, n: int) -> dict[str, float]:
    s = cs.scenario
    spent: dict[str, float] = {}

    def lap(name: str, t0: float) -> float:
        t = time.process_time()
        spent[name] = spent.get(name, 0.0) + t - t0
        return t

    for i in range(n):
        t0 = time.process_time()
        pert = draw_perturbation(s.path.perturbation, rng=component_rng(1, i, "path"))
        run = draw_run(s.motion, rng=component_rng(1, i, "motion"))
        t0 = lap("path and motion draws", t0)
        kin = kinematics(cs.geometry, pert, s.motion, cs.shape, run, rate_hz=s.truth_rate_hz,
                         reverse=s.path.reverse, lateral_dir=cs.lateral_dir)
        t0 = lap("kinematics", t0)
        att = simulate_attitude(kin.t_s, kin.vel_enu_mps, kin.acc_enu_mps2, s.attitude,
                                rng=component_rng(1, i, "attitude") if s.attitude.kind == "tumble" else None)
        t0 = lap("attitude", t0)
        _imu(kin, att, s, 1, i)
        t0 = lap("IMU", t0)
        tries = simulate_uwb(kin, s.uwb, cs.channel, rng=component_rng(1, i, "uwb"))
        t0 = lap("UWB attempts", t0)
        outage, dropped = simulate_availability(tries.t_true_s, tries.anchor, tries.burst, tries.bursts_s,
                                                cs.availability, s.uwb.burst_rate_hz, range_m=tries.true_range_m,
                                                rng=component_rng(1, i, "availability"), rows_of=tries.anchor_rows)
        t0 = lap("availability", t0)
        uwb_record(tries, outage=outage, dropped=dropped)
        lap("UWB record", t0)
    return {k: 1e3 * v / n for k, v in spent.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=60)
    ap.add_argument("--scenario", default="cablecar-descending")
    ap.add_argument("--body", action="store_true", help="add the body-frame IMU")
    args = ap.parse_args()
    scn = load_scenario(args.scenario)
    if args.body:
        scn = scn.model_copy(update={"imu_frames": [IMU_FRAME, IMU_BODY_FRAME]})
    cs = compile_scenario(scn)
    _one_pass(cs, 2)  # warm-up
    best = None
    for _ in range(2):
        got = _one_pass(cs, args.n)
        best = got if best is None else {k: min(v, got[k]) for k, v in best.items()}
    total = sum(best.values())
    print(f"{args.scenario} ({', '.join(scn.imu_frames)}), CPU ms per trace, best of 2 x {args.n} traces:")
    for k, v in best.items():
        print(f"  {k:24s} {v:6.2f}  ({100 * v / total:4.1f} %)")
    print(f"  {'total':24s} {total:6.2f}  -> {1e3 / total:.0f} traces/s per core")
    n_imu = int(np.ceil(103.9 * scn.imu.rate_hz))
    triads = len(scn.imu_frames) + (1 if IMU_BODY_FRAME in scn.imu_frames else 0)  # ENU 1, body 2
    rng = np.random.default_rng(0)
    floors = {}
    for name, draw in (("Box-Muller (used)", lambda: standard_normal_rows(rng, 3 * triads, n_imu)),
                       ("NumPy standard_normal", lambda: rng.standard_normal((3 * triads, n_imu)))):
        best_t = np.inf
        for _ in range(2):
            t0 = time.process_time()
            for _ in range(args.n):
                draw()
            best_t = min(best_t, time.process_time() - t0)
        floors[name] = 1e3 * best_t / args.n
    floor = floors["Box-Muller (used)"]
    print(f"  white-noise draws alone: {floor:.2f} ms per trace ({triads} triad(s) x 3 x {n_imu} samples): "
          f"at most {1e3 / floor:.0f} traces/s per core even if nothing else took time")
    print(f"  the same draws by NumPy's standard_normal: {floors['NumPy standard_normal']:.2f} ms "
          f"({floors['NumPy standard_normal'] / floor:.2f}x the Box-Muller draws)")


if __name__ == "__main__":
    main()
