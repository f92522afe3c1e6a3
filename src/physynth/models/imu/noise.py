"""The IMU's noise processes: white noise, the bias random walk and the bias instability, on knots
resampled to the sample times.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...rng import standard_normal_rows
from .._filters import ar1 as _ar1

_BIAS_KNOT_S = 0.1  # bias random-walk knot spacing [s]


def white_noise(n: int, density_mps2_per_sqrt_hz: np.ndarray, rate_hz: float, *,
                rng: np.random.Generator) -> np.ndarray:
    """(n, 3) white noise with per-axis density [m s^-2 Hz^-1/2] sampled at ``rate_hz``."""
    return white_noise_cf(n, density_mps2_per_sqrt_hz, rate_hz, rng=rng).T


def white_noise_cf(n: int, density: np.ndarray, rate_hz: float, *, rng: np.random.Generator) -> np.ndarray:
    std = np.asarray(density, dtype=float) * np.sqrt(rate_hz)
    out = standard_normal_rows(rng, 3, n)
    out *= std[:, None]
    return out


def sample_times(t0_s: float, n: int, rate_hz: float) -> np.ndarray:
    """``t0_s + numpy.arange(n) / rate_hz``, bit for bit: a copy of the first n of :func:`_time_grid` (each
    k / rate_hz is the same division whatever the grid's length), t0 added only when non-zero (0 + x is
    x for the x >= +0 of ``arange(n) / rate_hz``, rate > 0)."""
    if n <= 0:
        return np.zeros(0)
    t = _time_grid(float(rate_hz), 1 << (n - 1).bit_length())[:n].copy()  # a copy: cheaper than the division
    if t0_s != 0.0:
        t += t0_s
    return t


@lru_cache(maxsize=8)
def _time_grid(rate_hz: float, n: int) -> np.ndarray:
    """``numpy.arange(n) / rate_hz`` (the integers made as floats: no int64 pass), read-only, kept for the
    next traces (n a power of two: a handful of lengths per rate)."""
    t = np.arange(n, dtype=np.float64)
    t /= rate_hz
    t.setflags(write=False)
    return t


def knots(t_s: np.ndarray, spacing_s: float) -> np.ndarray:
    """Uniform knots covering ``t_s``, spaced by a whole number of samples close to ``spacing_s``."""
    dt = t_s[1] - t_s[0] if t_s.shape[0] > 1 else spacing_s
    step = max(1, int(round(spacing_s / dt))) * dt
    n = int(np.ceil((t_s[-1] - t_s[0]) / step - 1e-9)) + 2
    return t_s[0] + np.arange(n) * step


def upsample_linear(values_cf: np.ndarray, factor: int) -> np.ndarray:
    """Linear interpolation of uniform samples (C, K) by an integer factor -> (C, (K-1)*factor).

    Output sample j sits at knot position j / factor; the last knot itself is not repeated. One
    matrix product: [value, slope] per knot interval times [1, r / factor] per phase r.
    """
    c, k = values_cf.shape
    lhs = np.empty((c, k - 1, 2), dtype=np.result_type(values_cf.dtype, float))
    lhs[:, :, 0] = values_cf[:, :-1]
    np.subtract(values_cf[:, 1:], values_cf[:, :-1], out=lhs[:, :, 1])
    return (lhs.reshape(-1, 2) @ _upsample_rhs(factor)).reshape(c, -1)


@lru_cache(maxsize=16)
def _upsample_rhs(factor: int) -> np.ndarray:
    """The (2, factor) right-hand side of :func:`upsample_linear`: [1, r / factor] per phase r (read-only)."""
    rhs = np.vstack([np.ones(factor), np.arange(factor) / factor])
    rhs.setflags(write=False)
    return rhs


def resample_cf(t_s: np.ndarray, knots_t: np.ndarray, values_cf: np.ndarray) -> np.ndarray:
    """Linear interpolation of (C, K) values on uniform knots to uniform times -> (C, N)."""
    if t_s.shape[0] > 1 and knots_t.shape[0] > 1:
        ratio = (knots_t[1] - knots_t[0]) / (t_s[1] - t_s[0])
        factor = int(round(ratio))
        if (factor >= 1 and abs(ratio - factor) < 1e-9 and abs(t_s[0] - knots_t[0]) < 1e-12
                and (knots_t.shape[0] - 1) * factor >= t_s.shape[0]):
            return upsample_linear(values_cf, factor)[:, : t_s.shape[0]]
    return np.stack([np.interp(t_s, knots_t, v) for v in values_cf])


def bias_random_walk(t_s: np.ndarray, sigma_mps2_per_sqrt_s: float, initial_std_mps2: float, *,
                     rng: np.random.Generator) -> np.ndarray:
    """(N, 3) bias random walk at uniform times ``t_s`` (knots every ~0.1 s, linear in between)."""
    return bias_cf(t_s, sigma_mps2_per_sqrt_s, initial_std_mps2, rng=rng).T


def bias_cf(t_s, sigma, initial_std, *, rng):
    knots_t = knots(t_s, _BIAS_KNOT_S)
    steps = rng.standard_normal((3, knots_t.shape[0]))
    steps *= sigma * np.sqrt(knots_t[1] - knots_t[0])  # in place: the same products
    steps[:, 0] = rng.standard_normal(3) * initial_std
    return resample_cf(t_s, knots_t, steps.cumsum(axis=1))


def bias_instability(t_s: np.ndarray, std: float, tau_s: float, *, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) first-order Gauss-Markov bias: stationary std ``std``, correlation time ``tau_s`` [s].

    Drawn on knots every ~0.1 s (exact AR(1) recursion) and linearly interpolated; its Allan deviation
    peaks near 0.66 ``std`` at tau about 1.9 ``tau_s`` (the usual stand-in for flicker bias instability).
    """
    return gauss_markov_cf(t_s, std, tau_s, rng=rng).T


def gauss_markov_cf(t_s, std, tau_s, *, rng):
    knots_t = knots(t_s, _BIAS_KNOT_S)
    rho = np.exp(-(knots_t[1] - knots_t[0]) / tau_s)
    e = rng.standard_normal((3, knots_t.shape[0])) * std
    e[:, 1:] *= np.sqrt(1.0 - rho * rho)
    return resample_cf(t_s, knots_t, _ar1(e, rho))
