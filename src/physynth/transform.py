"""A whole trace in a turned (or mirrored) world: the anchors and the truth moved together.

A UWB range is a distance, so moving the anchors and the tag path by one isometry (a turn about the
vertical axis, optionally after a mirror in a vertical plane) leaves every range, outage and age of
information of a run valid: the turned run is what the same walk gives at a site laid out in another
direction. This makes test runs along directions no tracker was trained on out of real recordings
(docs/tracking.md, "Runs in other directions").

:func:`turn_trace` moves positions, velocities, anchors and the ENU acceleration. A turn leaves a
body-frame IMU's readings as they are (gravity stays vertical) and turns the attitude with the world.
A mirror would make the body frame left-handed, so the mirrored body frame is the mirror image of the
original one with its y (left) axis flipped back: attitude ``R' = M R D`` with ``D = diag(1, -1, 1)``,
specific force ``f' = D f`` and angular rate ``w' = -D w`` (a rate is a pseudovector): the run of the
left-right mirrored vehicle. The move is recorded in ``meta["isometry"]`` (``matrix`` (3, 3) and
``offset_m`` (3,): ``p' = matrix @ p + offset``), composed with any earlier one, so that estimates
made in the original frame (the dataset authors' reference rows) can be moved the same way
(:func:`apply_isometry`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .records import Trace

ISOMETRY_META_KEY = "isometry"


def isometry_matrix(yaw_rad: float, mirror: bool = False) -> np.ndarray:
    """(3, 3) turn by ``yaw_rad`` (counter-clockwise seen from above) after a mirror ``y -> -y`` if asked."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot @ np.diag([1.0, -1.0, 1.0]) if mirror else rot


def turn_trace(trace: Trace, yaw_rad: float, *, mirror: bool = False,
               centre_enu_m: Sequence[float] | None = None) -> Trace:
    """``trace`` with anchors and truth turned by ``yaw_rad`` about the vertical through ``centre_enu_m``.

    ``centre_enu_m`` defaults to the anchor centroid. ``mirror`` first reflects ``y`` about the centre.
    Ranges, stamps and flags are unchanged. Raises ``ValueError`` for a non-finite angle or centre.
    """
    if not np.isfinite(yaw_rad):
        raise ValueError(f"yaw_rad must be finite, got {yaw_rad}")
    centre = (trace.anchors.pos_enu_m.mean(axis=0) if centre_enu_m is None
              else np.asarray(centre_enu_m, dtype=np.float64).reshape(-1))
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise ValueError(f"centre_enu_m must be 3 finite numbers, got {centre_enu_m!r}")
    m = isometry_matrix(yaw_rad, mirror)
    flip = np.diag([1.0, -1.0, 1.0]) if mirror else np.eye(3)  # D: keeps the body frame right-handed
    offset = centre - m @ centre

    def move(p: np.ndarray) -> np.ndarray:
        return p @ m.T + offset

    truth = trace.truth
    quat = truth.quat_wxyz
    if quat is not None:
        from scipy.spatial.transform import Rotation

        fin = np.all(np.isfinite(quat), axis=1)
        quat = quat.copy()
        turned = m @ Rotation.from_quat(quat[fin], scalar_first=True).as_matrix() @ flip
        quat[fin] = Rotation.from_matrix(turned).as_quat(scalar_first=True)
    omega = None if truth.omega_body_radps is None else _pseudo(truth.omega_body_radps, flip)
    truth = dataclasses.replace(truth, pos_enu_m=move(truth.pos_enu_m), vel_enu_mps=truth.vel_enu_mps @ m.T,
                                quat_wxyz=quat, omega_body_radps=omega)
    imu = trace.imu
    if imu is not None:
        imu = dataclasses.replace(
            imu, acc_mps2=None if imu.acc_mps2 is None else imu.acc_mps2 @ m.T,
            acc_body_mps2=None if imu.acc_body_mps2 is None else imu.acc_body_mps2 @ flip,
            gyro_body_radps=None if imu.gyro_body_radps is None else _pseudo(imu.gyro_body_radps, flip))
    anchors = dataclasses.replace(trace.anchors, pos_enu_m=move(trace.anchors.pos_enu_m))
    before = trace.meta.get(ISOMETRY_META_KEY)
    if isinstance(before, Mapping):
        m0 = np.asarray(before["matrix"], dtype=np.float64)
        t0 = np.asarray(before["offset_m"], dtype=np.float64)
        total, total_offset = m @ m0, m @ t0 + offset
    else:
        total, total_offset = m, offset
    meta = {**trace.meta, ISOMETRY_META_KEY: {"matrix": total.tolist(), "offset_m": total_offset.tolist()}}
    return dataclasses.replace(trace, truth=truth, anchors=anchors, imu=imu, meta=meta)


def _pseudo(rate: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """An angular rate (pseudovector) in the body frame mirrored by ``flip``: ``det(D) D w``."""
    return rate @ flip.T * np.linalg.det(flip)


def apply_isometry(meta: Mapping[str, Any], pos_m: np.ndarray) -> np.ndarray:
    """Positions (N, 3) of the original frame moved like the trace whose ``meta`` this is (as is if none)."""
    iso = meta.get(ISOMETRY_META_KEY)
    if not isinstance(iso, Mapping):
        return pos_m
    m = np.asarray(iso["matrix"], dtype=np.float64)
    return np.asarray(pos_m, dtype=np.float64) @ m.T + np.asarray(iso["offset_m"], dtype=np.float64)
