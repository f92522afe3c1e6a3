"""The IMU models' parameters: the ENU accelerometer (:class:`ImuParams`, its vibration and motion noise)
and the body-frame accelerometer and gyroscope (:class:`BodyImuParams`), with the Kalibr conversion.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, model_validator

from .._params import NonNegFloat, ParamsModel, PositiveFloat, Vec3


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
