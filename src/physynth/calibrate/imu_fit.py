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
from scipy.signal import butter, sosfiltfilt, welch

from ..evaluate.stats import allan_deviation
from ..models.imu import simulate_imu
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


def imu_error(trace: Trace, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU error (N, 3) = IMU minus truth-derived acceleration at the IMU times, its mask and the times.

    The error is NaN (mask False) where the IMU or the truth is masked, near truth gaps and segment
    ends. The IMU is assumed to be ENU, gravity-free (the trace's ``imu.frame``).
    """
    if trace.imu is None:
        raise CalibrationError("trace has no IMU samples")
    tg, a_truth, valid = truth_acceleration(trace.truth.t_s, trace.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    ti = trace.imu.t_s
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
    for bw in np.geomspace(max(df / 2, 0.02), max(f0, df), 24):  # grid over the line width
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
    if not np.any(eb > floor):
        return None
    k = max(int(round(0.3 / (f[1] - f[0]))), 1)
    smooth = np.convolve(eb, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    peaks = np.flatnonzero((smooth[1:-1] >= smooth[:-2]) & (smooth[1:-1] >= smooth[2:]) & (smooth[1:-1] > floor)) + 1
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


def fit_imu(traces: Trace | Sequence[Trace], *, cutoff_hz: float | None = None, nperseg_s: float = 20.0,
            defaults: ImuParams | None = None) -> Fit[ImuParams]:
    """Fit white noise, bias random walk and vibration to the IMU error of traces with IMU and truth.

    Parameters
    ----------
    traces
        Traces with IMU samples (ENU, gravity-free) and truth positions.
    cutoff_hz
        Low-pass cut-off of the truth before double differentiation [Hz]; default
        min(10 Hz, 0.2 x truth rate).
    nperseg_s
        Welch segment length [s] (frequency resolution 1 / nperseg_s).

    Returns
    -------
    Fit[ImuParams]
        Diagnostics: per-axis white-noise density and error standard deviation, the PSD (decimated),
        the vibration fit, the Allan deviation table, what was not identifiable.
    """
    trs = [traces] if isinstance(traces, Trace) else list(traces)
    trs = [t for t in trs if t.imu is not None and t.imu.t_s.size > 100]
    if not trs:
        raise CalibrationError("no trace with IMU samples: IMU noise cannot be calibrated")
    base = defaults or ImuParams()
    fs = 1.0 / median_step_s(trs[0].imu.t_s)
    truth_rate = 1.0 / median_step_s(trs[0].truth.t_s[np.all(np.isfinite(trs[0].truth.pos_enu_m), axis=1)])
    fc = float(cutoff_hz) if cutoff_hz is not None else float(min(10.0, 0.2 * truth_rate))
    errs = [imu_error(t, fc) for t in trs]
    nper = int(2 ** np.round(np.log2(nperseg_s * fs)))
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
    f = f[:minlen]
    nyq = fs / 2.0
    lo, hi = max(WHITE_BAND[0] * nyq, 1.5 * fc), WHITE_BAND[1] * nyq
    if lo >= hi:
        lo = 0.5 * (fc + nyq)
    wb = (f >= lo) & (f <= hi)
    floor = np.median(psd[wb], axis=0)  # (3,) one-sided white level
    density = np.sqrt(floor / 2.0)
    err_std = np.sqrt(np.nanmean(np.concatenate([e[ok] for e, ok, _ in errs]) ** 2, axis=0))
    # vibration on the excess of the pooled (mean over axes) spectrum
    pooled = psd.mean(axis=1)
    pooled_floor = float(floor.mean())
    vib = _fit_vibration(f, pooled - pooled_floor, pooled, pooled_floor, 3 * n_avg, f_lo=max(0.3, 3.0 / (nper / fs)),
                         f_hi=min(0.45 * nyq, lo))
    notes: list[str] = []
    # bias random walk from the long-tau end of the Allan deviation
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
        bias_note = None
    else:
        upper = float(np.sqrt(max(k2_mean, 0.0) + 2.0 * k2_se))
        bias_rw = min(base.bias_rw_mps2_per_sqrt_s, upper)
        bias_note = (f"bias random walk not identifiable over {dur:.0f} s (upper bound {upper:.3g}); "
                     f"{bias_rw:.3g} used")
        notes.append("imu.bias_rw_mps2_per_sqrt_s (" + bias_note + ")")
    # vibration: spectral shape from the comb fit, amplitude from the variance the white noise and the
    # bias walk leave unexplained (per axis), one amplitude for all axes (the generator's model)
    seg_s = float(np.mean([(b_ - a_) / fs for e_, ok_, t_ in errs for a_, b_ in segments(t_, ok_, 1.5 / fs)]))
    other_var = density**2 * fs + bias_rw**2 * seg_s / 6.0
    resid_std = np.sqrt(np.maximum(err_std**2 - other_var, 0.0))
    if vib is None or not resid_std.max() > 0:
        vibration = VibrationParams(amplitude_mps2=0.0)
        notes.append("imu.vibration (no spectral excess over the white floor)")
        vib_diag: dict[str, Any] = {"note": "no vibration found"}
    else:
        v = vib["harmonic_variances"]
        f0 = vib["fundamental_hz"]
        nz = np.flatnonzero(v > 1e-3 * v.max()) + 1
        step = int(np.gcd.reduce(nz)) if nz.size else 1
        if step > 1:  # only multiples of step carry power: the fundamental is step * f0
            f0, v = f0 * step, v[step - 1::step]
        keep = np.flatnonzero(v > 1e-3 * v.max())
        w = v[: int(keep.max()) + 1] / v.max()
        white_frac = float(np.mean(density**2 * fs / err_std**2))
        if white_frac > 0.5:  # the error variance is mostly white noise: the spectral lines are more precise
            amp = float(np.sqrt(vib["comb_variance"]))
            amp_method = ("white noise dominates the error variance: amplitude from the variance of the fitted "
                          "spectral lines (axis-mean spectrum)")
            gain = np.ones(3)
        else:
            amp = float(resid_std.max())
            gain = resid_std / amp
            amp_method = ("per-axis error std left after white noise and bias walk: amplitude of the strongest "
                          "axis, axis_gain for the others")
        vibration = VibrationParams(fundamental_hz=rounded(f0, 5), amplitude_mps2=rounded(amp, 5),
                                    harmonic_weights=[rounded(x, 4) for x in w],
                                    bandwidth_hz=rounded(vib["bandwidth_hz"], 4),
                                    axis_gain=[rounded(float(g), 4) for g in gain])
        rel = (np.sqrt((amp * gain) ** 2 + other_var) / err_std - 1.0)
        vib_diag = {"fundamental_hz": f0, "bandwidth_hz": vib["bandwidth_hz"], "amplitude_mps2": amp,
                    "harmonic_weights": w.tolist(), "n_harmonics_fitted": vib["n_harmonics"],
                    "frequency_resolution_hz": vib["resolution_hz"], "log_misfit": vib["log_misfit"],
                    "candidate_fundamentals_misfit": vib["candidates"],
                    "comb_fit_amplitude_mps2": float(np.sqrt(vib["harmonic_variances"].sum())),
                    "line_variance_method": vib["line_variance_method"],
                    "per_axis_nonwhite_std_mps2": resid_std.tolist(),
                    "per_axis_model_std_rel_error": rel.tolist(),
                    "white_variance_frac": white_frac, "amplitude_method": amp_method}
    params = ImuParams(rate_hz=rounded(fs, 7), white_noise_density_mps2_per_sqrt_hz=[rounded(x, 5) for x in density],
                       bias_rw_mps2_per_sqrt_s=rounded(bias_rw, 4), bias_initial_std_mps2=0.0, vibration=vibration)
    dec = max(1, f.size // 400)
    diag = {
        "truth_cutoff_hz": fc,
        "imu_rate_hz": fs,
        "white_band_hz": [float(lo), float(hi)],
        "white_noise_density_mps2_per_sqrt_hz": density.tolist(),
        "white_noise_rel_se": float(1.0 / np.sqrt(max(wb.sum() * len(psds), 1))),
        "error_std_mps2": err_std.tolist(),
        "n_samples": n_total,
        "vibration": vib_diag,
        "bias_rw": {"value": bias_rw, "k2_estimate": float(k2_mean), "k2_std_error": k2_se,
                    "note": bias_note},
        "allan_deviation": {"tau_s": taus.tolist(), "adev_mps2": adev.tolist()},
        "psd": {"f_hz": f[::dec].tolist(), "psd_mps2_sq_per_hz": psd[::dec].tolist()},
        "recordings": [trace_label(t, i) for i, t in enumerate(trs)],
        "not_identifiable": notes,
    }
    return Fit(params=params, n_samples=n_total, diagnostics=diag)


def simulate_imu_on(t_s: np.ndarray, acc_enu_mps2: np.ndarray, params: ImuParams, *,
                    rng: np.random.Generator) -> Imu:
    """The generator's IMU model (:func:`physynth.imu.simulate_imu`) applied to a given acceleration track.

    ``t_s`` (T,) uniform times [s] and ``acc_enu_mps2`` (T, 3) the true acceleration (e.g. derived
    from a real trial's truth, NaN spans filled); the IMU is sampled at ``params.rate_hz`` from t_s[0].
    """
    acc = np.asarray(acc_enu_mps2, dtype=float)
    kin = Kinematics(t_s=np.asarray(t_s, dtype=float), s_m=np.zeros(len(t_s)), pos_enu_m=np.zeros_like(acc),
                     vel_enu_mps=np.zeros_like(acc), acc_enu_mps2=acc)
    return simulate_imu(kin, params, rng=rng)


def compare_imu_along_truth(real: Trace, params: ImuParams, cutoff_hz: float, *,
                            rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Apply the IMU error model ``params`` along a real trace's own truth and compare the IMU errors.

    The error of both sides is IMU minus the truth-derived acceleration (:func:`imu_error`). Returns
    per-axis error std (``std_real``, ``std_synth``), and on log10 Welch PSDs (8192-sample segments,
    0.2 Hz to 0.95 x Nyquist, masked samples zeroed) the correlation (``log_psd_corr``) and the
    log-spectral distance in dB (``lsd_db``).
    """
    tg, acc, valid = truth_acceleration(real.truth.t_s, real.truth.pos_enu_m, cutoff_hz=cutoff_hz)
    filled = np.stack([np.interp(tg, tg[valid], acc[valid, k]) for k in range(3)], axis=1)
    synth = Trace(truth=real.truth, uwb=real.uwb, anchors=real.anchors,
                  imu=simulate_imu_on(tg, filled, params, rng=rng))
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
