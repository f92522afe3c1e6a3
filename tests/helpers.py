"""Small scenarios and statistics helpers shared by the generator tests."""

from __future__ import annotations

import numpy as np

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


def binomial_tol(p: float, n: int, k: float = 5.0) -> float:
    """k standard errors of a proportion estimated from n independent trials."""
    return k * np.sqrt(p * (1 - p) / n)
