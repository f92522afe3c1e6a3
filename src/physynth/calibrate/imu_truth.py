"""What the IMU should have read, from the ground truth: the truth-derived acceleration (low-passed,
differentiated twice), the truth attitude and body rate, and the IMU error against them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.signal import butter, sosfiltfilt
from scipy.spatial.transform import Rotation, Slerp

from ..models.imu import lever_arm_acceleration
from ..records import Trace
from ._base import CalibrationError, median_step_s, segments

EDGE_MARGIN_S = 1.0
"""IMU samples this close to a truth gap or a segment end are left out (filter transients) [s]."""


def truth_acceleration(t_s: np.ndarray, pos_m: np.ndarray, *, cutoff_hz: float,
                       max_gap_s: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Acceleration (K, 3) [m s^-2] of a truth track on its uniform grid, and a validity mask.

    Each contiguous segment of finite positions (gaps <= ``max_gap_s`` bridged linearly) is resampled
    to the median step, low-passed (4th-order zero-phase Butterworth at ``cutoff_hz``) and
    differentiated twice. Returns (t_grid, acc, valid), valid False within ``EDGE_MARGIN_S`` of a
    segment end.
    """
    ok = np.all(np.isfinite(pos_m), axis=1)
    t, p = t_s[ok], pos_m[ok]
    if t.size < 10:
        raise CalibrationError("too few finite truth positions to differentiate")
    dt = median_step_s(t)
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    tg = t[0] + np.arange(n) * dt
    pg = np.stack([np.interp(tg, t, p[:, k]) for k in range(3)], axis=1)
    # gaps in the finite truth: grid points inside a gap are invalid
    gap_at = np.flatnonzero(np.diff(t) > max(max_gap_s, 1.5 * dt))
    invalid = np.zeros(n, dtype=bool)
    for g in gap_at:  # a handful of gaps
        invalid |= (tg > t[g]) & (tg < t[g + 1])
    masked = np.zeros(n, dtype=bool)
    # masked (NaN) spans of the original truth also make nearby grid points invalid
    nan_t = t_s[~ok]
    if nan_t.size:
        k = np.clip(np.searchsorted(tg, nan_t), 0, n - 1)
        masked[k] = True
    invalid |= masked
    fs = 1.0 / dt
    acc = np.full((n, 3), np.nan)
    valid = np.zeros(n, dtype=bool)
    margin = int(np.ceil(EDGE_MARGIN_S * fs))
    wc = min(cutoff_hz, 0.45 * fs)
    sos = butter(4, wc, fs=fs, output="sos")
    for a, b in segments(tg, ~invalid, max_gap_s=1.5 * dt):  # contiguous segments, each vectorised
        if b - a < 4 * margin + 10:
            continue
        ps = sosfiltfilt(sos, pg[a:b], axis=0)
        acc[a:b] = np.gradient(np.gradient(ps, dt, axis=0), dt, axis=0)
        valid[a + margin:b - margin] = True
    return tg, acc, valid


def imu_error(trace: Trace, cutoff_hz: float, offset_s: float = 0.0, *, lever_arm_m: Sequence[float] | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU error (N, 3) = IMU minus truth-derived acceleration at the IMU times, its mask and the times.

    The error is NaN (mask False) where the IMU or the truth is masked, near truth gaps and segment
    ends. The IMU is assumed to be ENU, gravity-free (the trace's ``imu.frame``). ``offset_s``: the
    IMU sample at t is compared with the truth at t - offset (an IMU clock lagging the truth).
    ``lever_arm_m`` (body frame [m]): the rotational acceleration of a sensor there
    (:func:`~.lever_arm.lever_arm_design`) counts as part of the truth; needs the truth attitude.
    """
    if trace.imu is None or trace.imu.acc_mps2 is None:
        raise CalibrationError("trace has no ENU (gravity-free) IMU samples")
    return error_against(trace, sensor_truth_acceleration(trace, cutoff_hz, lever_arm_m), offset_s)


def sensor_truth_acceleration(trace: Trace, cutoff_hz: float, lever_arm_m: Sequence[float] | None = None
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`truth_acceleration` of the trace's truth plus, with a non-zero ``lever_arm_m`` (body frame
    [m]), the rotational acceleration of a sensor there (:func:`physynth.models.imu.lever_arm_acceleration`
    along the truth attitude and its body rate low-passed at ``cutoff_hz``); invalid where the truth has
    no attitude."""
    tg, acc, valid = truth_acceleration(trace.truth.t_s, trace.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    r = None if lever_arm_m is None else np.asarray(lever_arm_m, dtype=float)
    if r is None or not np.any(r != 0.0):
        return tg, acc, valid
    att = truth_attitude_at(trace, tg)
    # the truth's rates hold over [t_k, t_{k+1}), i.e. belong to the middle of the step
    w = smoothed_body_rate(trace, tg - 0.5 * median_step_s(trace.truth.t_s), cutoff_hz)
    if att is None or w is None:
        raise CalibrationError("a lever arm needs the truth attitude")
    return tg, acc + lever_arm_acceleration(tg, att[0], w, r), valid & att[1]


def _finite_rows(values: np.ndarray | None, at_least: int) -> np.ndarray | None:
    """The mask of the rows of ``values`` (a truth field, None when the truth has none) that are finite;
    None without the field or with fewer than ``at_least`` such rows."""
    if values is None:
        return None
    fin = np.all(np.isfinite(values), axis=1)
    return fin if int(fin.sum()) >= at_least else None


def has_truth_rotation(trace: Trace) -> bool:
    """Whether the truth has an attitude and a body rate (at least 10 finite rows of each)."""
    return (_finite_rows(trace.truth.quat_wxyz, 10) is not None
            and _finite_rows(trace.truth.omega_body_radps, 10) is not None)


def truth_attitude_at(trace: Trace, t_q: np.ndarray) -> tuple[Rotation, np.ndarray] | None:
    """The truth attitude (body -> ENU) at times ``t_q``, spherically interpolated between the finite
    truth quaternions, and a mask (False outside them or within a masked span); None without attitude."""
    q = trace.truth.quat_wxyz
    fin = _finite_rows(q, 2)
    if fin is None:
        return None
    t = trace.truth.t_s
    slerp = Slerp(t[fin], Rotation.from_quat(q[fin], scalar_first=True))
    tc = np.clip(t_q, t[fin][0], t[fin][-1])
    # a query is valid when both neighbouring truth samples are finite
    k = np.clip(np.searchsorted(t, t_q, side="right") - 1, 0, t.size - 1)
    k1 = np.minimum(k + 1, t.size - 1)
    ok = fin[k] & fin[k1] & (t_q >= t[0]) & (t_q <= t[-1])
    return slerp(tc), ok


def error_against(trace: Trace, truth_acc: tuple[np.ndarray, np.ndarray, np.ndarray], offset_s: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    err, ok, ti = errors_at_offsets(trace, truth_acc)(offset_s)
    err[~ok] = np.nan
    return err, ok, ti


def errors_at_offsets(trace: Trace, truth_acc: tuple[np.ndarray, np.ndarray, np.ndarray]
                      ) -> Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`error_against` for one trace at offset after offset (a grid search): the truth's masked
    samples zeroed once, not per offset; the rows outside ``ok`` are left as computed (not NaN)."""
    tg, a_truth, valid = truth_acc
    cols = [np.where(valid, a_truth[:, k], 0.0) for k in range(3)]
    valid_f = valid.astype(float)
    acc, t_imu = trace.imu.acc_mps2, trace.imu.t_s

    def at(offset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ti = t_imu - offset_s
        err = np.empty(acc.shape)
        ok = np.interp(ti, tg, valid_f) > 0.999
        for k, c in enumerate(cols):  # column by column: no stacked copy, no reduction over the 3 axes
            err[:, k] = acc[:, k] - np.interp(ti, tg, c)
            ok &= np.isfinite(err[:, k])
        return err, ok, ti

    return at


def smoothed_body_rate(trace: Trace, t_q: np.ndarray, cutoff_hz: float) -> np.ndarray | None:
    """(N, 3) truth body angular rate low-passed at ``cutoff_hz`` (zero phase), at times ``t_q``.

    From the truth's ``omega_body_radps`` (e.g. differentiated optical attitude); None without one.
    """
    w = trace.truth.omega_body_radps
    ok = _finite_rows(w, 10)
    if ok is None:
        return None
    t = trace.truth.t_s
    fs = 1.0 / median_step_s(t)
    wf = np.stack([np.interp(t, t[ok], w[ok, k]) for k in range(3)], axis=1)
    wf = sosfiltfilt(butter(4, min(cutoff_hz, 0.45 * fs), fs=fs, output="sos"), wf, axis=0)
    return np.stack([np.interp(t_q, t, wf[:, k]) for k in range(3)], axis=1)


def filled_truth_acceleration(real: Trace, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(truth grid, acceleration (K, 3)) of a real trace's truth low-passed at ``cutoff_hz``, masked
    spans filled linearly: what an IMU model is run along."""
    tg, acc, valid = truth_acceleration(real.truth.t_s, real.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    if valid.sum() < 10:
        raise CalibrationError("too little valid truth to run the IMU along")
    return tg, np.stack([np.interp(tg, tg[valid], acc[valid, k]) for k in range(3)], axis=1)
