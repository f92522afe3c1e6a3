"""The IMU's motion-dependent error and its time offset: the band where the truth still follows the IMU,
the error's growth with the motion's intensity, the white density measured where the motion is calm.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.signal import butter, coherence, sosfiltfilt

from ..records import Trace
from ._base import CalibrationError, median_step_s
from .imu_truth import errors_at_offsets, imu_error, sensor_truth_acceleration, smoothed_body_rate, truth_acceleration

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
        error_at = errors_at_offsets(tr, ta)
        for j, off in enumerate(grid):  # ~80 offsets
            e, ok, _ = error_at(float(off))
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


def motion_intensity(trace: Trace, cutoff_hz: float, offset_s: float) -> tuple[np.ndarray, np.ndarray]:
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
        a_abs, w = motion_intensity(tr, cutoff_hz, offset_s)
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
        a_abs, w = motion_intensity(tr, fc, offset_s)
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


def level_motion_noise(trs: list[Trace], errs: list, fc: float, offset: float, motion: dict[str, Any],
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
        a_abs, w = motion_intensity(tr, fc, offset)
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
