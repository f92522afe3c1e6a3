"""Build the two presets calibrated on real recordings shipped in src/physynth/presets/.

    python tools/make_real_presets.py [--data ../shared/data]

- ``walk-hanyang``: what ``physynth calibrate`` writes on the four Hanyang Trajectory_A runs (LOS and NLOS,
  Case_1 and Case_2; imported with ``--crop-to-uwb``): a person walking an outdoor route with a UWB tag
  1 m above the ground, four anchors (re-placed for every run; the first run's layout generates, the
  four layouts are recorded, so ``generate --vary-site`` draws around all of them). The recordings
  have no IMU: the preset's accelerometer and gyroscope are the MEMS device of the BROAD trials
  (``handheld-broad``: white noise, bias walk, scale factor, misalignment, turn-on bias, read at rest and
  against the optical truth), without the terms that grow with a hand's motion (the truth's own lag
  behind a shaken sensor, not the sensor's error), at 200 Hz, on a body that faces its direction of
  travel.
- ``handheld-broad``: what ``physynth calibrate`` writes on the BROAD trials of undisturbed motion
  (10, 15, 21): a MEMS IMU moved by hand on a lab bench, in place, turning smoothly; ENU and body-frame
  IMU, no anchors.

The descriptions cite the datasets (Hanyang: Apache-2.0; BROAD: CC BY 4.0).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from physynth.calibrate import calibrate  # noqa: E402
from physynth.data import HANYANG_TRAJECTORY_A_RUNS  # noqa: E402
from physynth.io.importers import import_broad, import_hanyang  # noqa: E402
from physynth.io.scenario_file import save_scenario  # noqa: E402
from physynth.scenario import scenario_from_dict, scenario_to_dict  # noqa: E402

BROAD_TRIALS = ("10_undisturbed_slow_translation_A", "15_undisturbed_fast_translation_A",
                "21_undisturbed_fast_combined")

WALK_DESCRIPTION = (
    "A person walking an outdoor route with a UWB tag 1 m above the ground and four anchors, "
    "calibrated on four real runs (LOS and NLOS) of the Hanyang outdoor UWB dataset (ADIP laboratory, "
    "Hanyang University, Apache-2.0, doi:10.5281/zenodo.15226105); the four runs' anchor layouts are "
    "recorded for a per-trace variation of the site. IMU: the MEMS device of the BROAD trials "
    "(handheld-broad) on a body facing its direction of travel.")
HANDHELD_DESCRIPTION = (
    "A MEMS IMU moved by hand on a lab bench (in place, turning smoothly), ENU and body-frame outputs, "
    "no anchors; calibrated on three undisturbed trials of the BROAD inertial dataset (Laidig et al., "
    "Data 6(7):72, 2021, CC BY 4.0).")

WALK_IMU_RATE_HZ = 200.0
"""The walker's IMU output rate: a common MEMS rate (the device's noise is given per sqrt(Hz), so it holds
at any rate; BROAD's own is 285.7 Hz)."""


def walk_imu(walk: dict, handheld: dict) -> dict:
    """The walker with the handheld device's IMU errors, minus what grows with a hand's motion."""
    imu = dict(handheld["imu"])
    imu.update(rate_hz=WALK_IMU_RATE_HZ, vibration={**imu["vibration"], "amplitude_mps2": 0.0},
               motion_noise={"acc_var_gain_mps2": [0.0, 0.0, 0.0], "rate_var_gain_mps4_per_radps": [0.0, 0.0, 0.0]},
               time_offset_s=0.0, lever_arm_m=[0.0, 0.0, 0.0], truth_cutoff_hz=None)
    body = dict(handheld["body_imu"])
    body["vibration"] = {**body["vibration"], "amplitude_mps2": 0.0}
    body["accelerometer"] = {**body["accelerometer"], "vibration_amplitude_mps2": 0.0,
                             "vibration_acc_var_gain_mps2": 0.0, "vibration_rate_var_gain_mps4_per_radps": 0.0}
    body["gyroscope"] = {**body["gyroscope"], "vibration_amplitude_radps": 0.0, "vibration_rate_var_gain_radps": 0.0,
                         "vibration_acc_var_gain_rad2_per_m": [0.0, 0.0, 0.0]}
    body.update(rate_hz=WALK_IMU_RATE_HZ, time_offset_s=0.0, lever_arm_m=[0.0, 0.0, 0.0])
    return {**walk, "imu": imu, "body_imu": body, "imu_frames": ["enu-gravity-free", "body-flu"],
            "attitude": {"kind": "tangent"}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data",
                    help="folder of hanyang-uwb and broad-imu")
    args = ap.parse_args()
    runs = [import_hanyang(args.data / "hanyang-uwb" / "Dynamic_measurements" / r, crop_to_uwb=True)[0]
            for r in HANYANG_TRAJECTORY_A_RUNS]
    trials = [import_broad(args.data / "broad-imu" / "data_mat" / f"{t}.mat")[0] for t in BROAD_TRIALS]
    handheld = scenario_to_dict(calibrate(trials, name="handheld-broad", sources=list(BROAD_TRIALS)).scenario)
    walk = scenario_to_dict(calibrate(runs, name="walk-hanyang", sources=list(HANYANG_TRAJECTORY_A_RUNS)).scenario)
    handheld["description"] = HANDHELD_DESCRIPTION
    walk = walk_imu(walk, handheld)
    walk["description"] = WALK_DESCRIPTION
    for data, what in ((walk, "Hanyang Trajectory_A: " + ", ".join(HANYANG_TRAJECTORY_A_RUNS)),
                       (handheld, "BROAD: " + ", ".join(BROAD_TRIALS))):
        for key in ("created_utc",):  # a rebuilt preset differs only where the calibration differs
            data["provenance"].pop(key, None)
        scn = scenario_from_dict(data, f"preset {data['name']}")
        out = ROOT / "src" / "physynth" / "presets" / f"{data['name']}.yaml"
        save_scenario(scn, out, header=f"Built by tools/make_real_presets.py: physynth calibrate on {what}")
        print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
