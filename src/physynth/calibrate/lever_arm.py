"""The IMU's lever arm from the truth's rotation: the least-squares offset of the IMU from the truth point.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..models.imu import lever_arm_acceleration
from ..records import Trace
from ._base import CalibrationError, median_step_s
from .imu_motion_noise import MOTION_WINDOW_S
from .imu_truth import imu_error, smoothed_body_rate, truth_attitude_at


def lever_arm_design(trace: Trace, cutoff_hz: float, offset_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3, 3) matrices D at the IMU times with D r = R (alpha x r + w x (w x r)), and their mask.

    A sensor at r [m] in the body frame reads this on top of the reference point's acceleration
    (:func:`physynth.models.imu.lever_arm_acceleration`): w the truth body rate low-passed at
    ``cutoff_hz`` (:func:`smoothed_body_rate`, each step's rate at the step's middle), alpha its
    derivative, R the truth attitude, all at the IMU time minus ``offset_s``. Zero with mask False
    where the truth has no attitude.
    """
    ti = trace.imu.t_s - offset_s
    att = truth_attitude_at(trace, ti)
    # the truth's rates hold over [t_k, t_{k+1}), i.e. belong to the middle of the step
    half = 0.5 * median_step_s(trace.truth.t_s) if trace.truth.t_s.size > 1 else 0.0
    w = smoothed_body_rate(trace, ti - half, cutoff_hz)
    if att is None or w is None:
        return np.zeros((ti.size, 3, 3)), np.zeros(ti.size, dtype=bool)
    rot, ok = att
    # column j: the acceleration of a unit lever arm along body axis j
    cols = [lever_arm_acceleration(ti, rot, w, e) for e in np.eye(3)]
    return np.nan_to_num(np.stack(cols, axis=2)), ok


LEVER_ARM_MIN_CONDITION = 1e-6
"""Smallest eigenvalue ratio of the lever-arm normal matrix: below it (rotation about one axis, as a
vehicle that only turns) the lever arm is not identifiable and is not fitted."""


def _lever_rows(tr: Trace, cutoff_hz: float, offset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One trace's lever-arm regression: design rows (3M, 3), error (3M,) and 2 s block ids (3M,)."""
    e, ok, ti = imu_error(tr, cutoff_hz, offset_s=offset_s)
    d, ok_att = lever_arm_design(tr, cutoff_hz, offset_s)
    ok = ok & ok_att
    block = np.repeat(np.flatnonzero(ok) // int(round(MOTION_WINDOW_S / median_step_s(ti))), 3)
    return d[ok].reshape(-1, 3), e[ok].reshape(-1), block


def fit_lever_arm(traces: Sequence[Trace], cutoff_hz: float, offset_s: float) -> tuple[np.ndarray, dict[str, Any]]:
    """Sensor position r (3,) [m] in the body frame by least squares pooled over the traces.

    The IMU error (:func:`imu_error` at ``offset_s``) regressed on the lever-arm design
    (:func:`lever_arm_design`) of each trace's truth attitude, all three axes at once. The standard
    error is from 2 s blocks of the residual (the error is coloured, so per-sample statistics would
    overstate the precision). Two passes over the traces, one at a time (memory does not grow with
    their number): the normal equations, then the residual's block scores.

    Raises
    ------
    CalibrationError
        No truth attitude, or a rotation about too few axes to identify r (``LEVER_ARM_MIN_CONDITION``).
    """
    ata, atb, btb, n = np.zeros((3, 3)), np.zeros(3), 0.0, 0
    for tr in traces:  # a handful of recordings, each vectorised
        a, b, _ = _lever_rows(tr, cutoff_hz, offset_s)
        ata += a.T @ a
        atb += a.T @ b
        btb += float(b @ b)
        n += a.shape[0]
    if n < 30 or not np.any(ata):
        raise CalibrationError("no truth attitude: the lever arm cannot be fitted")
    eig = np.linalg.eigvalsh(ata)
    if eig[0] <= LEVER_ARM_MIN_CONDITION * eig[-1]:
        raise CalibrationError("the truth rotates about too few axes for the lever arm to be fitted")
    r = np.linalg.solve(ata, atb)
    # block-bootstrap-free sandwich estimate: sum over blocks of (A_b^T res_b)(A_b^T res_b)^T
    meat, rss = np.zeros((3, 3)), 0.0
    for tr in traces:
        a, b, block = _lever_rows(tr, cutoff_hz, offset_s)
        res = b - a @ r
        rss += float(res @ res)
        _, inv = np.unique(block, return_inverse=True)
        score = np.zeros((int(inv.max()) + 1 if inv.size else 0, 3))
        np.add.at(score, inv, a * res[:, None])
        meat += score.T @ score
    ata_inv = np.linalg.inv(ata)
    cov = ata_inv @ meat @ ata_inv
    return r, {"lever_arm_m": r.tolist(), "std_error_m": np.sqrt(np.diag(cov)).tolist(),
               "mean_square_reduction_frac": float(1.0 - rss / btb), "n_samples": int(n // 3)}
