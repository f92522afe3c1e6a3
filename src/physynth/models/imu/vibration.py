"""Vibration: narrow-band lines at a fundamental and its harmonics, modulated by the motion."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .._filters import ar1 as _ar1
from .noise import knots, resample_cf
from .params import GyroscopeParams, ImuParams, VibrationParams


@lru_cache(maxsize=32)
def _comb_phases(freq_h: tuple[float, ...], dt: float, r: int) -> np.ndarray:
    """The (4H, r) right-hand side of :func:`_comb`'s product: [Re R, Im R, Re R j/r, Im R j/r] with
    R_hj = exp(i 2 pi freq_h j dt), built once per (lines, step, knot spacing) and read-only."""
    freq = np.asarray(freq_h, dtype=float)
    rot = np.exp(1j * 2.0 * np.pi * freq[:, None] * (np.arange(r) * dt)[None, :])  # (H, r)
    frac = np.arange(r) / r
    rhs = np.concatenate([rot.real, rot.imag, rot.real * frac, rot.imag * frac], axis=0)
    rhs.setflags(write=False)
    return rhs


def _comb(t_s: np.ndarray, knots_t: np.ndarray, z_hak: np.ndarray, amp_h: np.ndarray, freq_h: np.ndarray,
          phase_h: np.ndarray) -> np.ndarray:
    """(A, N) sum over lines h of amp_h Re(z_h,a(t) exp(i (2 pi freq_h (t - t_0) + phase_h))), with the
    complex envelopes z (H, A, K) linearly interpolated from uniform knots (rows possibly strided: a view).

    On the usual aligned grid (knots every r samples from t_0, t = t_k + j dt) the carrier factorises
    as C_k R_j, so z(t) c(t) = (z_k C_k) R_j + (dz_k C_k) (j / r) R_j: one (A K, 4H) @ (4H, r) matrix
    product, with no trigonometry per sample. Otherwise the envelopes are interpolated in full.
    """
    h, a, k = z_hak.shape
    n = t_s.shape[0]
    dt = t_s[1] - t_s[0] if n > 1 else 0.0
    ratio = (knots_t[1] - knots_t[0]) / dt if n > 1 and k > 1 else 0.0
    r = int(round(ratio))
    if r >= 1 and abs(ratio - r) < 1e-9 and abs(t_s[0] - knots_t[0]) < 1e-12 and (k - 1) * r >= n:
        c_k = amp_h[:, None] * np.exp(1j * (2.0 * np.pi * freq_h[:, None] * (knots_t[None, :-1] - t_s[0])
                                            + phase_h[:, None]))  # (H, K-1)
        p = z_hak[:, :, :-1] * c_k[:, None, :]
        q = np.diff(z_hak, axis=2) * c_k[:, None, :]
        lhs = np.concatenate([p.real, -p.imag, q.real, -q.imag], axis=0)  # (4H, A, K-1)
        rhs = _comb_phases(tuple(freq_h.tolist()), float(dt), r)  # (4H, r), the same for every trace
        out = lhs.transpose(1, 2, 0).reshape(a * (k - 1), 4 * h) @ rhs
        return out.reshape(a, -1)[:, :n]  # rows of the product (no copy: the callers' next step makes one)
    z = resample_cf(t_s, knots_t, z_hak.real.reshape(h * a, k)) + 1j * resample_cf(
        t_s, knots_t, z_hak.imag.reshape(h * a, k))
    carrier = amp_h[:, None] * np.exp(1j * (2.0 * np.pi * freq_h[:, None] * (t_s - t_s[0]) + phase_h[:, None]))
    return np.einsum("han,hn->an", z.reshape(h, a, n), carrier).real


def vibration(t_s: np.ndarray, params: VibrationParams, *, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) narrow-band vibration at f0 and harmonics; RMS per axis ``amplitude_mps2``.

    ``t_s`` must be uniformly spaced; harmonics at or above its Nyquist frequency are left out.
    """
    return vibration_cf(t_s, params, rng=rng).T


def vibration_cf(t_s: np.ndarray, params: VibrationParams, *, rng: np.random.Generator) -> np.ndarray:
    n = t_s.shape[0]
    if params.amplitude_mps2 == 0 or n < 2:
        return np.zeros((3, n))
    env_t = knots(t_s, 1.0 / max(8.0 * params.bandwidth_hz, 2.0))  # knots well above the line width
    lines = _comb_lines(params.amplitude_mps2, params.fundamental_hz, tuple(params.harmonic_weights),
                        params.bandwidth_hz, float(t_s[1] - t_s[0]), float(env_t[1] - env_t[0]))
    if lines is None:
        return np.zeros((3, n))
    amp_h, freq_h, rho, n_h = lines
    # exact complex OU recursion z_k = rho z_{k-1} + sqrt(1 - rho^2) e_k, started in its stationary law
    innov = rng.standard_normal((2 * 3 * n_h, env_t.shape[0])) * np.sqrt(0.5)
    innov[:, 1:] *= np.sqrt(1.0 - rho**2)
    env = _ar1(innov, rho).reshape(n_h, 2, 3, -1)  # on the knots: (line, re/im, axis, knot)
    phase0 = rng.uniform(0.0, 2.0 * np.pi, n_h)
    out = _comb(t_s, env_t, env[:, 0] + 1j * env[:, 1], amp_h, freq_h, phase0)
    if any(g != 1.0 for g in params.axis_gain):
        out *= np.asarray(params.axis_gain, dtype=float)[:, None]
    return out


@lru_cache(maxsize=64)
def _comb_lines(amplitude_mps2: float, fundamental_hz: float, weights: tuple[float, ...], bandwidth_hz: float,
                dt: float, knot_step_s: float) -> tuple[np.ndarray, np.ndarray, np.float64, int] | None:
    """The comb's lines for samples ``dt`` apart and envelope knots ``knot_step_s`` apart: (amplitude and
    frequency of each line below the Nyquist frequency (read-only), the envelope's AR(1) factor rho,
    the number of lines), or None when no line is left. Built once per (vibration, time step), not per trace.
    """
    w = np.asarray(weights, dtype=float)
    if w.sum() == 0:
        return None
    nyquist = 0.5 / dt
    freqs = fundamental_hz * np.arange(1, w.size + 1)
    w = np.where(freqs < nyquist, w, 0.0)  # harmonics at or above the Nyquist frequency are left out
    if w.sum() == 0:
        return None
    amp = amplitude_mps2 * np.sqrt(2.0 * w / w.sum())  # Re(z e^{iwt}) has variance |z|^2 / 2
    rho = np.exp(-np.pi * bandwidth_hz * np.float64(knot_step_s))  # OU rate pi * bandwidth
    # linear interpolation between knots keeps on average a share 2/3 + rho/3 of the envelope variance:
    # scale it back so that the vibration RMS is amplitude_mps2
    amp = amp / np.sqrt(2.0 / 3.0 + rho / 3.0)
    harmonic = np.flatnonzero(w) + 1
    amp_h, freq_h = amp[harmonic - 1], harmonic * fundamental_hz
    amp_h.setflags(write=False)
    freq_h.setflags(write=False)
    return amp_h, freq_h, rho, int(np.count_nonzero(w))


def vibration_variance(acc_enu_mps2: np.ndarray, omega_body_radps: np.ndarray | None, params: ImuParams
                       ) -> np.ndarray:
    """(T, 3) vibration variance per axis [m^2 s^-4] at the motion's intensity (:class:`MotionNoiseParams`)."""
    vib, mot = params.vibration, params.motion_noise
    base = (vib.amplitude_mps2 * np.asarray(vib.axis_gain, dtype=float)) ** 2
    var = base[None, :] + np.abs(acc_enu_mps2) * np.asarray(mot.acc_var_gain_mps2)[None, :]
    if omega_body_radps is not None and any(mot.rate_var_gain_mps4_per_radps):
        w = np.nan_to_num(np.linalg.norm(omega_body_radps, axis=1))
        var = var + w[:, None] * np.asarray(mot.rate_var_gain_mps4_per_radps)[None, :]
    return var


def modulated_vibration_cf(t_s, acc_enu_mps2, omega_body_radps, params: ImuParams, *, rng):
    unit = params.vibration.model_copy(update={"amplitude_mps2": 1.0, "axis_gain": [1.0, 1.0, 1.0]})
    out = vibration_cf(t_s, unit, rng=rng)
    out *= np.sqrt(vibration_variance(acc_enu_mps2, omega_body_radps, params)).T
    return out


def gyro_vibration_variance(g: GyroscopeParams, omega_body_radps: np.ndarray, acc_norm: np.ndarray | None
                             ) -> np.ndarray | None:
    """The gyroscope comb's variance over time, (T,) or per body axis (T, 3) with the acceleration
    term; None when it does not follow the motion (then the constant amplitude applies)."""
    acc_gain = np.asarray(g.vibration_acc_var_gain_rad2_per_m, dtype=float)
    if g.vibration_rate_var_gain_radps <= 0 and not acc_gain.any():
        return None
    var = g.vibration_amplitude_radps**2 + g.vibration_rate_var_gain_radps * np.linalg.norm(omega_body_radps, axis=1)
    if acc_gain.any() and acc_norm is not None:
        var = var[:, None] + acc_norm[:, None] * acc_gain[None, :]
    return var
