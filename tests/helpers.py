"""Small scenarios and statistics helpers shared by the generator tests; the command line run in-process;
a copy of a real Hanyang run to corrupt."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from physynth.scenario import Scenario, scenario_from_dict


def simple_scenario_dict(**updates) -> dict:
    """A straight 300 m walk past three anchors; every error term switched off unless updated."""
    d = {
        "name": "test-line",
        "path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [150, 10, 1], [300, 0, 1]],
                 "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}},
        "motion": {"cruise_speed_mps": 3.0, "cruise_speed_spread_frac": 0.0, "length_spread_frac": 0.0,
                   "profile": {"kind": "trapezoid", "accel_frac": 0.1, "decel_frac": 0.1}},
        "imu": {"rate_hz": 400.0, "white_noise_density_mps2_per_sqrt_hz": [0.0, 0.0, 0.0],
                "bias_rw_mps2_per_sqrt_s": 0.0, "vibration": {"amplitude_mps2": 0.0}},
        "uwb": {"burst_rate_hz": 20.0, "burst_jitter_s": 0.0, "slot_s": 0.001},
        "anchors": [{"id": "A1", "pos_enu_m": [50, 20, 3]}, {"id": "A2", "pos_enu_m": [150, -20, 3]},
                    {"id": "A3", "pos_enu_m": [250, 20, 3]}],
        "channel": {"rate_hz": 20.0, "los_mean_m": 0.0, "los_std_m": 1e-12, "nlos_prob": 0.0,
                    "max_range_m": 1e6},
        "availability": {"dropout_prob": 0.0, "outage_onset_prob": 0.0},
    }
    for key, value in updates.items():
        cur = d
        parts = key.split(".")
        for p in parts[:-1]:
            cur = cur.setdefault(p, {})
        cur[parts[-1]] = value
    return d


def simple_scenario(**updates) -> Scenario:
    return scenario_from_dict(simple_scenario_dict(**updates), "test")


def uwb_only_traces(scn: Scenario, n: int, seed: int) -> list:
    """``n`` traces of ``scn`` without their IMU samples: for calibration tests of the UWB fit, which does not
    use them (the IMU calibration would add a third to such a test's time)."""
    from dataclasses import replace

    from physynth.generate import generate_traces

    return [replace(t, imu=None) for t in generate_traces(scn, n, seed=seed)]


def binomial_tol(p: float, n: int, k: float = 5.0) -> float:
    """k standard errors of a proportion estimated from n independent trials."""
    return k * np.sqrt(p * (1 - p) / n)


def run_cli(capsys, *args) -> tuple[int, str, str]:
    """``physynth ARGS`` run in this process: exit code, stdout, stderr."""
    from physynth.cli import main

    with pytest.raises(SystemExit) as exc:
        main([*map(str, args)])
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


def copy_hanyang_run(case: Path, tmp_path: Path) -> Path:
    """The trajectory and anchor files of the real Hanyang run ``case`` (LOS Trajectory_A Case_1: anchors 3,
    5, 9, 12) copied to the same relative place under ``tmp_path``."""
    dst = tmp_path / "LOS" / "Trajectory_A" / "Case_1"
    dst.mkdir(parents=True)
    for f in ["trajectory.csv", "A3.csv", "A5.csv", "A9.csv", "A12.csv"]:
        shutil.copyfile(case / f, dst / f)
    return dst


def edit_csv_columns(path: Path, cols: list[int], fn) -> None:
    """Every data row of the CSV file ``path`` with ``fn`` applied to the cells of ``cols`` (0-based)."""
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        p = ln.split(",")
        for c in cols:
            p[c] = fn(p[c])
        out.append(",".join(p))
    path.write_text("\n".join(out) + "\n")
