"""Statistics written once: Allan deviation, two-sample KS, Wasserstein-1 and Anderson-Darling.

Calibration (IMU noise from the Allan deviation), validation (distances between real and synthetic
residuals) and the section-5 metrics all call these; none has a private copy.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np


def overlapping_allan_variance_sums(y: np.ndarray, m: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Sums of squared second differences of the overlapping Allan variance, for pooling.

    Parameters
    ----------
    y : (N,) or (N, C) array
        Uniformly sampled signal (e.g. acceleration [m s^-2]); must be finite.
    m : (M,) int array
        Averaging factors; tau = m / rate_hz [s].
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    sums : (C, M) array
        sum_k (x_{k+2m} - 2 x_{k+m} + x_k)^2 / (2 tau^2), with the phase x = [0, cumsum(y)] / rate_hz.
    counts : (M,) int array
        Number of terms, N - 2m + 1 (0 when the signal is too short).

    The overlapping Allan variance is ``sums / counts``; adding sums and counts of several traces
    pools them.
    """
    y2 = np.asarray(y, dtype=np.float64)
    y2 = y2[:, None] if y2.ndim == 1 else y2
    n = y2.shape[0]
    dt = 1.0 / rate_hz
    x = np.concatenate([np.zeros((1, y2.shape[1])), np.cumsum(y2, axis=0) * dt])  # (N+1, C)
    m = np.asarray(m, dtype=np.int64)
    sums = np.zeros((y2.shape[1], m.size))
    counts = np.maximum(n - 2 * m + 1, 0)
    for j, mj in enumerate(m):  # one vectorised pass per averaging time
        if counts[j] == 0:
            continue
        d = x[2 * mj:] - 2.0 * x[mj:n + 1 - mj] + x[:n + 1 - 2 * mj]
        tau = mj * dt
        sums[:, j] = np.einsum("kc,kc->c", d, d) / (2.0 * tau * tau)
    return sums, counts


def allan_deviation(y: np.ndarray, rate_hz: float, tau_s: Sequence[float] | np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of a uniformly sampled signal.

    Parameters
    ----------
    y : (N,) or (N, C) array
        Signal, e.g. acceleration [m s^-2] at ``rate_hz``.
    rate_hz : float
        Sample rate [Hz].
    tau_s : sequence of float
        Averaging times [s]; each is rounded to a whole number of samples (at least 1).

    Returns
    -------
    (C, M) array (or (M,) for a 1-D ``y``)
        sigma(tau) in the unit of ``y``; NaN where the signal is shorter than 2 tau.

    .. math:: \\sigma^2(\\tau) = \\frac{1}{2\\tau^2 (N - 2m + 1)} \\sum_k (x_{k+2m} - 2x_{k+m} + x_k)^2

    with ``x`` the running integral of ``y`` and tau = m / rate. White noise of per-sample standard
    deviation s gives sigma(tau) = s / sqrt(m); a random walk of increment density K gives
    K sqrt(tau / 3).
    """
    m = np.maximum(np.round(np.asarray(tau_s, dtype=float) * rate_hz).astype(np.int64), 1)
    sums, counts = overlapping_allan_variance_sums(y, m, rate_hz)
    with np.errstate(invalid="ignore", divide="ignore"):
        adev = np.sqrt(sums / np.where(counts > 0, counts, np.nan))
    return adev[0] if np.ndim(y) == 1 else adev


def ks_statistic(real_residual_m: np.ndarray, synth_residual_m: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov statistic between pooled signed residuals (scipy.stats.ks_2samp)."""
    real_residual_m = np.asarray(real_residual_m, dtype=float)
    synth_residual_m = np.asarray(synth_residual_m, dtype=float)
    if real_residual_m.size == 0 or synth_residual_m.size == 0:
        return float("nan")
    from scipy import stats  # imported where used (slow to import)

    # only the statistic is used: the asymptotic p-value costs nothing, where the exact one can fail on
    # small samples with a RuntimeWarning on stderr (the statistic is the same, to rounding)
    return float(stats.ks_2samp(real_residual_m, synth_residual_m, method="asymp").statistic)


def wasserstein(a: np.ndarray, b: np.ndarray) -> float:
    """First Wasserstein distance between two samples (scipy.stats.wasserstein_distance); NaN if one is empty."""
    if a.size == 0 or b.size == 0:
        return float("nan")
    from scipy import stats  # imported where used (slow to import)

    return float(stats.wasserstein_distance(a, b))


def anderson_darling(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(statistic, tabulated p-value) of scipy's k-sample Anderson-Darling test (midrank variant)."""
    if a.size < 2 or b.size < 2 or np.unique(np.concatenate([a, b])).size < 2:
        return float("nan"), float("nan")
    from scipy import stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "p-value capped/floored" and the 1.17 `midrank` deprecation
        try:
            res = stats.anderson_ksamp([a, b], variant="midrank")
        except TypeError:  # scipy < 1.17 has no `variant`; midrank is its default
            res = stats.anderson_ksamp([a, b])
    return float(res.statistic), float(res.pvalue)
