"""The ENU accelerometer composed (:func:`simulate_imu`): the truth's acceleration at the sensor point (the
lever arm) plus white noise, bias random walk and vibration.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...records import Imu
from ..kinematics import Kinematics
from .noise import bias_cf, resample_cf, sample_times, upsample_linear, white_noise_cf
from .params import ImuParams
from .vibration import modulated_vibration_cf, vibration_cf

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


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
        vib = modulated_vibration_cf(kin.t_s, kin.acc_enu_mps2, omega_body_radps, params, rng=rng)
    else:
        vib = vibration_cf(kin.t_s, params.vibration, rng=rng)
    if params.time_offset_s != 0.0:  # the sensor reads the motion at t - offset
        slow = np.stack([np.interp(kin.t_s - params.time_offset_s, kin.t_s, acc_in[:, k]) for k in range(3)])
        slow += vib
    else:  # acceleration + vibration, into the vibration's array (the model never writes into its inputs)
        slow = np.add(acc_in.T, vib, out=vib)
    slow += bias_cf(kin.t_s, params.bias_rw_mps2_per_sqrt_s, params.bias_initial_std_mps2, rng=rng)
    # IMU samples cover [t0, t_end) of the truth; the last truth instant itself has no IMU sample
    n_imu = int(np.ceil((kin.t_s[-1] - kin.t_s[0]) * params.rate_hz - 1e-9))
    t_imu = sample_times(kin.t_s[0], n_imu, params.rate_hz)
    acc = white_noise_cf(t_imu.shape[0], np.asarray(params.white_noise_density_mps2_per_sqrt_hz),
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
    return sensor_point_acc(kin.t_s, kin.acc_enu_mps2, attitude, omega_body_radps, params.lever_arm_m)


def sensor_point_acc(t_s, acc_enu_mps2, attitude, omega_body_radps, lever_arm_m) -> np.ndarray:
    """The acceleration (T, 3) of the point at ``lever_arm_m``; the input itself when it is zero or
    the attitude or rates are missing."""
    acc = np.asarray(acc_enu_mps2)
    if attitude is None or omega_body_radps is None or not any(lever_arm_m):
        return acc
    # the truth's rates hold over [t_k, t_{k+1}): the rate at t_k is the mean of rows k-1 and k
    w = np.nan_to_num(np.asarray(omega_body_radps, dtype=float))
    w_at = 0.5 * (w + np.concatenate([w[:1], w[:-1]]))
    return acc + lever_arm_acceleration(np.asarray(t_s, dtype=float), attitude, w_at, lever_arm_m)
