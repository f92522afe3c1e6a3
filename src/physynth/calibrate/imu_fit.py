"""Calibration of the IMU error model from the IMU error = IMU minus truth-derived acceleration.

The generator's accelerometer (:mod:`physynth.imu`, ENU, gravity-free) adds to the true acceleration

- white noise of one-sided PSD 2 sigma_w^2 per axis (per-sample standard deviation sigma_w sqrt(fs));
- a bias random walk b(t) = sigma_b W(t) (Allan variance sigma_b^2 tau / 3, PSD sigma_b^2 / (2 pi^2 f^2));
- narrow-band vibration at f0 and its harmonics, each line a Lorentzian of -3 dB width
  ``bandwidth_hz`` holding the share w_h / sum(w) of the variance ``amplitude_mps2^2``.

The truth-derived acceleration is the truth position low-passed (zero-phase Butterworth at
``cutoff_hz``) and differentiated twice, interpolated to the IMU times; masked (NaN) truth spans and
a margin around them are left out. Above the cut-off the truth has no content, so the white-noise
density comes from the top of the error PSD; the vibration lines are fitted to the rest of the Welch
PSD (non-negative least squares over harmonic variances, grid search over the line width); the bias
random walk from the long-tau end of the Allan deviation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.signal import butter, coherence, sosfiltfilt, welch
from scipy.spatial.transform import Rotation, Slerp

from ..evaluate.stats import allan_deviation
from ..models.imu import MotionNoiseParams, lever_arm_acceleration, simulate_imu
from ..models.motion import Kinematics
from ..records import Imu, Trace
from ..scenario import ImuParams, VibrationParams
from ._base import CalibrationError, Fit, median_step_s, rounded, segments, trace_label

WHITE_BAND = (0.6, 0.9)
"""Band of the error PSD, as fractions of the IMU Nyquist frequency, that gives the white noise."""
EDGE_MARGIN_S = 1.0
"""IMU samples this close to a truth gap or a segment end are left out (filter transients) [s]."""
MAX_HARMONICS = 40
N_PEAK_CANDIDATES = 6
"""Strongest local maxima of the excess spectrum (more than 30 % apart in frequency) tried as vibration
fundamentals, with their halves and thirds."""


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
    (:func:`lever_arm_design`) counts as part of the truth; needs the truth attitude.
    """
    if trace.imu is None or trace.imu.acc_mps2 is None:
        raise CalibrationError("trace has no ENU (gravity-free) IMU samples")
    return _error_against(trace, sensor_truth_acceleration(trace, cutoff_hz, lever_arm_m), offset_s)


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


def has_truth_rotation(trace: Trace) -> bool:
    """Whether the truth has an attitude and a body rate (at least 10 finite rows of each)."""
    q, w = trace.truth.quat_wxyz, trace.truth.omega_body_radps
    return (q is not None and w is not None and int(np.all(np.isfinite(q), axis=1).sum()) >= 10
            and int(np.all(np.isfinite(w), axis=1).sum()) >= 10)


def truth_attitude_at(trace: Trace, t_q: np.ndarray) -> tuple[Rotation, np.ndarray] | None:
    """The truth attitude (body -> ENU) at times ``t_q``, spherically interpolated between the finite
    truth quaternions, and a mask (False outside them or within a masked span); None without attitude."""
    q = trace.truth.quat_wxyz
    if q is None:
        return None
    t = trace.truth.t_s
    fin = np.all(np.isfinite(q), axis=1)
    if fin.sum() < 2:
        return None
    slerp = Slerp(t[fin], Rotation.from_quat(q[fin], scalar_first=True))
    tc = np.clip(t_q, t[fin][0], t[fin][-1])
    # a query is valid when both neighbouring truth samples are finite
    k = np.clip(np.searchsorted(t, t_q, side="right") - 1, 0, t.size - 1)
    k1 = np.minimum(k + 1, t.size - 1)
    ok = fin[k] & fin[k1] & (t_q >= t[0]) & (t_q <= t[-1])
    return slerp(tc), ok


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


def _error_against(trace: Trace, truth_acc: tuple[np.ndarray, np.ndarray, np.ndarray], offset_s: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tg, a_truth, valid = truth_acc
    ti = trace.imu.t_s - offset_s
    a_i = np.stack([np.interp(ti, tg, np.where(valid, a_truth[:, k], 0.0)) for k in range(3)], axis=1)
    v_i = np.interp(ti, tg, valid.astype(float)) > 0.999
    err = trace.imu.acc_mps2 - a_i
    ok = v_i & np.all(np.isfinite(err), axis=1)
    err[~ok] = np.nan
    return err, ok, ti


def _welch_segments(err: np.ndarray, ok: np.ndarray, t_s: np.ndarray, fs: float, nperseg: int
                    ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Length-weighted average Welch PSD (F, 3) over the valid contiguous segments, samples, averages."""
    psd_sum, weight, n_used, n_avg = None, 0.0, 0, 0
    segs = segments(t_s, ok, max_gap_s=1.5 / fs)
    longest = max((b - a for a, b in segs), default=0)
    nper = int(min(nperseg, 2 ** int(np.floor(np.log2(max(longest, 16))))))
    f = None
    for a, b in segs:  # contiguous segments, each vectorised
        if b - a < nper:
            continue
        f, p = welch(err[a:b], fs=fs, nperseg=nper, axis=0, detrend="constant")
        w = float(b - a)
        psd_sum = p * w if psd_sum is None else psd_sum + p * w
        weight += w
        n_used += b - a
        n_avg += (b - a - nper) // (nper // 2) + 1
    if psd_sum is None:
        raise CalibrationError("no valid IMU error segment long enough for a spectrum")
    return f, psd_sum / weight, n_used, n_avg


def lorentzian(f: np.ndarray, centre_hz: float, bandwidth_hz: float) -> np.ndarray:
    """One-sided spectral shape (integral 1) of a narrow-band line of -3 dB width ``bandwidth_hz``."""
    g = 0.5 * bandwidth_hz
    return (g / np.pi) / (g * g + (f - centre_hz) ** 2)


def _comb_fit(f: np.ndarray, excess: np.ndarray, total: np.ndarray, floor: float, f0: float, f_lo: float,
              f_hi: float) -> tuple[float, float, np.ndarray, int] | None:
    """Best (relative SSE, line width, harmonic variances, number of harmonics) of a comb at ``f0``."""
    df = float(f[1] - f[0])
    h_max = int(min(MAX_HARMONICS, np.floor(f_hi / f0)))
    if h_max < 1:
        return None
    sel = (f >= f_lo) & (f <= f_hi)
    fs_, es_, ts_ = f[sel], np.maximum(excess[sel], 0.0), total[sel]
    wts = 1.0 / np.maximum(ts_, floor)  # relative errors: close to a log-spectrum fit
    best = None
    # grid over the line width, up to half the fundamental: a band wider than that is no line (a broad
    # line at twice the fundamental out-scored the true comb on 3 traces of the default preset)
    for bw in np.geomspace(max(df / 2, 0.02), max(0.5 * f0, df), 24):
        design = np.stack([lorentzian(fs_, h * f0, bw) for h in range(1, h_max + 1)], axis=1)
        v, _ = nnls(design * wts[:, None], es_ * wts)
        model = design @ v
        # misfit per log-frequency (weights 1/f: every octave counts the same, not every Welch bin)
        lw = 1.0 / fs_
        sse = float(np.sum(lw * np.log((model + floor) / (es_ + floor)) ** 2) / lw.sum())
        n = float(lw.sum() ** 2 / np.sum(lw**2))  # effective number of bins
        score = n * np.log(max(sse, 1e-300)) + (np.count_nonzero(v) + 2) * np.log(n)  # BIC-like
        if best is None or score < best[0]:
            best = (score, float(bw), v, h_max)
    return best


VIBRATION_MIN_EXCESS_FRAC = 0.25
"""The error spectrum (smoothed over 0.6 Hz) must exceed the white floor by at least this share of it ...
"""
VIBRATION_EXCESS_SE = 5.0
"""... and by this many of its Welch standard errors for a vibration comb to be fitted."""


def _fit_vibration(f: np.ndarray, excess: np.ndarray, total: np.ndarray, floor: float, n_avg: int, f_lo: float,
                   f_hi: float) -> dict[str, Any] | None:
    """Fundamental, line width and harmonic variances of the pooled excess PSD (over the white floor).

    Candidate fundamentals are the strongest distinct local maxima of the excess spectrum and their
    halves and thirds where these carry a line of their own; each is fitted as a comb of Lorentzian
    lines (non-negative variances per harmonic, grid search over the common line width) and the
    candidate with the smallest BIC-like score of the log-spectral misfit (one parameter per non-zero
    harmonic) wins.
    """
    band = (f >= f_lo) & (f <= f_hi)
    if band.sum() < 5:
        return None
    fb, eb = f[band], excess[band]
    k = max(int(round(0.3 / (f[1] - f[0]))), 1)
    smooth = np.convolve(eb, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    # an excess counts where the smoothed spectrum stands out of its Welch noise (a relative standard
    # error of 1 / sqrt(segments x bins averaged)) and is a fair share of the floor; a line under the
    # floor is found once enough data averages the floor's scatter down (it took twice the floor)
    thr = floor * max(VIBRATION_MIN_EXCESS_FRAC, VIBRATION_EXCESS_SE / np.sqrt(max(n_avg, 1) * (2 * k + 1)))
    if not np.any(smooth > thr):
        return None
    peaks = np.flatnonzero((smooth[1:-1] >= smooth[:-2]) & (smooth[1:-1] >= smooth[2:]) & (smooth[1:-1] > thr)) + 1
    if peaks.size == 0:
        peaks = np.array([int(np.argmax(smooth))])
    top: list[int] = []
    for j in peaks[np.argsort(smooth[peaks])[::-1]]:  # strongest first, distinct by more than 30 %
        if all(abs(np.log(fb[j] / fb[i])) > np.log(1.3) for i in top):
            top.append(int(j))
        if len(top) == N_PEAK_CANDIDATES:
            break
    cands = set()
    for j in top:
        for d in (1, 2, 3):  # sub-harmonics only where they carry a line of their own
            c = float(fb[j]) / d
            if c >= f_lo and (d == 1 or np.interp(c, fb, smooth) > 0.1 * smooth[j]):
                cands.add(round(c, 4))
    results = []
    for f0 in sorted(cands, reverse=True):  # a handful of candidate fundamentals
        r = _comb_fit(f, excess, total, floor, f0, f_lo, f_hi)
        if r is not None:
            results.append((f0, *r))
    if not results:
        return None
    best = min(results, key=lambda c: c[1])
    f0, sse, bw, v, h_max = best
    # keep the harmonics whose variance stands out of the Welch noise (3 standard errors), refit them
    # and refine the fundamental on a sub-bin grid
    df = float(f[1] - f[0])
    sel = (f >= f_lo) & (f <= f_hi)
    fs_, es_, ts_ = f[sel], np.maximum(excess[sel], 0.0), total[sel]
    wts = 1.0 / np.maximum(ts_, floor)
    width = max(2.0 * bw, 4.0 * df)
    h_idx = np.arange(1, h_max + 1)
    level = np.interp(h_idx * f0, fs_, ts_)
    se = level / np.sqrt(max(n_avg, 1)) * np.sqrt(width / df) * df
    kept = h_idx[v > 5.0 * se]
    if kept.size == 0:
        return None

    def refit(fund: float) -> tuple[float, np.ndarray]:
        design = np.stack([lorentzian(fs_, h * fund, bw) for h in kept], axis=1)
        vk, _ = nnls(design * wts[:, None], es_ * wts)
        return float(np.sum(((design @ vk) - es_) ** 2 * wts**2)), vk

    grid = f0 + np.linspace(-1.5, 1.5, 25) * df / kept.min()
    fits = [refit(g) for g in grid if g > 0]  # sub-bin refinement of the fundamental
    j = int(np.argmin([x[0] for x in fits]))
    f0 = float(grid[j])
    v = np.zeros(int(kept.max()))
    if bw < 0.25 * f0:
        # separated lines: the excess integrated over +-W around each, corrected for the share of a
        # Lorentzian of width bw outside the window (the relative-error fit underestimates line peaks)
        half = min(max(2.0 * bw, 5.0 * df), 0.5 * f0)
        share = (2.0 / np.pi) * np.arctan(2.0 * half / bw)
        for h in kept:  # a few lines
            win = np.abs(f - h * f0) <= half
            v[h - 1] = max(float(np.sum(excess[win]) * df) / share, 0.0)
        method = "excess integrated around each line"
    else:  # overlapping lines (a broad band): the fitted variances
        v[kept - 1] = fits[j][1]
        method = "non-negative least squares of the line comb"
    if not v.sum() > 0:
        return None
    return {"fundamental_hz": f0, "bandwidth_hz": bw, "harmonic_variances": v, "n_harmonics": h_max,
            "resolution_hz": float(f[1] - f[0]), "log_misfit": sse,
            "candidates": {str(c[0]): c[1] for c in results}, "comb_variance": float(v.sum()),
            "line_variance_method": method}


MOTION_WINDOW_S = 2.0
"""Window of the motion-noise regression: mean squared error against mean |a|^2 and |w|^2 [s]."""


def fit_time_offset(traces: Sequence[Trace], cutoff_hz: float, *, max_offset_s: float = 0.01,
                    lever_arm_m: Sequence[float] | None = None) -> tuple[float, dict[str, Any]]:
    """IMU-to-truth clock offset [s] minimising the pooled IMU error variance (IMU lags truth: > 0).

    A grid of 0.25 ms steps over +-``max_offset_s`` (per-axis error variances summed, pooled over
    the traces by sample count), refined by a parabola through the best three points. With
    ``lever_arm_m`` the truth is the sensor point's (:func:`sensor_truth_acceleration`), shifted as a whole.
    """
    grid = np.arange(-max_offset_s, max_offset_s + 1e-12, 2.5e-4)
    cost = np.zeros(grid.size)
    for tr in traces:  # a handful of recordings, each vectorised
        ta = sensor_truth_acceleration(tr, cutoff_hz, lever_arm_m)
        for j, off in enumerate(grid):  # ~80 offsets
            e, ok, _ = _error_against(tr, ta, float(off))
            cost[j] += float(np.sum(np.var(e[ok], axis=0))) * int(ok.sum())
    j = int(np.clip(np.argmin(cost), 1, grid.size - 2))
    y0, y1, y2 = cost[j - 1:j + 2]
    den = y0 - 2 * y1 + y2
    best = float(grid[j] + (0.5 * (y0 - y2) / den * (grid[1] - grid[0]) if den > 0 else 0.0))
    rel_gain = float(1.0 - cost.min() / cost[np.argmin(np.abs(grid))])
    return best, {"offset_s": best, "grid_step_s": float(grid[1] - grid[0]),
                  "error_variance_reduction_frac": rel_gain}


COHERENCE_MIN = 0.5
"""Magnitude-squared coherence between IMU and truth acceleration above which the truth still carries
the motion the IMU reads (:func:`coherent_bandwidth_hz`)."""


def coherent_bandwidth_hz(traces: Sequence[Trace], floor_hz: float, cap_hz: float, offset_s: float = 0.0
                          ) -> tuple[float, dict[str, Any]]:
    """The widest truth bandwidth [Hz] the IMU confirms, between ``floor_hz`` and ``cap_hz``.

    The magnitude-squared coherence between the IMU (ENU, gravity-free) and the truth-derived
    acceleration (low-passed well above ``cap_hz``, read at t - ``offset_s``; masked samples zeroed on
    both sides), Welch segments of 1 s, averaged over the three axes and the recordings: the bandwidth
    is the highest frequency up to which it stays at least ``COHERENCE_MIN`` (``floor_hz`` when it is
    already below there). Above it the truth's acceleration is mostly its own noise (optical jitter
    differentiated twice) and the IMU's motion content is no longer in it. Diagnostics: the coherence
    curve from ``floor_hz`` to ``cap_hz``.
    """
    if cap_hz <= floor_hz:
        return float(floor_hz), {"bandwidth_hz": float(floor_hz), "reason": "truth rate too low to widen"}
    curves, f = [], None
    for tr in traces:  # a handful of recordings, each vectorised
        ti = tr.imu.t_s
        fs = 1.0 / median_step_s(ti)
        tg, a, valid = truth_acceleration(tr.truth.t_s, tr.truth.pos_enu_m, cutoff_hz=min(2.0 * cap_hz, 0.45 * fs))
        a_i = np.stack([np.interp(ti - offset_s, tg, np.where(valid, a[:, k], 0.0)) for k in range(3)], axis=1)
        ok = (np.interp(ti - offset_s, tg, valid.astype(float)) > 0.999) & np.all(np.isfinite(tr.imu.acc_mps2), axis=1)
        nper = int(round(fs))
        if ok.sum() < 4 * nper:
            continue
        f, c = coherence(np.where(ok[:, None], tr.imu.acc_mps2, 0.0), np.where(ok[:, None], a_i, 0.0), fs=fs,
                         nperseg=nper, axis=0)
        curves.append(np.nan_to_num(c).mean(axis=1))
    if not curves or f is None:
        return float(floor_hz), {"bandwidth_hz": float(floor_hz), "reason": "too little IMU with valid truth"}
    n = min(c.size for c in curves)
    mean = np.mean([c[:n] for c in curves], axis=0)
    f = f[:n]
    band = (f >= floor_hz - 1e-6) & (f <= cap_hz + 1e-6)  # the grid is fs / round(fs): not exactly whole Hz
    below = np.flatnonzero(band & (mean < COHERENCE_MIN))
    top = float(f[below[0] - 1]) if below.size else float(f[band][-1]) if band.any() else float(floor_hz)
    bw = float(min(max(top, floor_hz), cap_hz))
    return bw, {"bandwidth_hz": bw, "coherence_min": COHERENCE_MIN, "frequency_hz": f[band].tolist(),
                "coherence": mean[band].round(3).tolist()}


def smoothed_body_rate(trace: Trace, t_q: np.ndarray, cutoff_hz: float) -> np.ndarray | None:
    """(N, 3) truth body angular rate low-passed at ``cutoff_hz`` (zero phase), at times ``t_q``.

    From the truth's ``omega_body_radps`` (e.g. differentiated optical attitude); None without one.
    """
    w = trace.truth.omega_body_radps
    if w is None:
        return None
    t = trace.truth.t_s
    ok = np.all(np.isfinite(w), axis=1)
    if ok.sum() < 10:
        return None
    fs = 1.0 / median_step_s(t)
    wf = np.stack([np.interp(t, t[ok], w[ok, k]) for k in range(3)], axis=1)
    wf = sosfiltfilt(butter(4, min(cutoff_hz, 0.45 * fs), fs=fs, output="sos"), wf, axis=0)
    return np.stack([np.interp(t_q, t, wf[:, k]) for k in range(3)], axis=1)


def _intensity(trace: Trace, cutoff_hz: float, offset_s: float) -> tuple[np.ndarray, np.ndarray]:
    """|a_k| (N, 3) (truth-derived, at the IMU times read at t - offset) and |w| (N,) (smoothed truth rate)."""
    tg, a, valid = truth_acceleration(trace.truth.t_s, trace.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    ti = trace.imu.t_s
    a_i = np.stack([np.interp(ti - offset_s, tg, np.where(valid, a[:, k], 0.0)) for k in range(3)], axis=1)
    w = smoothed_body_rate(trace, ti, cutoff_hz)
    return np.abs(a_i), (np.zeros(ti.size) if w is None else np.linalg.norm(w, axis=1))


CALM_ACC_MPS2 = 0.3
CALM_RATE_RADPS = 0.1
"""Samples below both (|a|, |w|) are calm: their error variance is the motion-free level c0."""


def reference_noise_target(trace: Trace, cutoff_hz: float, offset_s: float, reference_cutoff_hz: float, *,
                           lever_arm_m: Sequence[float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample squared error (N, 3) that noise added to the ``cutoff_hz`` truth must reproduce
    against the ``reference_cutoff_hz`` truth, and its mask.

    A synthetic IMU fed the truth low-passed at ``cutoff_hz`` (the sensor point's, read at t - offset)
    plus independent noise nu has, against the reference, the error (input - reference) + nu, of mean
    square E[(input - reference)^2] + E[nu^2]. The real error against the reference is e_ref = IMU -
    reference, so nu must carry E[e_ref^2] - E[(input - reference)^2] per axis: the returned
    e_ref^2 - (input - reference)^2 (its window means are what the motion-noise regression fits). This
    differs from the squared error against the input band by twice the covariance of (IMU - input) and
    (input - reference): positive where the IMU reads motion the input attenuates, negative where the
    input band holds truth noise (optical noise between the two cut-offs) that the IMU does not read.
    """
    e_ref, ok_ref, ti = imu_error(trace, reference_cutoff_hz)
    tg, a_in, v_in = sensor_truth_acceleration(trace, cutoff_hz, lever_arm_m)
    tr_, a_ref, v_ref = truth_acceleration(trace.truth.t_s, trace.truth.pos_enu_m, cutoff_hz=reference_cutoff_hz)
    d = (np.stack([np.interp(ti - offset_s, tg, np.where(v_in, a_in[:, k], 0.0)) for k in range(3)], axis=1)
         - np.stack([np.interp(ti, tr_, np.where(v_ref, a_ref[:, k], 0.0)) for k in range(3)], axis=1))
    ok = ok_ref & (np.interp(ti - offset_s, tg, v_in.astype(float)) > 0.999)
    y = np.where(ok[:, None], np.nan_to_num(e_ref) ** 2 - d**2, np.nan)
    return y, ok


def fit_motion_noise(traces: Sequence[Trace], cutoff_hz: float, offset_s: float, *,
                     use_rate: bool = True, lever_arm_m: Sequence[float] | None = None,
                     reference_cutoff_hz: float | None = None) -> dict[str, Any]:
    """Joint fit over recordings of the error variance per axis as c0 + ca_k |a_k| + cw_k |w|.

    c0 (per axis) is the mean squared error of the calm samples (``CALM_ACC_MPS2``,
    ``CALM_RATE_RADPS``) when they make up at least 10 % of the data (the rest phases of a lab
    trial), else a free intercept. The slopes come from window means (``MOTION_WINDOW_S``, windows at
    least 95 % valid) of the squared error minus c0, regressed on window means of |a_k| and |w| by
    non-negative least squares pooled over all recordings, so that recordings of different
    intensity fix them. The slopes are the vibration's variance per unit intensity. ``lever_arm_m``:
    the error is taken with the sensor's lever-arm acceleration removed (:func:`imu_error`).
    ``reference_cutoff_hz``: the squared error is replaced by what noise on top of the ``cutoff_hz``
    truth must carry for the error against that reference band to come out right
    (:func:`reference_noise_target`), c0 included.
    """
    feats, ys, calm_e2, n_calm, n_all = [], [], np.zeros(3), 0, 0
    fs = None
    for tr in traces:  # a handful of recordings
        if reference_cutoff_hz is None:
            e, ok, ti = imu_error(tr, cutoff_hz, offset_s=offset_s, lever_arm_m=lever_arm_m)
            e2 = e**2
        else:
            e2, ok = reference_noise_target(tr, cutoff_hz, offset_s, reference_cutoff_hz, lever_arm_m=lever_arm_m)
            ti = tr.imu.t_s
        a_abs, w = _intensity(tr, cutoff_hz, offset_s)
        fs = 1.0 / median_step_s(ti)
        calm = ok & (np.linalg.norm(a_abs, axis=1) < CALM_ACC_MPS2) & (w < CALM_RATE_RADPS)
        calm_e2 += np.sum(e2[calm], axis=0)
        n_calm += int(calm.sum())
        n_all += int(ok.sum())
        w_n = int(round(MOTION_WINDOW_S * fs))
        n_w = ti.size // w_n
        if n_w == 0:
            continue
        sl = slice(0, n_w * w_n)
        okw = ok[sl].reshape(n_w, w_n)
        cnt = okw.sum(axis=1)
        keep = (okw.mean(axis=1) >= 0.95) & (cnt > 0)

        def wmean(x: np.ndarray, sl=sl, n_w=n_w, w_n=w_n, cnt=cnt, keep=keep, ok=ok) -> np.ndarray:
            x = np.where(ok[sl].reshape((-1,) + (1,) * (x.ndim - 1)), np.nan_to_num(x[sl]), 0.0)
            return (x.reshape((n_w, w_n) + x.shape[1:]).sum(axis=1).T / np.maximum(cnt, 1)).T[keep]

        ys.append(wmean(e2))
        feats.append((wmean(a_abs), wmean(w)))
    if not ys or fs is None:
        raise CalibrationError("no IMU error window long enough for the motion-noise fit")
    y = np.concatenate(ys)
    a_w = np.concatenate([f[0] for f in feats])
    w_w = np.concatenate([f[1] for f in feats])
    use_w = use_rate and bool(np.any(w_w > CALM_RATE_RADPS))
    calm_level = n_calm >= 0.1 * max(n_all, 1)
    coef = np.zeros((3, 3))  # per axis: c0, c_acc, c_rate
    for axis in range(3):
        cols = [a_w[:, axis]] + ([w_w] if use_w else [])
        x = np.stack(cols, axis=1)
        if calm_level:
            c0 = max(calm_e2[axis] / n_calm, 0.0)
            target = y[:, axis] - c0
        else:
            x = np.concatenate([np.ones((x.shape[0], 1)), x], axis=1)
            target = y[:, axis]
        scale = np.maximum(np.abs(x).max(axis=0), 1e-12)
        c, _ = nnls(x / scale, target)
        c = c / scale
        if calm_level:
            c = np.concatenate([[c0], c])
        coef[axis, : c.size] = c
    return {"c0_mps2_sq": coef[:, 0], "acc_var_gain_mps2": coef[:, 1],
            "rate_var_gain_mps4_per_radps": coef[:, 2], "n_windows": int(y.shape[0]),
            "window_s": MOTION_WINDOW_S, "rate_term": use_w,
            "c0_from": "calm samples" if calm_level else "regression intercept", "calm_frac": n_calm / max(n_all, 1),
            "reference_cutoff_hz": reference_cutoff_hz}


def _pooled_error_psd(errs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], fs: float, nper: int
                      ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Welch PSD of the IMU errors pooled over recordings (weighted by the samples each used):
    (f, psd (F, 3), samples used, segments averaged)."""
    psds, weights, n_total, n_avg = [], [], 0, 0
    f = None
    for e, ok, t in errs:
        f, p, n_used, k_avg = _welch_segments(e, ok, t, fs, nper)
        psds.append(p)
        weights.append(n_used)
        n_total += n_used
        n_avg += k_avg
    minlen = min(p.shape[0] for p in psds)
    psd = sum(p[:minlen] * w for p, w in zip(psds, weights, strict=True)) / sum(weights)
    return f[:minlen], psd, n_total, n_avg


def _fit_bias_walk(errs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], fs: float, density: np.ndarray,
                   prior_rw: float) -> tuple[float, dict[str, Any]]:
    """Bias random walk from the long-tau end of the Allan deviation of the longest valid segment,
    net of the white noise ``density``; where it is not identifiable (below two standard errors), the
    smaller of ``prior_rw`` and the upper bound. Returns the value and its diagnostics (with a note
    when not identifiable)."""
    e0, ok0, t0 = max(errs, key=lambda x: int(x[1].sum()))
    segs = segments(t0, ok0, max_gap_s=1.5 / fs)
    a, b = max(segs, key=lambda s: s[1] - s[0])
    x = e0[a:b]
    dur = (b - a) / fs
    taus = np.geomspace(2.0 / fs, max(dur / 5.0, 4.0 / fs), 25)
    adev = allan_deviation(x, fs, taus).T  # (T, 3)
    white_avar = (density**2)[None, :] / taus[:, None]
    long = taus >= taus[-1] / 4.0
    k2 = 3.0 * (adev[long] ** 2 - white_avar[long]) / taus[long, None]
    k2_mean = np.nanmean(k2)
    n_indep = max(dur / taus[long].max(), 1.0)
    k2_se = float(np.nanmean(adev[long] ** 2) * 3.0 / taus[long].mean() / np.sqrt(n_indep))
    if k2_mean > 2.0 * k2_se:
        bias_rw = float(np.sqrt(k2_mean))
        note = None
    else:
        upper = float(np.sqrt(max(k2_mean, 0.0) + 2.0 * k2_se))
        bias_rw = min(prior_rw, upper)
        note = f"bias random walk not identifiable over {dur:.0f} s (upper bound {upper:.3g}); {bias_rw:.3g} used"
    return bias_rw, {"value": bias_rw, "k2_estimate": float(k2_mean), "k2_std_error": k2_se, "note": note,
                     "allan_deviation": {"tau_s": taus.tolist(), "adev_mps2": adev.tolist()}}


def _imu_traces(traces: Trace | Sequence[Trace]) -> list[Trace]:
    """The traces with more than 100 IMU samples (an error when there is none)."""
    trs = [traces] if isinstance(traces, Trace) else list(traces)
    trs = [t for t in trs if t.imu is not None and t.imu.t_s.size > 100]
    if not trs:
        raise CalibrationError("no trace with IMU samples: IMU noise cannot be calibrated")
    return trs


def _fit_offset_and_lever(trs: list[Trace], fc: float, motion_dependent: bool, lever_arm: bool,
                          auto_lever: bool = False
                          ) -> tuple[float, dict[str, Any] | None, np.ndarray | None, dict[str, Any] | None]:
    """The kept IMU-to-truth time offset and lever arm with their diagnostics: (offset, offset_diag,
    lever or None, lever_diag). ``auto_lever``: a lever arm the truth's rotation cannot identify is left
    out (noted in the diagnostics) instead of raising.

    The offset is kept when it lowers the error variance by at least 0.5 % and exceeds 0.25 ms; the
    lever arm when it lowers the mean squared error by at least 0.5 %, and then the offset is fitted
    again for the sensor point (the first fit kept under ``without_lever_arm``).
    """
    offset, offset_diag = 0.0, None
    if motion_dependent:
        offset, offset_diag = fit_time_offset(trs, fc)
        if offset_diag["error_variance_reduction_frac"] < 0.005 or abs(offset) < 2.5e-4:
            offset_diag["kept"] = False
            offset = 0.0
    lever, lever_diag = None, None
    if lever_arm:
        try:
            r, lever_diag = fit_lever_arm(trs, fc, offset)
        except CalibrationError as exc:
            if not auto_lever:
                raise
            return offset, offset_diag, None, {"kept": False, "reason": str(exc)}
        lever_diag["kept"] = lever_diag["mean_square_reduction_frac"] >= 0.005
        lever = r if lever_diag["kept"] else None
        if lever is not None and motion_dependent:  # the clock offset again, now of the sensor point
            off2, od2 = fit_time_offset(trs, fc, lever_arm_m=lever)
            od2["kept"] = not (od2["error_variance_reduction_frac"] < 0.005 or abs(off2) < 2.5e-4)
            offset = off2 if od2["kept"] else 0.0
            offset_diag = {**od2, "without_lever_arm": offset_diag}
            r, lever_diag = fit_lever_arm(trs, fc, offset)
            lever_diag["kept"] = lever_diag["mean_square_reduction_frac"] >= 0.005
            lever = r if lever_diag["kept"] else None
    return offset, offset_diag, lever, lever_diag


def _level_motion_noise(trs: list[Trace], errs: list, fc: float, offset: float, motion: dict[str, Any],
                        targets: list[tuple[np.ndarray, np.ndarray]] | None = None) -> np.ndarray:
    """Scale the motion-noise gains of ``motion`` (in place) so that, pooled over the recordings,
    zero-motion variance plus motion variance equals the error variance (with ``errs`` items
    ``targets``, per recording the (squared-error target, mask) of :func:`reference_noise_target`: its
    mean); drop
    an axis's gains when they carry less than 5 % of its variance. Returns the mean motion variance (3,)
    [m^2 s^-4]."""
    # mean motion-noise variance over the samples used (per-sample, at the IMU rate)
    num, cnt = np.zeros(3), 0
    sq = [(e**2, ok) for e, ok, _ in errs] if targets is None else targets
    for tr, (_, ok) in zip(trs, sq, strict=True):
        a_abs, w = _intensity(tr, fc, offset)
        num += np.sum(a_abs[ok] * motion["acc_var_gain_mps2"][None, :]
                      + w[ok, None] * motion["rate_var_gain_mps4_per_radps"][None, :], axis=0)
        cnt += int(ok.sum())
    motion_var = num / max(cnt, 1)  # (3,) [m^2 s^-4]
    # the regression fixes how the power grows; its level is set so that, pooled over the
    # recordings, zero-motion variance plus motion variance equals the error variance
    pooled = np.sum([np.sum(y[ok], axis=0) for y, ok in sq], axis=0) / max(cnt, 1)
    level = np.where(motion_var > 0,
                     np.maximum(pooled - motion["c0_mps2_sq"], 0.0) / np.maximum(motion_var, 1e-300), 0.0)
    motion["acc_var_gain_mps2"] = motion["acc_var_gain_mps2"] * level
    motion["rate_var_gain_mps4_per_radps"] = motion["rate_var_gain_mps4_per_radps"] * level
    motion["level_factor"] = level.tolist()
    motion_var = motion_var * level
    total = motion["c0_mps2_sq"] + motion_var
    weak = motion_var < 0.05 * total
    motion["acc_var_gain_mps2"][weak] = 0.0
    motion["rate_var_gain_mps4_per_radps"][weak] = 0.0
    motion_var[weak] = 0.0
    motion["mean_motion_variance_mps2_sq"] = motion_var.tolist()
    motion["axes_without_motion_term"] = [a for a, w in zip("enu", weak, strict=True) if w]
    return motion_var


def calm_white_density(trs: Sequence[Trace], errs: list, fc: float, offset_s: float, band_hz: tuple[float, float]
                       ) -> tuple[np.ndarray | None, int]:
    """White-noise density (3,) [m s^-2 Hz^-1/2] of the IMU error over the calm samples only.

    The error (``errs`` items of :func:`imu_error`) band-passed to ``band_hz`` (4th-order zero-phase
    Butterworth, masked samples zeroed) has, over the calm samples (``CALM_ACC_MPS2``,
    ``CALM_RATE_RADPS``), the mean square psd x bandwidth of a white floor of one-sided PSD psd, so
    density = sqrt(mean square / bandwidth / 2). Returns (None, n) with fewer than 10 s of calm samples.
    """
    fs = 1.0 / median_step_s(trs[0].imu.t_s)
    lo, hi = band_hz
    sos = butter(4, [lo, min(hi, 0.49 * fs)], btype="band", fs=fs, output="sos")
    acc, n = np.zeros(3), 0
    for tr, (e, ok, _) in zip(trs, errs, strict=True):  # a handful of recordings, each vectorised
        a_abs, w = _intensity(tr, fc, offset_s)
        calm = ok & (np.linalg.norm(a_abs, axis=1) < CALM_ACC_MPS2) & (w < CALM_RATE_RADPS)
        # keep away from the zeroed (masked) samples: the band-pass rings over a few of its periods
        near = np.convolve((~ok).astype(float), np.ones(int(0.2 * fs) | 1), mode="same") > 0
        calm &= ~near
        x = sosfiltfilt(sos, np.where(ok[:, None], np.nan_to_num(e), 0.0), axis=0)
        acc += np.sum(x[calm] ** 2, axis=0)
        n += int(calm.sum())
    if n < 10.0 * fs:
        return None, n
    return np.sqrt(acc / n / (min(hi, 0.49 * fs) - lo) / 2.0), n


def _error_spectrum_white_floor(errs: list, fs: float, fc: float, nperseg_s: float) -> tuple:
    """Pooled Welch PSD of the IMU error and its white floor in ``WHITE_BAND`` (above 1.5 fc):
    (nper, f, psd, n_total, n_avg, lo, hi, wb, floor (3,) one-sided, density (3,))."""
    nper = int(2 ** np.round(np.log2(nperseg_s * fs)))
    f, psd, n_total, n_avg = _pooled_error_psd(errs, fs, nper)
    nyq = fs / 2.0
    lo, hi = max(WHITE_BAND[0] * nyq, 1.5 * fc), WHITE_BAND[1] * nyq
    if lo >= hi:
        lo = 0.5 * (fc + nyq)
    wb = (f >= lo) & (f <= hi)
    floor = np.median(psd[wb], axis=0)  # (3,) one-sided white level
    density = np.sqrt(floor / 2.0)
    return nper, f, psd, n_total, n_avg, lo, hi, wb, floor, density


def _vibration_params(vib: dict[str, Any] | None, density: np.ndarray, fs: float, err_std: np.ndarray,
                      resid_std: np.ndarray, other_var: np.ndarray, motion: dict[str, Any] | None,
                      notes: list[str]) -> tuple[VibrationParams, dict[str, Any]]:
    """The vibration model and its diagnostics from the comb fit ``vib``: spectral shape from the
    comb, amplitude from the variance left by white noise and bias walk (or from the lines when
    white noise dominates), capped at zero motion by the error variance. Appends to ``notes``."""
    if vib is None or (not resid_std.max() > 0 and motion is None):
        notes.append("imu.vibration (no spectral excess over the white floor)")
        return VibrationParams(amplitude_mps2=0.0), {"note": "no vibration found"}
    v = vib["harmonic_variances"]
    f0 = vib["fundamental_hz"]
    nz = np.flatnonzero(v > 1e-3 * v.max()) + 1
    step = int(np.gcd.reduce(nz)) if nz.size else 1
    if step > 1:  # only multiples of step carry power: the fundamental is step * f0
        f0, v = f0 * step, v[step - 1::step]
    keep = np.flatnonzero(v > 1e-3 * v.max())
    w = v[: int(keep.max()) + 1] / v.max()
    white_frac = float(np.mean(density**2 * fs / np.maximum(err_std, 1e-12) ** 2))
    if white_frac > 0.5:  # the error variance is mostly white noise: the spectral lines are more precise
        amp = float(np.sqrt(vib["comb_variance"]))
        amp_method = ("white noise dominates the error variance: amplitude from the variance of the fitted "
                      "spectral lines (axis-mean spectrum)")
        gain = np.ones(3)
    else:
        amp = float(resid_std.max())
        gain = resid_std / amp if amp > 0 else np.ones(3)
        amp_method = ("per-axis error std left after white noise and bias walk: amplitude of the strongest "
                      "axis, axis_gain for the others")
    if motion is not None and amp > 0:  # at zero motion the vibration holds what c0 leaves, no more
        cap = resid_std / np.maximum(gain, 1e-12)
        if amp > float(cap.min()):
            amp = float(cap.min())
            amp_method += "; capped by the error variance at zero motion"
    vibration = VibrationParams(fundamental_hz=rounded(f0, 5), amplitude_mps2=rounded(amp, 5),
                                harmonic_weights=[rounded(x, 4) for x in w],
                                bandwidth_hz=rounded(vib["bandwidth_hz"], 4),
                                axis_gain=[rounded(float(g), 4) for g in gain])
    rel = (np.sqrt((amp * gain) ** 2 + other_var) / np.maximum(err_std, 1e-12) - 1.0)
    vib_diag = {"fundamental_hz": f0, "bandwidth_hz": vib["bandwidth_hz"], "amplitude_mps2": amp,
                "harmonic_weights": w.tolist(), "n_harmonics_fitted": vib["n_harmonics"],
                "frequency_resolution_hz": vib["resolution_hz"], "log_misfit": vib["log_misfit"],
                "candidate_fundamentals_misfit": vib["candidates"],
                "comb_fit_amplitude_mps2": float(np.sqrt(vib["harmonic_variances"].sum())),
                "line_variance_method": vib["line_variance_method"],
                "per_axis_nonwhite_std_mps2": resid_std.tolist(),
                "per_axis_model_std_rel_error": rel.tolist(),
                "white_variance_frac": white_frac, "amplitude_method": amp_method}
    return vibration, vib_diag


def _imu_params(fs: float, density: np.ndarray, bias_rw: float, vibration: VibrationParams, offset: float,
                motion: dict[str, Any] | None, lever: np.ndarray | None, truth_cutoff_hz: float) -> ImuParams:
    """The fitted values, rounded, as the scenario's IMU section."""
    motion_params = MotionNoiseParams()
    if motion is not None:
        motion_params = MotionNoiseParams(
            acc_var_gain_mps2=[rounded(x, 5) for x in motion["acc_var_gain_mps2"]],
            rate_var_gain_mps4_per_radps=[rounded(x, 5) for x in motion["rate_var_gain_mps4_per_radps"]])
    return ImuParams(rate_hz=rounded(fs, 7), white_noise_density_mps2_per_sqrt_hz=[rounded(x, 5) for x in density],
                     bias_rw_mps2_per_sqrt_s=rounded(bias_rw, 4), bias_initial_std_mps2=0.0, vibration=vibration,
                     time_offset_s=rounded(offset, 4), motion_noise=motion_params,
                     lever_arm_m=[0.0, 0.0, 0.0] if lever is None else [rounded(float(x), 4) for x in lever],
                     truth_cutoff_hz=rounded(truth_cutoff_hz, 4))


def _imu_fit_diagnostics(trs: list[Trace], errs: list, fc: float, fs: float, spectrum: tuple,
                         offset_diag: dict[str, Any] | None, lever_diag: dict[str, Any] | None,
                         motion: dict[str, Any] | None, vib_diag: dict[str, Any], bias_diag: dict[str, Any],
                         notes: list[str]) -> dict[str, Any]:
    """The diagnostics dict of :func:`fit_imu` (``spectrum`` from :func:`_error_spectrum_white_floor`)."""
    _, f, psd, n_total, _, lo, hi, wb, _, density = spectrum
    dec = max(1, f.size // 400)
    return {
        "truth_cutoff_hz": fc,
        "imu_rate_hz": fs,
        "white_band_hz": [float(lo), float(hi)],
        "white_noise_density_mps2_per_sqrt_hz": density.tolist(),
        "white_noise_rel_se": float(1.0 / np.sqrt(max(wb.sum() * len(errs), 1))),
        "error_std_mps2": np.sqrt(np.nanmean(np.concatenate([e[ok] for e, ok, _ in errs]) ** 2, axis=0)).tolist(),
        "time_offset": offset_diag,
        "lever_arm": lever_diag,
        "motion_noise": None if motion is None else {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                                     for k, v in motion.items()},
        "n_samples": n_total,
        "vibration": vib_diag,
        "bias_rw": {k: bias_diag[k] for k in ("value", "k2_estimate", "k2_std_error", "note")},
        "allan_deviation": bias_diag["allan_deviation"],
        "psd": {"f_hz": f[::dec].tolist(), "psd_mps2_sq_per_hz": psd[::dec].tolist()},
        "recordings": [trace_label(t, i) for i, t in enumerate(trs)],
        "not_identifiable": notes,
    }


def _truth_band(trs: list[Trace], cutoff_hz: float | None, motion_dependent: bool, truth_rate: float
                ) -> tuple[float, dict[str, Any] | None]:
    """The truth cut-off of :func:`fit_imu` and its diagnostics (None unless widened by coherence)."""
    if cutoff_hz is not None:
        return float(cutoff_hz), None
    floor = float(min(10.0, 0.2 * truth_rate))
    return coherent_bandwidth_hz(trs, floor, 0.2 * truth_rate) if motion_dependent else (floor, None)


def fit_imu(traces: Trace | Sequence[Trace], *, cutoff_hz: float | None = None, nperseg_s: float = 20.0,
            defaults: ImuParams | None = None, motion_dependent: bool = True,
            motion_rate_term: bool = False, lever_arm: bool | None = None,
            reference_cutoff_hz: float | None = None, calm_white_noise: bool = False) -> Fit[ImuParams]:
    """Fit white noise, bias random walk and vibration to the IMU error of traces with IMU and truth.

    Parameters
    ----------
    traces
        Traces with IMU samples (ENU, gravity-free) and truth positions.
    cutoff_hz
        Low-pass cut-off of the truth before double differentiation [Hz]: the band of truth the noise
        terms are fitted against, recorded as ``truth_cutoff_hz``. Default min(10 Hz, 0.2 x truth
        rate), widened with the motion-dependent model up to the highest frequency where the truth
        still follows the IMU (:func:`coherent_bandwidth_hz`, at most 0.2 x truth rate): the real motion
        in that band is then the model's input, not its noise.
    nperseg_s
        Welch segment length [s] (frequency resolution 1 / nperseg_s).
    motion_dependent
        Also fit the IMU-to-truth time offset (:func:`fit_time_offset`; kept when it lowers the error
        variance by at least 0.5 %) and the motion-scaled noise (:func:`fit_motion_noise`; an axis's
        gains kept when they carry at least 5 % of its mean error variance). The white-noise density is
        fitted as before; the vibration amplitude comes from the error variance at zero motion, and
        the vibration's power grows with the motion (:class:`~physynth.models.imu.MotionNoiseParams`).
    motion_rate_term
        Let the motion noise grow with the angular rate too (needs truth attitude rates).
    lever_arm
        Also fit the sensor's position in the body frame (:func:`fit_lever_arm`, after the time
        offset, before the motion noise; needs the truth attitude), kept when it lowers the mean
        squared error by at least 0.5 %; the noise terms are then fitted to the error with its
        lever-arm acceleration removed. Default (None): when every recording's truth has an attitude
        and a body rate.
    reference_cutoff_hz
        The cut-off of the reference truth the IMU error is judged against, when it is below
        ``cutoff_hz`` (e.g. 10 Hz against a 14 Hz input): the motion noise (c0, gains, level) is then
        fitted to what noise added to the ``cutoff_hz`` truth must carry for the error against the
        reference to come out right (:func:`reference_noise_target`), rather than to the error
        against the ``cutoff_hz`` truth itself.
    calm_white_noise
        With the motion noise, take the white-noise density from the calm samples only
        (:func:`calm_white_density`, same band): the sensor's own noise. The high-frequency error of the
        moving phases (ten times the calm level on a fast rotating trial) then belongs to the
        motion-scaled term, and at zero motion white noise, bias walk and vibration add up to c0
        instead of the pooled white level alone exceeding it.

    Returns
    -------
    Fit[ImuParams]
        Diagnostics: per-axis white-noise density and error standard deviation, the PSD (decimated),
        the vibration fit, the Allan deviation table, what was not identifiable.
    """
    trs = _imu_traces(traces)
    base = defaults or ImuParams()
    fs = 1.0 / median_step_s(trs[0].imu.t_s)
    truth_rate = 1.0 / median_step_s(trs[0].truth.t_s[np.all(np.isfinite(trs[0].truth.pos_enu_m), axis=1)])
    fc, band_diag = _truth_band(trs, cutoff_hz, motion_dependent, truth_rate)
    offset, offset_diag, lever, lever_diag = _fit_offset_and_lever(
        trs, fc, motion_dependent, all(has_truth_rotation(t) for t in trs) if lever_arm is None else lever_arm,
        auto_lever=lever_arm is None)
    motion, motion_var = None, np.zeros(3)
    if motion_dependent:
        motion = fit_motion_noise(trs, fc, offset, use_rate=motion_rate_term, lever_arm_m=lever,
                                  reference_cutoff_hz=reference_cutoff_hz)
    errs = [imu_error(t, fc, offset_s=offset, lever_arm_m=lever) for t in trs]
    if motion is not None:
        targets = None if reference_cutoff_hz is None else [
            reference_noise_target(t, fc, offset, reference_cutoff_hz, lever_arm_m=lever) for t in trs]
        motion_var = _level_motion_noise(trs, errs, fc, offset, motion, targets)
    spectrum = _error_spectrum_white_floor(errs, fs, fc, nperseg_s)
    nper, f, psd, n_total, n_avg, lo, hi, _, floor, density = spectrum
    calm_white = None
    if calm_white_noise and motion is not None:
        calm_white, n_calm = calm_white_density(trs, errs, fc, offset, (lo, hi))
        if calm_white is not None:
            motion["white_noise_density_pooled_mps2_per_sqrt_hz"] = density.tolist()
            motion["white_noise_from_calm_samples"] = n_calm
            density = calm_white
    err_std = np.sqrt(np.nanmean(np.concatenate([e[ok] for e, ok, _ in errs]) ** 2, axis=0))
    if motion is not None:  # the vibration must explain what is left at zero motion
        err_std = np.sqrt(np.maximum(np.minimum(err_std**2 - motion_var, motion["c0_mps2_sq"]), 1e-12))
    pooled, pooled_floor = psd.mean(axis=1), float(floor.mean())  # vibration on the pooled spectrum's excess
    vib = _fit_vibration(f, pooled - pooled_floor, pooled, pooled_floor, 3 * n_avg, f_lo=max(0.3, 3.0 / (nper / fs)),
                         f_hi=min(0.45 * (fs / 2.0), lo))
    notes: list[str] = []
    bias_rw, bias_diag = _fit_bias_walk(errs, fs, density, base.bias_rw_mps2_per_sqrt_s)
    if bias_diag["note"] is not None:
        notes.append("imu.bias_rw_mps2_per_sqrt_s (" + bias_diag["note"] + ")")
    # vibration: spectral shape from the comb fit, amplitude from the variance the white noise and the
    # bias walk leave unexplained (per axis), one amplitude for all axes (the generator's model)
    seg_s = float(np.mean([(b_ - a_) / fs for e_, ok_, t_ in errs for a_, b_ in segments(t_, ok_, 1.5 / fs)]))
    other_var = density**2 * fs + bias_rw**2 * seg_s / 6.0
    resid_std = np.sqrt(np.maximum(err_std**2 - other_var, 0.0))
    vibration, vib_diag = _vibration_params(vib, density, fs, err_std, resid_std, other_var, motion, notes)
    params = _imu_params(fs, density, bias_rw, vibration, offset, motion, lever, fc)
    diag = _imu_fit_diagnostics(trs, errs, fc, fs, spectrum, offset_diag, lever_diag, motion, vib_diag, bias_diag,
                                notes)
    if band_diag is not None:
        diag["truth_bandwidth"] = band_diag
    return Fit(params=params, n_samples=n_total, diagnostics=diag)


def simulate_imu_on(t_s: np.ndarray, acc_enu_mps2: np.ndarray, params: ImuParams, *,
                    rng: np.random.Generator, omega_body_radps: np.ndarray | None = None,
                    attitude: Rotation | None = None) -> Imu:
    """The generator's IMU model (:func:`physynth.imu.simulate_imu`) applied to a given acceleration track.

    ``t_s`` (T,) uniform times [s] and ``acc_enu_mps2`` (T, 3) the true acceleration (e.g. derived
    from a real trial's truth, NaN spans filled); the IMU is sampled at ``params.rate_hz`` from t_s[0].
    ``omega_body_radps`` (T, 3) and ``attitude`` (T rotations): for the rate-scaled noise and the lever arm.
    """
    acc = np.asarray(acc_enu_mps2, dtype=float)
    kin = Kinematics(t_s=np.asarray(t_s, dtype=float), s_m=np.zeros(len(t_s)), pos_enu_m=np.zeros_like(acc),
                     vel_enu_mps=np.zeros_like(acc), acc_enu_mps2=acc)
    return simulate_imu(kin, params, rng=rng, omega_body_radps=omega_body_radps, attitude=attitude)


def filled_truth_acceleration(real: Trace, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(truth grid, acceleration (K, 3)) of a real trace's truth low-passed at ``cutoff_hz``, masked
    spans filled linearly: what an IMU model is run along."""
    tg, acc, valid = truth_acceleration(real.truth.t_s, real.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    if valid.sum() < 10:
        raise CalibrationError("too little valid truth to run the IMU along")
    return tg, np.stack([np.interp(tg, tg[valid], acc[valid, k]) for k in range(3)], axis=1)


def imu_along_truth(real: Trace, params: ImuParams, *, rng: np.random.Generator,
                    input_cutoff_hz: float | None = None,
                    truth_input: tuple[np.ndarray, np.ndarray] | None = None) -> Imu:
    """The ENU IMU model ``params`` run along a real trace's own truth (sampled from its first truth instant).

    The model reads the truth acceleration low-passed at ``input_cutoff_hz`` (default the model's
    ``truth_cutoff_hz``, else 10 Hz), masked spans filled linearly; with a lever arm and a truth
    attitude, the sensor point's rotational acceleration along the truth's rotation (body rate
    low-passed at the same band). ``truth_input``: that band's :func:`filled_truth_acceleration`, when
    the caller has it already.
    """
    fc_in = float(input_cutoff_hz if input_cutoff_hz is not None else params.truth_cutoff_hz or 10.0)
    tg, filled = truth_input if truth_input is not None else filled_truth_acceleration(real, fc_in)
    att = truth_attitude_at(real, tg) if any(params.lever_arm_m) else None
    return simulate_imu_on(tg, filled, params, rng=rng, omega_body_radps=smoothed_body_rate(real, tg, fc_in),
                           attitude=None if att is None else att[0])


def compare_imu_along_truth(real: Trace, params: ImuParams, cutoff_hz: float, *,
                            rng: np.random.Generator, input_cutoff_hz: float | None = None) -> dict[str, np.ndarray]:
    """Apply the IMU error model ``params`` along a real trace's own truth and compare the IMU errors.

    The error of both sides is IMU minus the truth-derived acceleration low-passed at ``cutoff_hz``
    (:func:`imu_error`). The synthetic IMU reads the truth low-passed at ``input_cutoff_hz`` (default
    the model's ``truth_cutoff_hz``, else ``cutoff_hz``; :func:`imu_along_truth`): above ``cutoff_hz``
    the real IMU reads motion that the reference filters out, so a
    model calibrated on the error against a wider-band truth (``fit_imu(..., cutoff_hz=input_cutoff_hz)``)
    is compared with the same band of real motion in its input. With a truth attitude, the model's
    lever arm acts along the truth's rotation (body rate low-passed at ``input_cutoff_hz``). Returns
    per-axis error std (``std_real``, ``std_synth``), and on log10 Welch PSDs (8192-sample segments,
    0.2 Hz to 0.95 x Nyquist, masked samples zeroed) the correlation (``log_psd_corr``) and the
    log-spectral distance in dB (``lsd_db``).
    """
    fc_in = input_cutoff_hz if input_cutoff_hz is not None else params.truth_cutoff_hz or cutoff_hz
    synth = Trace(truth=real.truth, uwb=real.uwb, anchors=real.anchors,
                  imu=imu_along_truth(real, params, rng=rng, input_cutoff_hz=fc_in))
    e_r, ok_r, _ = imu_error(real, cutoff_hz)
    e_s, ok_s, _ = imu_error(synth, cutoff_hz)
    fs = params.rate_hz
    f, p_r = welch(np.where(ok_r[:, None], e_r, 0.0), fs=fs, nperseg=8192, axis=0)
    _, p_s = welch(np.where(ok_s[:, None], e_s, 0.0), fs=fs, nperseg=8192, axis=0)
    band = (f > 0.2) & (f < 0.95 * fs / 2)
    lr, ls = np.log10(p_r[band]), np.log10(p_s[band])
    return {
        "std_real": np.std(e_r[ok_r], axis=0),
        "std_synth": np.std(e_s[ok_s], axis=0),
        "log_psd_corr": np.array([np.corrcoef(lr[:, k], ls[:, k])[0, 1] for k in range(3)]),
        "lsd_db": np.sqrt(np.mean((10.0 * (lr - ls)) ** 2, axis=0)),
    }
