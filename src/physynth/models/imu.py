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

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from pydantic import Field, model_validator

from ..constants import G0_MPS2
from ..records import Imu
from ..rng import standard_normal_rows
from ._filters import ar1 as _ar1
from ._params import NonNegFloat, ParamsModel, PositiveFloat, Vec3
from .motion import Kinematics

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


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


class MotionNoiseParams(ParamsModel):
    """Vibration whose power grows with the motion's intensity (unresolved motion, a cabin's rollers).

    With either gain non-zero, the vibration comb's variance on axis k at time t is
    ``(amplitude_mps2 * axis_gain_k)^2 + acc_var_gain_k * |a_k(t)| + rate_var_gain_k * |w(t)|``
    [m^2 s^-4], with a_k the truth acceleration along axis k [m s^-2] and |w| the body angular rate
    magnitude [rad/s]: ``acc_var_gain_mps2`` in m^2 s^-4 per m s^-2, ``rate_var_gain_mps4_per_radps``
    in m^2 s^-4 per rad s^-1. The spectral shape (lines, widths) stays the comb's. Zero (the default)
    switches the term off.
    """

    acc_var_gain_mps2: Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    rate_var_gain_mps4_per_radps: Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]

    @property
    def active(self) -> bool:
        return any(self.acc_var_gain_mps2) or any(self.rate_var_gain_mps4_per_radps)


class ImuParams(ParamsModel):
    """Accelerometer in ENU, gravity-free [m s^-2].

    White noise of density ``white_noise_density_mps2_per_sqrt_hz`` per axis (per-sample standard
    deviation density * sqrt(rate_hz)); bias random walk whose standard deviation grows as
    ``bias_rw_mps2_per_sqrt_s`` * sqrt(t); vibration as above; ``time_offset_s``: the IMU clock lags
    the truth, sample t reads the acceleration at t - offset [s]; ``motion_noise``: white noise
    the vibration's power growing with the motion (:class:`MotionNoiseParams`); ``lever_arm_m``: the
    sensor's position in the body frame relative to the truth's reference point [m], so that it also
    reads the rotational acceleration R (alpha x r + w x (w x r)) (:func:`lever_arm_acceleration`;
    needs the truth attitude, zero by default); ``truth_cutoff_hz``: the bandwidth of the truth
    acceleration the noise terms were calibrated against [Hz] (:func:`physynth.calibrate.imu_fit.fit_imu`).
    Run along a recorded truth (``physynth validate --transfer`` on an IMU recording), the model reads
    that truth low-passed there (10 Hz when unset); generation from a scenario's own kinematics ignores it.
    """

    rate_hz: PositiveFloat = 400.0
    white_noise_density_mps2_per_sqrt_hz: Vec3 = [0.161, 0.086, 0.106]
    bias_rw_mps2_per_sqrt_s: NonNegFloat = 0.002
    bias_initial_std_mps2: NonNegFloat = 0.0
    vibration: VibrationParams = VibrationParams()
    time_offset_s: Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)] = 0.0
    motion_noise: MotionNoiseParams = MotionNoiseParams()
    lever_arm_m: Vec3 = [0.0, 0.0, 0.0]
    truth_cutoff_hz: PositiveFloat | None = None


_BIAS_KNOT_S = 0.1  # bias random-walk knot spacing [s]


def white_noise(n: int, density_mps2_per_sqrt_hz: np.ndarray, rate_hz: float, *,
                rng: np.random.Generator) -> np.ndarray:
    """(n, 3) white noise with per-axis density [m s^-2 Hz^-1/2] sampled at ``rate_hz``."""
    return _white_noise_cf(n, density_mps2_per_sqrt_hz, rate_hz, rng=rng).T


def _white_noise_cf(n: int, density: np.ndarray, rate_hz: float, *, rng: np.random.Generator) -> np.ndarray:
    std = np.asarray(density, dtype=float) * np.sqrt(rate_hz)
    out = standard_normal_rows(rng, 3, n)
    out *= std[:, None]
    return out


def _sample_times(t0_s: float, n: int, rate_hz: float) -> np.ndarray:
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


def _knots(t_s: np.ndarray, spacing_s: float) -> np.ndarray:
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
    return _bias_cf(t_s, sigma_mps2_per_sqrt_s, initial_std_mps2, rng=rng).T


def _bias_cf(t_s, sigma, initial_std, *, rng):
    knots_t = _knots(t_s, _BIAS_KNOT_S)
    steps = rng.standard_normal((3, knots_t.shape[0]))
    steps *= sigma * np.sqrt(knots_t[1] - knots_t[0])  # in place: the same products
    steps[:, 0] = rng.standard_normal(3) * initial_std
    return resample_cf(t_s, knots_t, steps.cumsum(axis=1))


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
    return _vibration_cf(t_s, params, rng=rng).T


def _vibration_cf(t_s: np.ndarray, params: VibrationParams, *, rng: np.random.Generator) -> np.ndarray:
    n = t_s.shape[0]
    if params.amplitude_mps2 == 0 or n < 2:
        return np.zeros((3, n))
    env_t = _knots(t_s, 1.0 / max(8.0 * params.bandwidth_hz, 2.0))  # knots well above the line width
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


def simulate_imu(kin: Kinematics, params: ImuParams, *, rng: np.random.Generator,
                 omega_body_radps: np.ndarray | None = None, attitude: Rotation | None = None) -> Imu:
    """IMU samples at ``params.rate_hz`` over the kinematics' time span (ENU, gravity-free).

    ``omega_body_radps`` (T, 3): the body angular rate at the truth times, used by the rate-dependent
    vibration power (zero when None) and with ``attitude`` (T rotations body -> ENU) by the lever arm
    (:func:`lever_arm_acceleration`; ignored without both). The modulated vibration makes the same draws
    as the plain one, so the other terms' samples do not change when it is switched on.
    """
    acc_in = _with_lever_arm(kin, params, omega_body_radps, attitude)
    if params.motion_noise.active:  # a new (3, T) array either way
        vib = _modulated_vibration_cf(kin.t_s, kin.acc_enu_mps2, omega_body_radps, params, rng=rng)
    else:
        vib = _vibration_cf(kin.t_s, params.vibration, rng=rng)
    if params.time_offset_s != 0.0:  # the sensor reads the motion at t - offset
        slow = np.stack([np.interp(kin.t_s - params.time_offset_s, kin.t_s, acc_in[:, k]) for k in range(3)])
        slow += vib
    else:  # acceleration + vibration, into the vibration's array (the model never writes into its inputs)
        slow = np.add(acc_in.T, vib, out=vib)
    slow += _bias_cf(kin.t_s, params.bias_rw_mps2_per_sqrt_s, params.bias_initial_std_mps2, rng=rng)
    # IMU samples cover [t0, t_end) of the truth; the last truth instant itself has no IMU sample
    n_imu = int(np.ceil((kin.t_s[-1] - kin.t_s[0]) * params.rate_hz - 1e-9))
    t_imu = _sample_times(kin.t_s[0], n_imu, params.rate_hz)
    acc = _white_noise_cf(t_imu.shape[0], np.asarray(params.white_noise_density_mps2_per_sqrt_hz),
                          params.rate_hz, rng=rng)
    ratio = (kin.t_s[1] - kin.t_s[0]) * params.rate_hz if kin.t_s.shape[0] > 1 else 0.0
    factor = int(round(ratio))
    if factor >= 1 and abs(ratio - factor) < 1e-9 and n_imu == (kin.t_s.shape[0] - 1) * factor:
        # the usual case: the slow terms upsampled by an integer factor (one matrix product)
        acc += upsample_linear(slow, factor)
    else:
        acc += resample_cf(t_imu, kin.t_s, slow)
    return Imu(t_s=t_imu, acc_mps2=acc.T)


def lever_arm_acceleration(t_s: np.ndarray, attitude: Rotation, omega_body_radps: np.ndarray,
                           lever_arm_m: np.ndarray) -> np.ndarray:
    """(T, 3) ENU acceleration [m s^-2] a sensor at ``lever_arm_m`` (body frame [m]) adds to the reference point's.

    R (alpha x r + w x (w x r)) with w the body rate (T, 3) at the times ``t_s`` [rad/s], alpha = dw/dt
    its derivative (central differences on ``t_s``) and R the attitude (body -> ENU). NaN rates count
    as zero. :func:`simulate_imu` first moves the truth's step rates (row k over [t_k, t_{k+1})) to the
    sample times.
    """
    w = np.nan_to_num(np.asarray(omega_body_radps, dtype=float))
    r = np.asarray(lever_arm_m, dtype=float)
    alpha = np.gradient(w, t_s, axis=0) if w.shape[0] > 1 else np.zeros_like(w)
    return attitude.apply(np.cross(alpha, r) + np.cross(w, np.cross(w, r)))


def _with_lever_arm(kin: Kinematics, params: ImuParams, omega_body_radps, attitude) -> np.ndarray:
    return _sensor_point_acc(kin.t_s, kin.acc_enu_mps2, attitude, omega_body_radps, params.lever_arm_m)


def _sensor_point_acc(t_s, acc_enu_mps2, attitude, omega_body_radps, lever_arm_m) -> np.ndarray:
    """The acceleration (T, 3) of the point at ``lever_arm_m``; the input itself when it is zero or
    the attitude or rates are missing."""
    acc = np.asarray(acc_enu_mps2)
    if attitude is None or omega_body_radps is None or not any(lever_arm_m):
        return acc
    # the truth's rates hold over [t_k, t_{k+1}): the rate at t_k is the mean of rows k-1 and k
    w = np.nan_to_num(np.asarray(omega_body_radps, dtype=float))
    w_at = 0.5 * (w + np.concatenate([w[:1], w[:-1]]))
    return acc + lever_arm_acceleration(np.asarray(t_s, dtype=float), attitude, w_at, lever_arm_m)


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


def _modulated_vibration_cf(t_s, acc_enu_mps2, omega_body_radps, params: ImuParams, *, rng):
    unit = params.vibration.model_copy(update={"amplitude_mps2": 1.0, "axis_gain": [1.0, 1.0, 1.0]})
    out = _vibration_cf(t_s, unit, rng=rng)
    out *= np.sqrt(vibration_variance(acc_enu_mps2, omega_body_radps, params)).T
    return out


# ---------------------------------------------------------------- body-frame IMU (strapdown sensor)
class AccelerometerParams(ParamsModel):
    """Accelerometer triad errors (body frame, specific force) [m s^-2 based units].

    Defaults are those of a MEMS IMU (ADIS16448 as in the EuRoC Kalibr ``imu.yaml``). The vibration
    comb's variance per axis is ``vibration_amplitude_mps2^2 + vibration_acc_var_gain_mps2 * |a(t)| +
    vibration_rate_var_gain_mps4_per_radps * |w(t)|`` (|a| the truth acceleration magnitude, |w| the
    body rate magnitude), as in :class:`MotionNoiseParams`.
    """

    noise_density_mps2_per_sqrt_hz: NonNegFloat = 1.86e-3
    bias_rw_mps2_per_sqrt_s: NonNegFloat = 4.33e-4
    bias_instability_mps2: NonNegFloat = 0.0
    bias_instability_tau_s: PositiveFloat = 100.0
    turn_on_bias_std_mps2: NonNegFloat = 0.0
    scale_factor_std: NonNegFloat = 0.0
    misalignment_std_rad: NonNegFloat = 0.0
    quantisation_mps2: NonNegFloat = 0.0
    vibration_amplitude_mps2: NonNegFloat = 0.0
    vibration_acc_var_gain_mps2: NonNegFloat = 0.0
    vibration_rate_var_gain_mps4_per_radps: NonNegFloat = 0.0


class GyroscopeParams(ParamsModel):
    """Gyroscope triad errors (body frame, angular rate) [rad s^-1 based units].

    The vibration comb's variance on body axis k is ``vibration_amplitude_radps^2 +
    vibration_rate_var_gain_radps * |w(t)| + vibration_acc_var_gain_rad2_per_m[k] * |a(t)|``
    [rad^2 s^-2] (|w| the body rate magnitude [rad/s], |a| the truth acceleration magnitude [m/s^2]).
    The acceleration term is the rotation a shaken sensor makes faster than the truth resolves (a
    hand-held device, a vehicle on rough ground): on the shared BROAD trials the gyroscope's error grows
    with |a|, not with |w| (docs/imu.md).
    """

    noise_density_radps_per_sqrt_hz: NonNegFloat = 1.87e-4
    bias_rw_radps_per_sqrt_s: NonNegFloat = 2.66e-5
    bias_instability_radps: NonNegFloat = 0.0
    bias_instability_tau_s: PositiveFloat = 100.0
    turn_on_bias_std_radps: NonNegFloat = 0.0
    scale_factor_std: NonNegFloat = 0.0
    misalignment_std_rad: NonNegFloat = 0.0
    quantisation_radps: NonNegFloat = 0.0
    vibration_amplitude_radps: NonNegFloat = 0.0
    vibration_rate_var_gain_radps: NonNegFloat = 0.0
    vibration_acc_var_gain_rad2_per_m: Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    g_sensitivity_radps_per_mps2: NonNegFloat = 0.0


KALIBR_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
               "gyroscope_random_walk", "update_rate")


class BodyImuParams(ParamsModel):
    """A strapdown IMU: accelerometer and gyroscope in the body frame (FLU), sampled at ``rate_hz``.

    ``time_offset_s``: the sensor's clock lags the truth, sample t reads the motion at t - offset.
    ``lever_arm_m``: the sensor's position in the body frame [m]; it reads the specific force of that
    point, alpha x r + w x (w x r) more than the truth's reference point (zero by default).
    ``vibration``: the spectral comb (lines, widths, axis gains) shared by both sensors; its amplitude
    is ignored here: the accelerometer's and gyroscope's ``vibration_amplitude_*`` set the RMS per
    axis. The Kalibr ``imu.yaml`` keys (``accelerometer_noise_density`` ...) are accepted in place of
    the fields they name (:func:`kalibr_to_body_imu`).
    """

    rate_hz: PositiveFloat = 400.0
    accelerometer: AccelerometerParams = AccelerometerParams()
    gyroscope: GyroscopeParams = GyroscopeParams()
    time_offset_s: Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)] = 0.0
    vibration: VibrationParams = VibrationParams(amplitude_mps2=0.0)
    lever_arm_m: Vec3 = [0.0, 0.0, 0.0]

    @model_validator(mode="before")
    @classmethod
    def _from_kalibr(cls, data: Any) -> Any:
        if isinstance(data, dict) and any(k in data for k in KALIBR_KEYS):
            return kalibr_to_body_imu(data)
        return data


def kalibr_to_body_imu(data: dict[str, Any]) -> dict[str, Any]:
    """Map a Kalibr ``imu.yaml`` mapping (plus any BodyImuParams fields) to BodyImuParams fields.

    Kalibr's ``*_noise_density`` are continuous white-noise densities (m s^-2 / sqrt(Hz), rad s^-1 /
    sqrt(Hz)) and ``*_random_walk`` bias random-walk densities (m s^-3 / sqrt(Hz), rad s^-2 /
    sqrt(Hz)): the same quantities as PhySynth's ``noise_density_*`` and ``bias_rw_*``. Other Kalibr
    keys (``rostopic``) are ignored.
    """
    out = {k: v for k, v in data.items() if k not in KALIBR_KEYS and k != "rostopic"}
    acc = dict(out.pop("accelerometer", {}) or {})
    gyr = dict(out.pop("gyroscope", {}) or {})
    pairs = ((acc, "noise_density_mps2_per_sqrt_hz", "accelerometer_noise_density"),
             (acc, "bias_rw_mps2_per_sqrt_s", "accelerometer_random_walk"),
             (gyr, "noise_density_radps_per_sqrt_hz", "gyroscope_noise_density"),
             (gyr, "bias_rw_radps_per_sqrt_s", "gyroscope_random_walk"))
    for target, field, key in pairs:
        if key in data:
            target[field] = data[key]
    if "update_rate" in data:
        out["rate_hz"] = data["update_rate"]
    return {**out, "accelerometer": acc, "gyroscope": gyr}


def body_imu_to_kalibr(params: BodyImuParams, rostopic: str = "/imu0") -> dict[str, Any]:
    """The Kalibr ``imu.yaml`` mapping of a body-frame IMU (white noise, bias walk, rate)."""
    return {
        "accelerometer_noise_density": params.accelerometer.noise_density_mps2_per_sqrt_hz,
        "accelerometer_random_walk": params.accelerometer.bias_rw_mps2_per_sqrt_s,
        "gyroscope_noise_density": params.gyroscope.noise_density_radps_per_sqrt_hz,
        "gyroscope_random_walk": params.gyroscope.bias_rw_radps_per_sqrt_s,
        "rostopic": rostopic,
        "update_rate": params.rate_hz,
    }


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuDevice:
    """Per-device errors drawn once per trace: ``matrix`` (3, 3) = I + scale factor + misalignment
    (measured = matrix @ true), ``turn_on_bias`` (3,), for the accelerometer and the gyroscope."""

    acc_matrix: np.ndarray
    acc_turn_on_bias_mps2: np.ndarray
    gyro_matrix: np.ndarray
    gyro_turn_on_bias_radps: np.ndarray


_OFF_DIAGONAL = np.array([1, 2, 3, 5, 6, 7])  # flat indices of a 3 x 3 matrix's off-diagonal, row by row


def _error_matrix(scale_std: float, misalign_std: float, rng: np.random.Generator) -> np.ndarray:
    m = np.eye(3)
    flat = m.reshape(-1)  # a view: the diagonal is every 4th element
    flat[::4] += rng.standard_normal(3) * scale_std
    flat[_OFF_DIAGONAL] += rng.standard_normal(6) * misalign_std  # small-angle non-orthogonal axes
    return m


def draw_imu_device(params: BodyImuParams, *, rng: np.random.Generator) -> ImuDevice:
    """Draw a device's scale factors, misalignments and turn-on biases (always 30 normal draws)."""
    a, g = params.accelerometer, params.gyroscope
    return ImuDevice(acc_matrix=_error_matrix(a.scale_factor_std, a.misalignment_std_rad, rng),
                     acc_turn_on_bias_mps2=rng.standard_normal(3) * a.turn_on_bias_std_mps2,
                     gyro_matrix=_error_matrix(g.scale_factor_std, g.misalignment_std_rad, rng),
                     gyro_turn_on_bias_radps=rng.standard_normal(3) * g.turn_on_bias_std_radps)


def bias_instability(t_s: np.ndarray, std: float, tau_s: float, *, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) first-order Gauss-Markov bias: stationary std ``std``, correlation time ``tau_s`` [s].

    Drawn on knots every ~0.1 s (exact AR(1) recursion) and linearly interpolated; its Allan deviation
    peaks near 0.66 ``std`` at tau about 1.9 ``tau_s`` (the usual stand-in for flicker bias instability).
    """
    return _gauss_markov_cf(t_s, std, tau_s, rng=rng).T


def _gauss_markov_cf(t_s, std, tau_s, *, rng):
    knots_t = _knots(t_s, _BIAS_KNOT_S)
    rho = np.exp(-(knots_t[1] - knots_t[0]) / tau_s)
    e = rng.standard_normal((3, knots_t.shape[0])) * std
    e[:, 1:] *= np.sqrt(1.0 - rho * rho)
    return resample_cf(t_s, knots_t, _ar1(e, rho))


def ideal_body_imu(t_s: np.ndarray, acc_enu_mps2: np.ndarray, rot: Rotation | np.ndarray,
                   omega_body_radps: np.ndarray, *, copy_rates: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Noiseless specific force and angular rate (T, 3) in the body frame at the truth times.

    f_b = R_wb^T (a_w - g_w), g_w = (0, 0, -G0): a level unit at rest reads (0, 0, +G0). ``rot``: the
    attitude body -> ENU, scipy rotations or (T, 4) quaternions (w, x, y, z). The rate is a copy of
    ``omega_body_radps`` unless ``copy_rates`` is False (then the input itself when float64).
    """
    w = np.array(omega_body_radps, dtype=float) if copy_rates else np.asarray(omega_body_radps, dtype=float)
    return _specific_force_body_cf(acc_enu_mps2, rot).T, w


def _rotation(rot: Rotation | np.ndarray) -> Rotation:
    """``rot`` as scipy rotations; (T, 4) quaternions (w, x, y, z) as :attr:`~physynth.models.attitude.Attitude.rot`
    makes them."""
    if isinstance(rot, np.ndarray):
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(rot, scalar_first=True)
    return rot


def _specific_force_body_cf(acc_enu_mps2: np.ndarray, rot: Rotation | np.ndarray) -> np.ndarray:
    """(3, T) specific force R_wb^T (a_w - g_w) in the body frame: ``rot.apply(f_w, inverse=True).T``
    (``rot`` scipy rotations or (T, 4) quaternions w, x, y, z as :func:`_rotation` reads them), bit for bit.

    scipy's ``apply`` sums ``R[:, k, j] * f[:, k]`` over k = 0, 1, 2 in order, from zero (numpy.einsum on
    the transposed matrices); here the same products and sums, one body axis at a time on contiguous
    rows, and + 0.0 for einsum's zero start (which turns a -0.0 sum into +0.0): a third of its time.
    Turns about the vertical only (:func:`_heading_force_cf`) skip the rotation objects altogether.
    """
    f_w = np.array(np.asarray(acc_enu_mps2, dtype=float).T, order="C")  # (3, T): a_w - g_w
    f_w[2] += G0_MPS2
    heading_only = (isinstance(rot, np.ndarray) and rot.shape == (f_w.shape[1], 4) and rot.shape[0] > 1
                    and not (rot[:, 1].any() or rot[:, 2].any()))  # quaternions (w, 0, 0, z)
    if heading_only:
        out = _heading_force_cf(rot, f_w)
        if out is not None:
            return out
    rot = _rotation(rot)
    m = rot.as_matrix()  # (T, 3, 3) body -> ENU; m[:, k, j] is (R^T)[j, k]
    if m.ndim != 3 or m.shape[0] != f_w.shape[1] or m.shape[0] < 2:  # one rotation: scipy uses matmul
        return rot.apply(f_w.T, inverse=True).T
    out = np.empty_like(f_w)
    tmp = np.empty(f_w.shape[1])
    for j in range(3):
        np.multiply(m[:, 0, j], f_w[0], out=out[j])
        out[j] += np.multiply(m[:, 1, j], f_w[1], out=tmp)
        out[j] += np.multiply(m[:, 2, j], f_w[2], out=tmp)
    out += 0.0
    return out


def _heading_force_cf(q_wxyz: np.ndarray, f_w: np.ndarray) -> np.ndarray | None:
    """R^T f (3, T) for turns about the vertical only, quaternions (w, 0, 0, z) (the tangent attitude),
    as :func:`_specific_force_body_cf` computes it from scipy's matrices, bit for bit; None when a
    quaternion is zero or not finite or ``f_w`` not finite (then scipy's path decides).

    scipy normalises by sqrt(z^2 + w^2) (the zero terms add nothing) and builds R00 = R11 = w^2 - z^2,
    R10 = -R01 = 2 z w, R22 = z^2 + w^2 the same way; its other entries are zeros of either sign, whose
    products with finite forces change a sum only where it is zero, and + 0.0 makes every zero sum +0.0.
    """
    if not np.isfinite(f_w.sum()):
        return None
    w, z = q_wxyz[:, 0], q_wxyz[:, 3]
    norm = np.sqrt(z * z + w * w)
    if not (norm > 0).all():  # scipy refuses zero (or NaN) quaternions
        return None
    z = z / norm
    w = w / norm
    z2, w2 = z * z, w * w
    diag = w2 - z2  # R00 = R11
    off = z * w
    off *= 2.0  # R10; R01 = -R10
    out = np.empty_like(f_w)
    np.multiply(diag, f_w[0], out=out[0])
    out[0] += off * f_w[1]  # R00 f0 + R10 f1
    np.multiply(off, f_w[0], out=out[1])
    np.negative(out[1], out=out[1])  # R01 f0 = -(R10 f0)
    out[1] += diag * f_w[1]
    z2 += w2  # R22
    np.multiply(z2, f_w[2], out=out[2])
    out += 0.0
    return out


ROTATION_EXACT_ABOVE_RAD = 1e-4
"""Largest turn within one truth step below which the specific force is interpolated linearly
between truth samples (chord error at most |f| angle^2 / 8, about 1e-8 m s^-2); above it, the rotation
within the step is applied exactly."""


def _max_turn_rad(omega_radps: np.ndarray, dt_s: np.ndarray) -> float:
    """max over steps k and axes c of |omega_kc| dt_k (omega (K, 3), dt (K,)), or, when that is cheaper to
    know, a bound of it that is itself at most :data:`ROTATION_EXACT_ABOVE_RAD`: then ``<=`` and ``>``
    against that threshold decide as on the maximum (rounding is monotonic). NaN as the maximum gives."""
    if dt_s.shape[0] == 0:
        return float(np.max(np.abs(omega_radps) * dt_s[:, None]))  # raises on empty input, as before
    bound = float(np.abs(omega_radps).max()) * float(dt_s.max())
    if bound <= ROTATION_EXACT_ABOVE_RAD:
        return bound
    return float(np.max(np.abs(omega_radps) * dt_s[:, None]))


def _ideal_at(t_q: np.ndarray, t_s: np.ndarray, acc_enu_mps2: np.ndarray, rot: Rotation, omega_body_radps: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Ideal specific force and body rate (3, N) at times ``t_q`` (any, e.g. shifted by a clock offset).

    Within truth step k the acceleration is linear in time and the attitude R_k exp(omega_k (t - t_k))
    (the attitude model's own convention), so f_b(t) = exp(-omega_k r) R_k^T (a(t) - g) exactly; the
    body rate is omega_k. Times before the first or after the last truth sample extend the first or
    last step.
    """
    n_t = t_s.shape[0]
    f_w = np.array(acc_enu_mps2, dtype=float)
    f_w[:, 2] += G0_MPS2
    inv = rot.inv()
    u = inv.apply(f_w)  # R_k^T (a_k - g)
    if n_t < 2:
        return np.repeat(u.T, t_q.shape[0], axis=1), np.repeat(np.asarray(omega_body_radps, float).T, t_q.shape[0], 1)
    d = inv[:-1].apply(np.diff(f_w, axis=0))  # R_k^T (a_{k+1} - a_k)
    dt = np.diff(t_s)
    turn = _max_turn_rad(np.asarray(omega_body_radps)[:-1], dt)
    n_q = t_q.shape[0]
    ratio = dt[0] / (t_q[1] - t_q[0]) if n_q > 1 else 0.0
    factor = int(round(ratio))
    if (turn <= ROTATION_EXACT_ABOVE_RAD and factor >= 1 and abs(ratio - factor) < 1e-9
            and abs(t_q[0] - t_s[0]) < 1e-12 and n_q <= (n_t - 1) * factor):
        # the usual case (no clock offset, IMU rate a multiple of the truth rate): upsample each step
        w_cf = np.asarray(omega_body_radps, dtype=float).T
        return upsample_linear(u.T, factor)[:, :n_q], np.repeat(w_cf[:, :-1], factor, axis=1)[:, :n_q]
    k = np.clip(np.searchsorted(t_s, t_q, side="right") - 1, 0, n_t - 2)
    r = (t_q - t_s[k]) / dt[k]
    f = u[k] + r[:, None] * d[k]
    w = np.asarray(omega_body_radps, dtype=float)[k]
    if turn > ROTATION_EXACT_ABOVE_RAD:
        from scipy.spatial.transform import Rotation

        f = Rotation.from_rotvec(w * (-(r * dt[k]))[:, None]).apply(f)
    return f.T, w.T


def _upsampling_factor(t_s: np.ndarray, t_imu: np.ndarray) -> int:
    """The integer ratio of IMU to truth rate when the IMU grid starts on the truth grid, else 0."""
    if t_s.shape[0] < 2 or t_imu.shape[0] < 2 or abs(t_imu[0] - t_s[0]) > 1e-12:
        return 0
    ratio = (t_s[1] - t_s[0]) / (t_imu[1] - t_imu[0])
    factor = int(round(ratio))
    return factor if factor >= 1 and abs(ratio - factor) < 1e-9 else 0


def _add_upsampled(out_cf: np.ndarray, slow_cf: np.ndarray, factor: int) -> None:
    """out (3, (T-1) factor) += slow (3, T) linearly upsampled, in place."""
    out_cf += upsample_linear(slow_cf, factor)


def _apply_device(matrix: np.ndarray, bias: np.ndarray, x_cf: np.ndarray, plus: np.ndarray | None = None, *,
                  copy: bool = True) -> np.ndarray:
    """(matrix @ x + bias) + plus for (3, N) samples, skipping an identity matrix, a zero bias and a None
    ``plus``: a new array, or ``x_cf`` itself when there is nothing to apply and ``copy`` is False."""
    has_bias = bool(np.any(bias != 0.0))
    if np.any(matrix != np.eye(3)):
        out = matrix @ x_cf
        if has_bias:
            out += bias[:, None]
    elif has_bias:
        out = x_cf + bias[:, None]
    elif plus is not None:
        return x_cf + plus
    else:
        return np.array(x_cf, dtype=float, order="C") if copy else x_cf
    if plus is not None:
        out += plus
    return out


def _gyro_vibration_variance(g: GyroscopeParams, omega_body_radps: np.ndarray, acc_norm: np.ndarray | None
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


def _triad_errors(t_s: np.ndarray, vib: VibrationParams, vib_amp: float, rw: float, bi: float, bi_tau: float,
                  *, rng: np.random.Generator, vib_var: np.ndarray | None = None) -> np.ndarray | None:
    """Slow errors (vibration, bias walk, bias instability) of one triad at the truth times, (3, T).

    ``vib_var`` (T,) or per axis (T, 3): the vibration's variance over time, when it follows the
    motion (then ``vib_amp`` is unused). None when all are zero. Each term draws only when it is on.
    """
    parts = []
    if vib_var is not None and np.any(vib_var > 0):
        unit = vib.model_copy(update={"amplitude_mps2": 1.0})
        scale = np.sqrt(vib_var).T if vib_var.ndim == 2 else np.sqrt(vib_var)[None, :]
        parts.append(_vibration_cf(t_s, unit, rng=rng) * scale)
    elif vib_amp > 0:
        parts.append(_vibration_cf(t_s, vib.model_copy(update={"amplitude_mps2": vib_amp}), rng=rng))
    if rw > 0:
        parts.append(_bias_cf(t_s, rw, 0.0, rng=rng))
    if bi > 0:
        parts.append(_gauss_markov_cf(t_s, bi, bi_tau, rng=rng))
    return sum(parts[1:], parts[0]) if parts else None


def simulate_body_imu(t_s: np.ndarray, acc_enu_mps2: np.ndarray, rot: Rotation | np.ndarray,
                      omega_body_radps: np.ndarray, params: BodyImuParams, *, rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-frame accelerometer and gyroscope over the truth span: (t_imu (N,), acc (N, 3), gyro (N, 3)).

    ``rot``: the attitude body -> ENU at the truth times, scipy rotations or (T, 4) quaternions
    (w, x, y, z) as the truth stores them (read as ``Rotation.from_quat(q, scalar_first=True)``).

    Physics, then deterministic errors, then noise: ideal f_b and omega_b (:func:`ideal_body_imu`) at
    the truth times ``t_s``, read at t - ``time_offset_s`` (:func:`_ideal_at`); gyro g-sensitivity
    (``g_sensitivity * f_b``); per-device matrix (scale factor, misalignment) and turn-on bias
    (:func:`draw_imu_device`); vibration, bias random walk and bias instability (slow, at the truth
    rate, linearly interpolated); white noise per IMU sample; quantisation. The angular rate is constant
    over each truth interval, so the noiseless gyroscope integrates to the truth attitude exactly.
    Inputs are not modified. A non-zero ``lever_arm_m`` moves the acceleration to the sensor's point first.
    """
    t = np.asarray(t_s, dtype=float)
    if any(params.lever_arm_m) or params.time_offset_s != 0.0:  # rotation objects needed
        rot = _rotation(rot)
    acc_enu_mps2 = _sensor_point_acc(t, acc_enu_mps2, rot, omega_body_radps, params.lever_arm_m)
    a, g = params.accelerometer, params.gyroscope
    dev = draw_imu_device(params, rng=rng)
    n_imu = int(np.ceil((t[-1] - t[0]) * params.rate_hz - 1e-9))
    t_imu = _sample_times(t[0], n_imu, params.rate_hz)
    vib_var = None
    acc_norm = None  # |a| at the truth times, when a vibration follows it
    if a.vibration_acc_var_gain_mps2 > 0 or any(g.vibration_acc_var_gain_rad2_per_m):
        acc_norm = np.linalg.norm(np.asarray(acc_enu_mps2, dtype=float), axis=1)
    if a.vibration_acc_var_gain_mps2 > 0 or a.vibration_rate_var_gain_mps4_per_radps > 0:
        vib_var = (a.vibration_amplitude_mps2**2
                   + a.vibration_acc_var_gain_mps2 * (0.0 if acc_norm is None else acc_norm)
                   + a.vibration_rate_var_gain_mps4_per_radps * np.linalg.norm(omega_body_radps, axis=1))
    acc_err = _triad_errors(t, params.vibration, a.vibration_amplitude_mps2, a.bias_rw_mps2_per_sqrt_s,
                            a.bias_instability_mps2, a.bias_instability_tau_s, rng=rng, vib_var=vib_var)
    gyro_var = _gyro_vibration_variance(g, omega_body_radps, acc_norm)
    gyro_err = _triad_errors(t, params.vibration, g.vibration_amplitude_radps, g.bias_rw_radps_per_sqrt_s,
                             g.bias_instability_radps, g.bias_instability_tau_s, rng=rng, vib_var=gyro_var)
    acc = _white_noise_cf(n_imu, np.full(3, a.noise_density_mps2_per_sqrt_hz), params.rate_hz, rng=rng)
    gyro = _white_noise_cf(n_imu, np.full(3, g.noise_density_radps_per_sqrt_hz), params.rate_hz, rng=rng)
    factor = _upsampling_factor(t, t_imu)
    turn = _max_turn_rad(np.asarray(omega_body_radps)[:-1], np.diff(t)) if t.size > 1 else 0.0
    if params.time_offset_s == 0.0 and factor and turn <= ROTATION_EXACT_ABOVE_RAD and n_imu == (t.size - 1) * factor:
        # the usual case: every term at the truth rate (linear maps commute with linear upsampling),
        # added into the noise
        f_b = _specific_force_body_cf(acc_enu_mps2, rot)  # (3, T), as ideal_body_imu
        w_b = np.asarray(omega_body_radps, dtype=float)  # read only
        acc_slow = _apply_device(dev.acc_matrix, dev.acc_turn_on_bias_mps2, f_b, acc_err)
        gyro_const = _apply_device(dev.gyro_matrix, dev.gyro_turn_on_bias_radps, w_b.T, copy=False)[:, :-1]
        gyro_lin = g.g_sensitivity_radps_per_mps2 * f_b if g.g_sensitivity_radps_per_mps2 > 0 else None
        if gyro_err is not None:
            gyro_lin = gyro_err if gyro_lin is None else gyro_lin + gyro_err
        _add_upsampled(acc, acc_slow, factor)
        per_step = gyro.reshape(3, -1, factor)
        for j in range(factor):  # one strided add per phase: 2x faster than a broadcast of length-factor rows
            per_step[:, :, j] += gyro_const
        if gyro_lin is not None:
            _add_upsampled(gyro, gyro_lin, factor)
    else:
        f, w = _ideal_at(t_imu - params.time_offset_s, t, acc_enu_mps2, _rotation(rot), omega_body_radps)  # (3, N)
        acc += _apply_device(dev.acc_matrix, dev.acc_turn_on_bias_mps2, f)
        gyro += _apply_device(dev.gyro_matrix, dev.gyro_turn_on_bias_radps, w)
        if g.g_sensitivity_radps_per_mps2 > 0:
            gyro += g.g_sensitivity_radps_per_mps2 * f
        if acc_err is not None:
            acc += resample_cf(t_imu, t, acc_err)
        if gyro_err is not None:
            gyro += resample_cf(t_imu, t, gyro_err)
    if a.quantisation_mps2 > 0:
        acc = np.round(acc / a.quantisation_mps2) * a.quantisation_mps2
    if g.quantisation_radps > 0:
        gyro = np.round(gyro / g.quantisation_radps) * g.quantisation_radps
    return t_imu, acc.T, gyro.T
