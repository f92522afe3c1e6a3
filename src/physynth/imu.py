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

import numpy as np
from scipy.signal import lfilter

from .motion import Kinematics
from .records import Imu
from .scenario import ImuParams, VibrationParams

_BIAS_KNOT_S = 0.1  # bias random-walk knot spacing [s]


def white_noise(n: int, density_mps2_per_sqrt_hz: np.ndarray, rate_hz: float, *,
                rng: np.random.Generator) -> np.ndarray:
    """(n, 3) white noise with per-axis density [m s^-2 Hz^-1/2] sampled at ``rate_hz``."""
    std = np.asarray(density_mps2_per_sqrt_hz, dtype=float) * np.sqrt(rate_hz)
    return rng.standard_normal((n, 3)) * std


def bias_random_walk(t_s: np.ndarray, sigma_mps2_per_sqrt_s: float, initial_std_mps2: float, *,
                     rng: np.random.Generator) -> np.ndarray:
    """(N, 3) bias random walk at times ``t_s`` (knots every 0.1 s, linear in between)."""
    t0, t1 = float(t_s[0]), float(t_s[-1])
    n_knots = int(np.ceil((t1 - t0) / _BIAS_KNOT_S)) + 2
    knots_t = t0 + np.arange(n_knots) * _BIAS_KNOT_S
    steps = rng.standard_normal((n_knots, 3)) * (sigma_mps2_per_sqrt_s * np.sqrt(_BIAS_KNOT_S))
    steps[0] = rng.standard_normal(3) * initial_std_mps2
    walk = np.cumsum(steps, axis=0)
    return _interp_rows(t_s, knots_t, walk)


def _interp_rows(t: np.ndarray, tk: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of (K, C) values from uniform knots ``tk`` to times ``t`` -> (N, C)."""
    dt = tk[1] - tk[0]
    x = (t - tk[0]) / dt
    i = np.clip(x.astype(np.int64), 0, len(tk) - 2)
    f = (x - i)[:, None]
    return values[i] * (1.0 - f) + values[i + 1] * f


def vibration(t_s: np.ndarray, params: VibrationParams, axis_gain: np.ndarray | None = None, *,
              rng: np.random.Generator) -> np.ndarray:
    """(N, 3) narrow-band vibration at f0 and harmonics; RMS per axis ``amplitude_mps2``.

    ``t_s`` must be uniformly spaced with a rate above twice the highest harmonic.
    """
    n = t_s.shape[0]
    w = np.asarray(params.harmonic_weights, dtype=float)
    if params.amplitude_mps2 == 0 or n < 2 or w.sum() == 0:
        return np.zeros((n, 3))
    harmonics = np.arange(1, w.size + 1)
    amp = params.amplitude_mps2 * np.sqrt(2.0 * w / w.sum())  # Re(z e^{iwt}) has variance |z|^2 / 2
    lam = np.pi * params.bandwidth_hz  # OU rate [1/s]
    env_rate = max(8.0 * params.bandwidth_hz, 2.0)  # envelope knots [Hz], well above its bandwidth
    dt_env = 1.0 / env_rate
    n_env = int(np.ceil((t_s[-1] - t_s[0]) / dt_env)) + 2
    rho = np.exp(-lam * dt_env)
    innov = (rng.standard_normal((n_env, w.size * 3)) + 1j * rng.standard_normal((n_env, w.size * 3)))
    innov *= np.sqrt(0.5)
    # exact OU recursion z_k = rho z_{k-1} + sqrt(1 - rho^2) e_k, started in its stationary law
    scaled = innov * np.sqrt(1.0 - rho**2)
    scaled[0] = innov[0]
    z = lfilter([1.0], [1.0, -rho], scaled, axis=0)
    env = _interp_rows(t_s, t_s[0] + np.arange(n_env) * dt_env, z)  # (N, H*3)
    phase = np.exp(1j * (2.0 * np.pi * params.fundamental_hz * (t_s - t_s[0]) + rng.uniform(0, 2 * np.pi)))
    carrier = np.ones(n, dtype=complex)
    out = np.zeros((n, 3))
    for h in range(w.size):  # a handful of harmonics, vectorised over time
        carrier = carrier * phase
        if amp[h] == 0 or harmonics[h] * params.fundamental_hz * 2.0 >= 1.0 / (t_s[1] - t_s[0]):
            continue
        out += amp[h] * (env[:, 3 * h:3 * h + 3] * carrier[:, None]).real
    if axis_gain is not None:
        out *= axis_gain
    return out


def simulate_imu(kin: Kinematics, params: ImuParams, *, rng: np.random.Generator) -> Imu:
    """IMU samples at ``params.rate_hz`` over the kinematics' time span (ENU, gravity-free)."""
    slow = kin.acc_enu_mps2.copy()
    slow += vibration(kin.t_s, params.vibration, rng=rng)
    slow += bias_random_walk(kin.t_s, params.bias_rw_mps2_per_sqrt_s, params.bias_initial_std_mps2, rng=rng)
    t_imu = np.arange(int(np.floor(kin.t_s[-1] * params.rate_hz)) + 1) / params.rate_hz + kin.t_s[0]
    acc = _interp_rows(t_imu, kin.t_s, slow)
    acc += white_noise(t_imu.shape[0], np.asarray(params.white_noise_density_mps2_per_sqrt_hz),
                       params.rate_hz, rng=rng)
    return Imu(t_s=t_imu, acc_mps2=acc)
