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

One module per part; :func:`~physynth.models.imu.enu.simulate_imu` and
:func:`~physynth.models.imu.body.simulate_body_imu` compose them.
"""

from .body import ROTATION_EXACT_ABOVE_RAD, ImuDevice, draw_imu_device, ideal_body_imu, simulate_body_imu
from .enu import lever_arm_acceleration, simulate_imu
from .noise import bias_instability, bias_random_walk, resample_cf, upsample_linear, white_noise
from .params import (
    KALIBR_KEYS,
    AccelerometerParams,
    BodyImuParams,
    GyroscopeParams,
    ImuParams,
    MotionNoiseParams,
    VibrationParams,
    body_imu_to_kalibr,
    kalibr_to_body_imu,
)
from .vibration import vibration, vibration_variance

__all__ = [
    "AccelerometerParams",
    "BodyImuParams",
    "GyroscopeParams",
    "ImuDevice",
    "ImuParams",
    "KALIBR_KEYS",
    "MotionNoiseParams",
    "ROTATION_EXACT_ABOVE_RAD",
    "VibrationParams",
    "bias_instability",
    "bias_random_walk",
    "body_imu_to_kalibr",
    "draw_imu_device",
    "ideal_body_imu",
    "kalibr_to_body_imu",
    "lever_arm_acceleration",
    "resample_cf",
    "simulate_body_imu",
    "simulate_imu",
    "upsample_linear",
    "vibration",
    "vibration_variance",
    "white_noise",
]
