"""The IMU part of PhySynth against the ``imusim`` package on the same trajectory, side by side.

    pip install 'physynth[bench]'        # imusim 1.1.2 from PyPI (x-io Technologies' IMU simulator)
    python benchmarks/bench_imu_vs_imusim.py [--repeat 3]

Trajectory: the truth of the trace of the default preset (seed 2026) closest to 104 s of the cable car at 100 Hz
(positions ENU; attitude held level, roll = pitch = yaw = 0, as PhySynth's IMU is ENU-aligned). Both
simulators produce a 400 Hz accelerometer with white noise and a bias random walk of the preset's
densities:

- PhySynth: ``physynth.models.imu.simulate_imu`` on the trajectory's kinematics (ideal acceleration,
  bias random walk, vibration, white noise);
- imusim: ``imusim.Simulator(csv, sample_rate=400)`` (cubic resampling, low-pass filtering,
  differentiation to acceleration, attitude propagation, gravity in the body frame) and
  ``set_accelerometer(noise_density, random_walk, bias_instability)``. Its constructor needs a CSV file,
  so the time to parse that file is measured separately and subtracted.

Both run in this process, one after the other, ``--repeat`` times; the best time of each is kept, and
the ratio is printed. The machine and its load are printed too: measure on a quiet machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from physynth.bench import _cpu_name  # noqa: E402
from physynth.generate import compile_scenario  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.models.imu import simulate_imu  # noqa: E402
from physynth.models.motion import draw_run, kinematics  # noqa: E402
from physynth.models.path import draw_perturbation  # noqa: E402
from physynth.rng import component_rng  # noqa: E402

G = 9.8  # imusim's gravity [m/s^2]; its accelerometer is in g


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    try:
        import imusim
    except ImportError:
        raise SystemExit("imusim is not installed: pip install 'physynth[bench]' (or pip install imusim)") from None

    scn = load_scenario("cablecar-descending")
    cs = compile_scenario(scn)
    s = cs.scenario
    best = None
    for i in range(40):  # the trace of seed 2026 whose duration is closest to 104 s
        pert = draw_perturbation(s.path.perturbation, rng=component_rng(2026, i, "path"))
        run = draw_run(s.motion, rng=component_rng(2026, i, "motion"))
        k = kinematics(cs.geometry, pert, s.motion, cs.shape, run, rate_hz=s.truth_rate_hz, reverse=s.path.reverse,
                       lateral_dir=cs.lateral_dir)
        if best is None or abs(k.t_s[-1] - k.t_s[0] - 104.0) < abs(best.t_s[-1] - best.t_s[0] - 104.0):
            best = k
    kin = best
    dens = np.asarray(s.imu.white_noise_density_mps2_per_sqrt_hz)
    print(f"trajectory: {kin.t_s[-1] - kin.t_s[0]:.1f} s at {s.truth_rate_hz:.0f} Hz, IMU at {s.imu.rate_hz:.0f} Hz")

    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "trajectory.csv"
        table = np.column_stack([kin.t_s, kin.pos_enu_m, np.zeros((kin.t_s.size, 3))])
        np.savetxt(csv, table, delimiter=",", header="time,x,y,z,roll,pitch,yaw", comments="", fmt="%.9f")
        best_ps, best_im, best_parse = np.inf, np.inf, np.inf
        for r in range(args.repeat):
            t0 = time.perf_counter()
            imu = simulate_imu(kin, s.imu, rng=component_rng(2026, r, "imu"))
            best_ps = min(best_ps, time.perf_counter() - t0)

            t0 = time.perf_counter()
            np.genfromtxt(csv, delimiter=",", skip_header=1)
            best_parse = min(best_parse, time.perf_counter() - t0)

            np.random.seed(r)  # noqa: NPY002 - imusim draws from NumPy's global state
            t0 = time.perf_counter()
            sim = imusim.Simulator(str(csv), sample_rate=s.imu.rate_hz)
            sim.set_accelerometer(noise_density=dens / G, random_walk=np.full(3, s.imu.bias_rw_mps2_per_sqrt_s / G),
                                  bias_instability=np.full(3, 1e-6))
            acc = sim.accelerometer
            best_im = min(best_im, time.perf_counter() - t0)
    im_net = best_im - best_parse
    print(f"PhySynth simulate_imu : {1e3 * best_ps:9.1f} ms  ({imu.t_s.size} samples)")
    print(f"imusim Simulator      : {1e3 * im_net:9.1f} ms  ({acc.shape[0]} samples; {1e3 * best_im:.1f} ms with "
          f"{1e3 * best_parse:.1f} ms of CSV parsing subtracted)")
    print(f"ratio imusim / PhySynth: {im_net / best_ps:.0f}x  (best of {args.repeat})")
    print(f"machine: {os.cpu_count()} core(s) {_cpu_name()}, load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
