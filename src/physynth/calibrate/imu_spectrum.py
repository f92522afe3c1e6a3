"""The IMU error's spectrum: the white-noise floor, the vibration lines (Lorentzian comb by non-negative
least squares) and the bias random walk (the long-tau end of the Allan deviation).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import nnls
from scipy.signal import welch

from ..evaluate.stats import allan_deviation
from ..scenario import VibrationParams
from ._base import CalibrationError, rounded, segments

WHITE_BAND = (0.6, 0.9)
"""Band of the error PSD, as fractions of the IMU Nyquist frequency, that gives the white noise."""

MAX_HARMONICS = 40

N_PEAK_CANDIDATES = 6
"""Strongest local maxima of the excess spectrum (more than 30 % apart in frequency) tried as vibration
fundamentals, with their halves and thirds."""


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


def fit_vibration(f: np.ndarray, excess: np.ndarray, total: np.ndarray, floor: float, n_avg: int, f_lo: float,
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


def fit_bias_walk(errs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], fs: float, density: np.ndarray,
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


def error_spectrum_white_floor(errs: list, fs: float, fc: float, nperseg_s: float) -> tuple:
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


def vibration_params(vib: dict[str, Any] | None, density: np.ndarray, fs: float, err_std: np.ndarray,
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
