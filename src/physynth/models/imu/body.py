"""The body-frame accelerometer and gyroscope composed (:func:`simulate_body_imu`): the ideal specific force
and body rate through a drawn device (scale, misalignment, biases) plus the noise processes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...constants import G0_MPS2
from .enu import sensor_point_acc
from .noise import bias_cf, gauss_markov_cf, resample_cf, sample_times, upsample_linear, white_noise_cf
from .params import BodyImuParams, VibrationParams
from .vibration import gyro_vibration_variance, vibration_cf

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


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
        parts.append(vibration_cf(t_s, unit, rng=rng) * scale)
    elif vib_amp > 0:
        parts.append(vibration_cf(t_s, vib.model_copy(update={"amplitude_mps2": vib_amp}), rng=rng))
    if rw > 0:
        parts.append(bias_cf(t_s, rw, 0.0, rng=rng))
    if bi > 0:
        parts.append(gauss_markov_cf(t_s, bi, bi_tau, rng=rng))
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
    acc_enu_mps2 = sensor_point_acc(t, acc_enu_mps2, rot, omega_body_radps, params.lever_arm_m)
    a, g = params.accelerometer, params.gyroscope
    dev = draw_imu_device(params, rng=rng)
    n_imu = int(np.ceil((t[-1] - t[0]) * params.rate_hz - 1e-9))
    t_imu = sample_times(t[0], n_imu, params.rate_hz)
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
    gyro_var = gyro_vibration_variance(g, omega_body_radps, acc_norm)
    gyro_err = _triad_errors(t, params.vibration, g.vibration_amplitude_radps, g.bias_rw_radps_per_sqrt_s,
                             g.bias_instability_radps, g.bias_instability_tau_s, rng=rng, vib_var=gyro_var)
    acc = white_noise_cf(n_imu, np.full(3, a.noise_density_mps2_per_sqrt_hz), params.rate_hz, rng=rng)
    gyro = white_noise_cf(n_imu, np.full(3, g.noise_density_radps_per_sqrt_hz), params.rate_hz, rng=rng)
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
