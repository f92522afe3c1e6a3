"""Azimuth error of the networks' far-field direction features on the four shared Hanyang runs.

    .venv/bin/python tools/direction_check.py

For every 10 Hz step more than 8 m (horizontally) from the anchor centroid, the azimuth of the full
(3-D) and of the level (``u_z = 0``) far-field direction solve (:func:`physynth.track.inputs.
far_field_direction`, age-weighted as the networks see them) against the truth, split by the number of
ranges younger than 0.5 s. Prints the median and the 90th percentile in degrees.
"""

from __future__ import annotations

import numpy as np

from physynth.io.importers import import_hanyang
from physynth.studies.tracking import default_data_root
from physynth.track.features import far_field_direction
from physynth.track.inputs import track_input

RUNS = ("LOS/Trajectory_A/Case_1", "LOS/Trajectory_A/Case_2", "NLOS/Trajectory_A/Case_1",
        "NLOS/Trajectory_A/Case_2")
UWB_LAG_S = 0.18  # the UWB stamps lag the RTK track (docs/tracking.md)


def _azimuth_error(v: np.ndarray, true_az: np.ndarray) -> np.ndarray:
    return np.degrees(np.abs(np.angle(np.exp(1j * (np.arctan2(v[:, 1], v[:, 0]) - true_az)))))


def main() -> None:
    root = default_data_root() / "hanyang-uwb" / "Dynamic_measurements"
    print("| run | fresh ranges | steps | full: median / P90 (deg) | level: median / P90 (deg) |")
    print("|---|---|---|---|---|")
    for rel in RUNS:
        trace, _ = import_hanyang(root / rel, crop_to_uwb=True)
        inp = track_input(trace, time_offset_s=UWB_LAG_S)
        k = np.arange(0, inp.n_steps, 10)
        r, aoi = inp.range_m[k], inp.aoi_s[k]
        has = np.isfinite(r)
        _, u = far_field_direction(r, has, inp.anchor_pos_rel_m, aoi_s=aoi)
        _, u_level = far_field_direction(r, has, inp.anchor_pos_rel_m, aoi_s=aoi, level=True)
        p = inp.pos_rel_m[k]
        far = np.all(np.isfinite(p), axis=1) & (np.linalg.norm(p[:, :2], axis=1) > 8.0)
        true_az = np.arctan2(p[:, 1], p[:, 0])

        fresh = (aoi < 0.5).sum(axis=1)
        for n in (3, 4):
            m = far & (fresh == n)
            if m.any():
                e3, el = _azimuth_error(u, true_az)[m], _azimuth_error(u_level, true_az)[m]
                print(f"| {rel} | {n} | {m.sum()} | {np.median(e3):.1f} / {np.percentile(e3, 90):.1f} "
                      f"| {np.median(el):.1f} / {np.percentile(el, 90):.1f} |")


if __name__ == "__main__":
    main()
