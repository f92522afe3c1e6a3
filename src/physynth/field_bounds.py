"""Physical ranges of every scenario field (docs/reliability.md); re-exported by :mod:`physynth.bounds`.

Pydantic checks types and signs; :data:`BOUNDS` adds, for every number of a scenario, the range in
which it still describes a physical UWB + IMU set-up (a walk, a vehicle, a cable car). A value
outside is refused with one line naming the field, its value and its range, so that a typo
(``imu.rate_hz: 1e7``, ``uwb.nlos_dwell_s: 1e-300``) never reaches the generator.

The table sits below :mod:`physynth.scenario` (which checks every scenario against it) and
:mod:`physynth.bounds` (the size budget, which reads scenarios).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Bound:
    """Inclusive physical range [lo, hi] of a field, its unit and why (one line)."""

    lo: float
    hi: float
    unit: str
    why: str


_COORD = Bound(-1e7, 1e7, "m", "ENU coordinates in a local or projected (UTM) frame")
_PROB = Bound(0.0, 1.0, "", "a probability")

_VIBRATION = {  # the structural vibration comb, of the world-frame IMU and of the body-frame one
    "fundamental_hz": Bound(0.01, 1000.0, "Hz", "structural vibration"),
    "amplitude_mps2": Bound(0.0, 1000.0, "m/s^2", "vibration RMS"),
    "harmonic_weights[]": Bound(0.0, 1e6, "", "relative weights"),
    "bandwidth_hz": Bound(1e-4, 1000.0, "Hz", "spectral line width"),
    "axis_gain[]": Bound(0.0, 100.0, "", "per-axis gain"),
}

BOUNDS: dict[str, Bound] = {
    "path.length_m": Bound(1.0, 100_000.0, "m", "a site from 1 m to 100 km"),
    "path.coeffs_enu_m[][]": _COORD,
    "path.waypoints_enu_m[][]": _COORD,
    "path.perturbation.lateral_std_m": Bound(0.0, 100.0, "m", "run-to-run cable or route deviation"),
    "path.perturbation.sag_std_m": Bound(0.0, 100.0, "m", "run-to-run cable sag change"),
    "motion.cruise_speed_mps": Bound(1e-6, 150.0, "m/s",
                                     "from a device shaken in place (motion.jitter) to a fast train"),
    "motion.profile.accel_frac": _PROB,
    "motion.profile.decel_frac": _PROB,
    "motion.profile.coeffs[]": Bound(-1e6, 1e6, "", "speed-shape polynomial coefficients (normalised)"),
    "motion.profile.samples[]": Bound(0.0, 1e6, "", "speed-shape samples (normalised to max 1)"),
    "motion.profile.smoothing": Bound(0.0, 1e6, "", "smoothing-spline penalty (positive)"),
    "motion.cruise_speed_spread_frac": Bound(0.0, 0.9, "", "per-run speed spread"),
    "motion.length_spread_frac": Bound(0.0, 0.9, "", "per-run length spread"),
    "motion.dwell_start_s": Bound(0.0, 86_400.0, "s", "a rest of at most a day"),
    "motion.dwell_end_s": Bound(0.0, 86_400.0, "s", "a rest of at most a day"),
    "motion.max_acc_mps2": Bound(1e-3, 1000.0, "m/s^2", "acceleration limit of the mover (100 g)"),
    "motion.jitter.bands_hz[]": Bound(1e-3, 1000.0, "Hz", "jitter band edges (slow wander to vibration)"),
    "motion.jitter.acc_rms_mps2[][]": Bound(0.0, 1000.0, "m/s^2", "jitter acceleration per band and axis (100 g)"),
    "motion.jitter.ramp_s": Bound(0.0, 3600.0, "s", "jitter fade-in and fade-out"),
    "motion.jitter.intensity_log_std": Bound(0.0, 3.0, "", "per-trace log-normal spread of the jitter"),
    "variation.layouts[][][]": _COORD,
    "variation.layout_jitter_m": Bound(0.0, 1000.0, "m", "per-trace horizontal anchor displacement"),
    "variation.layout_jitter_up_m": Bound(0.0, 1000.0, "m", "per-trace vertical anchor displacement"),
    "variation.path_yaw_std_rad": Bound(0.0, 3.1416, "rad", "per-trace turn of the path (at most half a turn)"),
    "variation.path_shift_std_m": Bound(0.0, 10_000.0, "m", "per-trace horizontal shift of the path"),
    "variation.path_lateral_std_m": Bound(0.0, 100.0, "m", "run-to-run route deviation of the varied path"),
    "variation.path_sag_std_m": Bound(0.0, 100.0, "m", "run-to-run sag of the varied path"),
    "variation.random_route_prob": _PROB,
    "variation.random_route_points": Bound(2.0, 1000.0, "", "waypoints of a random route"),
    "variation.nlos_log_std": Bound(0.0, 3.0, "", "per-trace log-normal spread of the NLOS probabilities"),
    "variation.layout_distribution.anchor_count[]": Bound(3.0, 8.0, "", "anchors of a drawn layout"),
    "variation.layout_distribution.footprint_m[]": Bound(0.0, 1000.0, "m",
                                                         "long side of a drawn layout (a desk to a 1 km site)"),
    "variation.layout_distribution.aspect[]": Bound(0.0, 1.0, "", "short side / long side of a drawn layout"),
    "variation.layout_distribution.height_m[]": _COORD,
    "variation.layout_distribution.coplanar_prob": _PROB,
    "variation.layout_distribution.coplanar_std_m": Bound(0.0, 100.0, "m",
                                                          "height spread of a drawn layout's anchors at one height"),
    "variation.layout_distribution.min_spacing_m": Bound(0.0, 1000.0, "m", "least distance of two drawn anchors"),
    "variation.layout_distribution.route_offset_m[]": Bound(0.0, 10_000.0, "m",
                                                            "drawn layout's centroid from the scenario's anchors'"),
    "uwb.antenna_sway_std_m": Bound(0.0, 10.0, "m", "UWB antenna offset from the truth point, per axis"),
    "uwb.antenna_sway_tau_s": Bound(0.01, 3600.0, "s", "correlation time of the antenna sway"),
    "uwb.antenna_sway_length_m": Bound(0.01, 1e5, "m", "correlation length of the antenna sway along the path"),
    "uwb.antenna_sway_turn_rad": Bound(0.001, 1e3, "rad", "angle turned over which the antenna sway decorrelates"),
    "uwb.tag_pattern_m[]": Bound(-1.0, 1.0, "m", "tag antenna delay per harmonic of the anchor's bearing"),
    "uwb.tag_nlos_prob": Bound(0.0, 1.0, "-", "fraction of the time the tag side is obstructed (all anchors at once)"),
    "uwb.late_burst_prob": _PROB,
    "uwb.late_burst_delay_s": Bound(0.0, 10.0, "s", "how much later the late rows of a late burst are stamped"),
    "imu.rate_hz": Bound(1.0, 10_000.0, "Hz", "MEMS accelerometer output rates"),
    "imu.white_noise_density_mps2_per_sqrt_hz[]": Bound(0.0, 10.0, "m/s^2/sqrt(Hz)", "accelerometer noise density"),
    "imu.bias_rw_mps2_per_sqrt_s": Bound(0.0, 10.0, "m/s^2/sqrt(s)", "bias random walk"),
    "imu.bias_initial_std_mps2": Bound(0.0, 100.0, "m/s^2", "turn-on bias"),
    **{f"imu.vibration.{k}": b for k, b in _VIBRATION.items()},
    "uwb.burst_rate_hz": Bound(0.1, 1000.0, "Hz", "UWB ranging rates"),
    "uwb.burst_jitter_s": Bound(0.0, 1.0, "s", "burst period jitter"),
    "uwb.burst_phase_s": Bound(0.0, 100.0, "s", "first burst offset"),
    "uwb.slot_s": Bound(0.0, 1.0, "s", "anchor slot spacing in a burst"),
    "uwb.time_offset_s": Bound(-10.0, 10.0, "s", "UWB clock offset"),
    "uwb.time_offset_std_s": Bound(0.0, 1.0, "s", "run-to-run spread of the UWB clock offset"),
    "uwb.nlos_dwell_s": Bound(1e-3, 3600.0, "s", "mean NLOS episode length"),
    "uwb.zones[].s_m": Bound(0.0, 100_000.0, "m", "position along the path"),
    "uwb.zones[].half_width_m": Bound(1e-3, 100_000.0, "m", "zone half width"),
    "uwb.zones[].nlos_prob": _PROB,
    "anchors[].pos_enu_m[]": _COORD,
    "channel.rate_hz": Bound(0.01, 1000.0, "Hz", "per-anchor ranging rate"),
    "channel.los_mean_m": Bound(-10.0, 10.0, "m", "LOS range bias"),
    "channel.los_std_m": Bound(0.0, 100.0, "m", "LOS range noise"),
    "channel.range_bias_per_m": Bound(-0.5, 0.5, "m/m", "range scale error"),
    "channel.range_bias_per_decade_m": Bound(-1.0, 1.0, "m/decade", "received-power ranging bias"),
    "channel.nlos_prob": _PROB,
    "channel.nlos_modes[].weight": Bound(0.0, 1e6, "", "relative mode weight"),
    "channel.nlos_modes[].mean_m": Bound(-100.0, 1000.0, "m", "NLOS excess range"),
    "channel.nlos_modes[].std_m": Bound(0.0, 1000.0, "m", "NLOS spread"),
    "channel.nlos_modes[].dwell_s": Bound(1e-3, 3600.0, "s", "mean NLOS episode length"),
    "channel.max_range_m": Bound(0.0, 1e7, "m", "link range"),
    "channel.edge_width_m": Bound(0.0, 100_000.0, "m", "link edge softness"),
    "availability.dropout_prob": _PROB,
    "availability.outage_onset_prob": _PROB,
    "availability.outage_mean_s": Bound(1e-3, 1e6, "s", "mean outage length"),
    "availability.tag_outage_onset_prob": _PROB,
    "availability.tag_outage_mean_s": Bound(1e-3, 1e6, "s", "mean tag outage length"),
    "availability.long_outage_rate_per_s": Bound(0.0, 1e3, "1/s", "long-outage onset rate at the reference range"),
    "availability.long_outage_mean_s": Bound(1e-3, 1e6, "s", "mean long-outage length"),
    "availability.long_outage_range_slope_per_m": Bound(-10.0, 10.0, "1/m", "log-rate slope against range"),
    "availability.long_outage_ref_range_m": Bound(0.0, 1e7, "m", "reference range of the long-outage rate"),
    "availability.long_outage_max_range_m": Bound(1e-3, 1e7, "m", "range beyond which the rate stays constant"),
    "availability.long_outage_frailty_shape": Bound(1e-3, 1e6, "", "Gamma shape of the per-anchor rate factor"),
    "uwb.run_offset_std_m": Bound(0.0, 10.0, "m", "run-to-run ranging offset"),
    "uwb.run_anchor_offset_std_m": Bound(0.0, 10.0, "m", "per-anchor run-to-run offset"),
    "uwb.run_slope_std_m": Bound(0.0, 2.0, "m/decade", "run-to-run tilt of the range law"),
    "uwb.run_anchor_slope_std_m": Bound(0.0, 2.0, "m/decade", "per-anchor run-to-run tilt of the range law"),
    "uwb.run_slope_ref_range_m": Bound(1e-3, 1e6, "m", "range the run-to-run tilt pivots about"),
    "uwb.terrain.spacing_m": Bound(0.01, 10_000.0, "m", "terrain grid spacing"),
    "uwb.terrain.heights_m[][]": Bound(-11_000.0, 9_000.0, "m", "terrain heights on Earth"),
    "uwb.terrain.origin_en_m[]": _COORD,
    "uwb.terrain.loss_db": Bound(0.0, 300.0, "dB", "terrain blockage loss"),
    "uwb.obstacles[].min_enu_m[]": _COORD,
    "uwb.obstacles[].max_enu_m[]": _COORD,
    "uwb.obstacles[].vertices_en_m[][]": _COORD,
    "uwb.obstacles[].base_m": _COORD,
    "uwb.obstacles[].top_m": _COORD,
    "uwb.obstacles[].loss_db": Bound(0.0, 300.0, "dB", "obstacle loss"),
    "anchors[].front_back_db": Bound(0.0, 100.0, "dB", "antenna front-to-back ratio"),
    "anchors[].boresight_enu[]": Bound(-1e6, 1e6, "", "antenna direction (normalised)"),
    "channel.link_budget.ref_power_dbm": Bound(-200.0, 50.0, "dBm", "received power at the reference distance"),
    "channel.link_budget.ref_distance_m": Bound(0.01, 1000.0, "m", "reference distance"),
    "channel.link_budget.path_loss_exponent": Bound(0.5, 10.0, "", "path-loss exponent"),
    "channel.link_budget.sensitivity_dbm": Bound(-200.0, 50.0, "dBm", "receiver sensitivity"),
    "channel.link_budget.shadowing_std_db": Bound(0.0, 50.0, "dB", "log-normal shadowing"),
    "channel.link_budget.ground_reflection": _PROB,
    "channel.link_budget.ground_u_m": _COORD,
    "channel.link_budget.wavelength_m": Bound(1e-3, 10.0, "m", "carrier wavelength"),
    "channel.link_budget.tag_height_m": Bound(0.01, 1000.0, "m", "tag antenna height above the ground plane"),
    "attitude.min_speed_mps": Bound(1e-4, 10.0, "m/s", "speed below which the heading is held"),
    "attitude.max_turn_rate_radps": Bound(0.01, 1000.0, "rad/s", "fastest turn of the heading"),
    "attitude.pendulum_period_s": Bound(0.1, 600.0, "s", "pendulum period"),
    "attitude.pendulum_damping_ratio": Bound(0.0, 1.0, "", "damping ratio"),
    "attitude.tumble_rate_std_radps": Bound(0.0, 100.0, "rad/s", "tumble rate"),
    "attitude.tumble_correlation_s": Bound(1e-3, 3600.0, "s", "tumble correlation time"),
    "attitude.fixed_quat_wxyz[]": Bound(-1e3, 1e3, "", "quaternion (normalised)"),
    "imu.time_offset_s": Bound(-1.0, 1.0, "s", "IMU clock offset"),
    "imu.lever_arm_m[]": Bound(-10.0, 10.0, "m", "sensor position in the body frame (a vehicle's size)"),
    "imu.truth_cutoff_hz": Bound(0.01, 10_000.0, "Hz", "truth band the IMU noise was calibrated against"),
    "imu.motion_noise.acc_var_gain_mps2[]": Bound(0.0, 1000.0, "m^2/s^4 per m/s^2", "motion-dependent vibration"),
    "imu.motion_noise.rate_var_gain_mps4_per_radps[]": Bound(0.0, 1000.0, "m^2/s^4 per rad/s",
                                                           "rate-dependent vibration"),
    "body_imu.accelerometer.vibration_acc_var_gain_mps2": Bound(0.0, 1000.0, "m^2/s^4 per m/s^2",
                                                              "motion-dependent vibration"),
    "body_imu.accelerometer.vibration_rate_var_gain_mps4_per_radps": Bound(0.0, 1000.0, "m^2/s^4 per rad/s",
                                                                         "rate-dependent vibration"),
    "body_imu.gyroscope.vibration_rate_var_gain_radps": Bound(0.0, 100.0, "rad^2/s^2 per rad/s",
                                                            "rate-dependent vibration"),
    "body_imu.gyroscope.vibration_acc_var_gain_rad2_per_m[]": Bound(0.0, 100.0, "rad^2/s^2 per m/s^2",
                                                                   "motion-dependent vibration"),
    "body_imu.rate_hz": Bound(1.0, 10_000.0, "Hz", "MEMS IMU output rates"),
    "body_imu.time_offset_s": Bound(-1.0, 1.0, "s", "IMU clock offset"),
    "body_imu.lever_arm_m[]": Bound(-10.0, 10.0, "m", "sensor position in the body frame (a vehicle's size)"),
    "body_imu.accelerometer.noise_density_mps2_per_sqrt_hz": Bound(0.0, 10.0, "m/s^2/sqrt(Hz)", "noise density"),
    "body_imu.accelerometer.bias_rw_mps2_per_sqrt_s": Bound(0.0, 10.0, "m/s^2/sqrt(s)", "bias random walk"),
    "body_imu.accelerometer.bias_instability_mps2": Bound(0.0, 10.0, "m/s^2", "bias instability"),
    "body_imu.accelerometer.bias_instability_tau_s": Bound(1e-3, 1e6, "s", "bias correlation time"),
    "body_imu.accelerometer.turn_on_bias_std_mps2": Bound(0.0, 100.0, "m/s^2", "turn-on bias"),
    "body_imu.accelerometer.scale_factor_std": Bound(0.0, 1.0, "", "scale-factor error"),
    "body_imu.accelerometer.misalignment_std_rad": Bound(0.0, 1.0, "rad", "axis misalignment"),
    "body_imu.accelerometer.quantisation_mps2": Bound(0.0, 10.0, "m/s^2", "output resolution"),
    "body_imu.accelerometer.vibration_amplitude_mps2": Bound(0.0, 1000.0, "m/s^2", "vibration RMS"),
    "body_imu.gyroscope.noise_density_radps_per_sqrt_hz": Bound(0.0, 1.0, "rad/s/sqrt(Hz)", "noise density"),
    "body_imu.gyroscope.bias_rw_radps_per_sqrt_s": Bound(0.0, 1.0, "rad/s/sqrt(s)", "bias random walk"),
    "body_imu.gyroscope.bias_instability_radps": Bound(0.0, 1.0, "rad/s", "bias instability"),
    "body_imu.gyroscope.bias_instability_tau_s": Bound(1e-3, 1e6, "s", "bias correlation time"),
    "body_imu.gyroscope.turn_on_bias_std_radps": Bound(0.0, 10.0, "rad/s", "turn-on bias"),
    "body_imu.gyroscope.scale_factor_std": Bound(0.0, 1.0, "", "scale-factor error"),
    "body_imu.gyroscope.misalignment_std_rad": Bound(0.0, 1.0, "rad", "axis misalignment"),
    "body_imu.gyroscope.quantisation_radps": Bound(0.0, 1.0, "rad/s", "output resolution"),
    "body_imu.gyroscope.vibration_amplitude_radps": Bound(0.0, 100.0, "rad/s", "vibration RMS"),
    "body_imu.gyroscope.g_sensitivity_radps_per_mps2": Bound(0.0, 1.0, "rad/s per m/s^2", "g-sensitivity"),
    **{f"body_imu.vibration.{k}": b for k, b in _VIBRATION.items()},
    "truth_rate_hz": Bound(1.0, 10_000.0, "Hz", "truth sampling rate"),
    "grid_rate_hz": Bound(1.0, 10_000.0, "Hz", "evaluation grid rate"),
}
"""Dotted field path (``[]`` for any list element; per-anchor overrides use the default's path) ->
physical range."""


def _leaves(obj: Any, path: str) -> Iterator[tuple[str, str, Any]]:
    """(pattern, concrete path, value) of every number in a dumped scenario."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if path in ("channel_per_anchor", "availability_per_anchor"):
                yield from _leaves(v, path.replace("_per_anchor", "") + f"@{k}")
            else:
                yield from _leaves(v, f"{path}.{k}" if path else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, f"{path}[{i}]")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield path, path, obj


def _pattern(concrete: str) -> str:
    import re

    p = re.sub(r"@[^.\[]*", "", concrete)
    return re.sub(r"\[\d+\]", "[]", p)


def check_bounds(data: dict[str, Any]) -> None:
    """Raise ValueError naming the first number of a dumped scenario outside its physical range."""
    for _, concrete, value in _leaves(data, ""):
        b = BOUNDS.get(_pattern(concrete))
        if b is None:
            continue
        if not (b.lo <= value <= b.hi):
            shown = concrete.replace("channel@", "channel_per_anchor.").replace(
                "availability@", "availability_per_anchor.")
            raise ValueError(f"field {shown}: {value:g} {b.unit} is outside the physical range "
                             f"[{b.lo:g}, {b.hi:g}] {b.unit} ({b.why})".replace("  ", " "))
