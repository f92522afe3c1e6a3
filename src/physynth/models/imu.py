"""IMU model: ideal acceleration from the kinematics, then bias random walk and vibration, then
white noise. Output in the ENU world frame with gravity removed (the paper's convention).

Error terms, each a pure function of (times, params, rng) and separately testable:

- white noise: per-axis density sigma_w [m s^-2 Hz^-1/2]; per-sample standard deviation
  sigma_w * sqrt(rate_hz), so the mean over a 10 ms grid bin has standard deviation sigma_w * 10
  (why the paper's Table I reads 1.61 for sigma_w = 0.161);
- bias random walk: b(t) = b0 + sigma_b * W(t), W a standard Wiener process (Var b = sigma_b^2 t);
- vibration: narrow-band noise at f0 and its harmonics, x_h(t) = Re(z_h(t) exp(i 2 pi h f0 t)) with
  a complex Ornstein-Uhlenbeck envelope z_h whose rate pi * bandwidth gives each spectral line a
  Lorentzian -3 dB width of ``bandwidth_hz``.

Slow terms (kinematics, bias, vibration) are built at the truth rate and linearly interpolated to the
IMU rate; only the white noise is drawn per IMU sample.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from ..records import Imu
from ._params import NonNegFloat, ParamsModel, PositiveFloat, Vec3
from .motion import Kinematics


class VibrationParams(ParamsModel):
    """Band-limited vibration: narrow-band noise at ``fundamental_hz`` and harmonics.

    ``amplitude_mps2`` is the RMS per axis of the whole vibration, times ``axis_gain`` (E, N, U) where
    the axes vibrate unequally; ``harmonic_weights`` split its variance between the fundamental and
    its harmonics; ``bandwidth_hz`` is the -3 dB width of
    each spectral line.
    """

    fundamental_hz: PositiveFloat = 2.8
    amplitude_mps2: NonNegFloat = 0.12
    harmonic_weights: list[NonNegFloat] = Field(default=[1.0, 0.5, 0.25], min_length=1)
    bandwidth_hz: PositiveFloat = 0.3
    axis_gain: Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)] = [1.0, 1.0, 1.0]


class ImuParams(ParamsModel):
    """Accelerometer in ENU, gravity-free [m s^-2].

    White noise of density ``white_noise_density_mps2_per_sqrt_hz`` per axis (per-sample standard
    deviation density * sqrt(rate_hz)); bias random walk whose standard deviation grows as
    ``bias_rw_mps2_per_sqrt_s`` * sqrt(t); vibration as above.
    """

    rate_hz: PositiveFloat = 400.0
    white_noise_density_mps2_per_sqrt_hz: Vec3 = [0.161, 0.086, 0.106]
    bias_rw_mps2_per_sqrt_s: NonNegFloat = 0.002
    bias_initial_std_mps2: NonNegFloat = 0.0
    vibration: VibrationParams = VibrationParams()


_BIAS_KNOT_S = 0.1  # bias random-walk knot spacing [s]


def white_noise(n: int, density_mps2_per_sqrt_hz: np.ndarray, rate_hz: float, *,
                rng: np.random.Generator) -> np.ndarray:
    """(n, 3) white noise with per-axis density [m s^-2 Hz^-1/2] sampled at ``rate_hz``."""
    return _white_noise_cf(n, density_mps2_per_sqrt_hz, rate_hz, rng=rng).T


def _white_noise_cf(n: int, density: np.ndarray, rate_hz: float, *, rng: np.random.Generator) -> np.ndarray:
    std = np.asarray(density, dtype=float) * np.sqrt(rate_hz)
    out = rng.standard_normal((3, n))
    out *= std[:, None]
    return out


def _knots(t_s: np.ndarray, spacing_s: float) -> np.ndarray:
    """Uniform knots covering ``t_s``, spaced by a whole number of samples close to ``spacing_s``."""
    dt = t_s[1] - t_s[0] if t_s.shape[0] > 1 else spacing_s
    step = max(1, int(round(spacing_s / dt))) * dt
    n = int(np.ceil((t_s[-1] - t_s[0]) / step - 1e-9)) + 2
    return t_s[0] + np.arange(n) * step


def upsample_linear(values_cf: np.ndarray, factor: int) -> np.ndarray:
    """Linear interpolation of uniform samples (C, K) by an integer factor -> (C, (K-1)*factor).

    Output sample j sits at knot position j / factor; the last knot itself is not repeated.
    """
    c, k = values_cf.shape
    inner = np.empty((c, k - 1, factor), dtype=values_cf.dtype)  # contiguous: fast broadcasting
    np.multiply(np.diff(values_cf, axis=1)[:, :, None], np.arange(factor) / factor, out=inner)
    inner += values_cf[:, :-1, None]
    return inner.reshape(c, -1)


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
    return _bias_cf(t_s, sigma_mps2_per_sqrt_s, initial_std_mps2, rng=rng).T


def _bias_cf(t_s, sigma, initial_std, *, rng):
    knots_t = _knots(t_s, _BIAS_KNOT_S)
    steps = rng.standard_normal((3, knots_t.shape[0])) * (sigma * np.sqrt(knots_t[1] - knots_t[0]))
    steps[:, 0] = rng.standard_normal(3) * initial_std
    return resample_cf(t_s, knots_t, np.cumsum(steps, axis=1))


def _ar1(x_ck: np.ndarray, rho: float) -> np.ndarray:
    """y_k = x_k + rho y_(k-1) along the last axis (what scipy.signal.lfilter([1], [1, -rho]) computes,
    with the same rounding), without importing scipy.signal (0.9 s) on every command."""
    y = np.empty_like(x_ck)
    prev = np.zeros(x_ck.shape[0])
    for k in range(x_ck.shape[1]):  # a few hundred knots per trace, vectorised over components
        prev = x_ck[:, k] + rho * prev
        y[:, k] = prev
    return y


def vibration(t_s: np.ndarray, params: VibrationParams, *, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) narrow-band vibration at f0 and harmonics; RMS per axis ``amplitude_mps2``.

    ``t_s`` must be uniformly spaced; harmonics at or above its Nyquist frequency are left out.
    """
    return _vibration_cf(t_s, params, rng=rng).T


def _vibration_cf(t_s: np.ndarray, params: VibrationParams, *, rng: np.random.Generator) -> np.ndarray:
    n = t_s.shape[0]
    w = np.asarray(params.harmonic_weights, dtype=float)
    if params.amplitude_mps2 == 0 or n < 2 or w.sum() == 0:
        return np.zeros((3, n))
    nyquist = 0.5 / (t_s[1] - t_s[0])
    freqs = params.fundamental_hz * np.arange(1, w.size + 1)
    w = np.where(freqs < nyquist, w, 0.0)
    if w.sum() == 0:
        return np.zeros((3, n))
    amp = params.amplitude_mps2 * np.sqrt(2.0 * w / w.sum())  # Re(z e^{iwt}) has variance |z|^2 / 2
    n_h = int(np.count_nonzero(w))
    env_t = _knots(t_s, 1.0 / max(8.0 * params.bandwidth_hz, 2.0))  # knots well above the line width
    rho = np.exp(-np.pi * params.bandwidth_hz * (env_t[1] - env_t[0]))  # OU rate pi * bandwidth
    # linear interpolation between knots keeps on average a share 2/3 + rho/3 of the envelope variance:
    # scale it back so that the vibration RMS is amplitude_mps2
    amp = amp / np.sqrt(2.0 / 3.0 + rho / 3.0)
    # exact complex OU recursion z_k = rho z_{k-1} + sqrt(1 - rho^2) e_k, started in its stationary law
    innov = rng.standard_normal((2 * 3 * n_h, env_t.shape[0])) * np.sqrt(0.5)
    innov[:, 1:] *= np.sqrt(1.0 - rho**2)
    env = resample_cf(t_s, env_t, _ar1(innov, rho))  # (2*3*H, N): re, im
    phase0 = rng.uniform(0.0, 2.0 * np.pi, n_h)
    out = np.zeros((3, n))
    base = np.exp(1j * 2.0 * np.pi * params.fundamental_hz * (t_s - t_s[0]))  # harmonics by powers
    carrier = np.ones(n, dtype=complex)
    j = 0
    for h in range(w.size):  # a handful of spectral lines, vectorised over time
        carrier = carrier * base
        if w[h] == 0:
            continue
        c = carrier * np.exp(1j * phase0[j])
        re, im = env[6 * j:6 * j + 3], env[6 * j + 3:6 * j + 6]
        out += amp[h] * (re * c.real - im * c.imag)
        j += 1
    gain = np.asarray(params.axis_gain, dtype=float)
    if np.any(gain != 1.0):
        out *= gain[:, None]
    return out


def simulate_imu(kin: Kinematics, params: ImuParams, *, rng: np.random.Generator) -> Imu:
    """IMU samples at ``params.rate_hz`` over the kinematics' time span (ENU, gravity-free)."""
    slow = np.ascontiguousarray(kin.acc_enu_mps2.T)
    slow += _vibration_cf(kin.t_s, params.vibration, rng=rng)
    slow += _bias_cf(kin.t_s, params.bias_rw_mps2_per_sqrt_s, params.bias_initial_std_mps2, rng=rng)
    # IMU samples cover [t0, t_end) of the truth; the last truth instant itself has no IMU sample
    n_imu = int(np.ceil((kin.t_s[-1] - kin.t_s[0]) * params.rate_hz - 1e-9))
    t_imu = kin.t_s[0] + np.arange(n_imu) / params.rate_hz
    acc = _white_noise_cf(t_imu.shape[0], np.asarray(params.white_noise_density_mps2_per_sqrt_hz),
                          params.rate_hz, rng=rng)
    ratio = (kin.t_s[1] - kin.t_s[0]) * params.rate_hz if kin.t_s.shape[0] > 1 else 0.0
    factor = int(round(ratio))
    if factor >= 1 and abs(ratio - factor) < 1e-9 and n_imu == (kin.t_s.shape[0] - 1) * factor:
        # the usual case: add the linear upsampling straight into the noise, one phase at a time
        view = acc.reshape(3, -1, factor)
        base, step = slow[:, :-1], np.diff(slow, axis=1)
        for r in range(factor):
            view[:, :, r] += base + step * (r / factor)
    else:
        acc += resample_cf(t_imu, kin.t_s, slow)
    return Imu(t_s=t_imu, acc_mps2=acc.T)
