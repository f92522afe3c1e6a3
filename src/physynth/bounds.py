"""Physical ranges of every scenario field and the size budget of a generation (docs/reliability.md).

Pydantic checks types and signs; :data:`BOUNDS` adds, for every number of a scenario, the range in
which it still describes a physical UWB + IMU set-up (a walk, a vehicle, a cable car). A value
outside is refused with one line naming the field, its value and its range, so that a typo
(``imu.rate_hz: 1e7``, ``uwb.nlos_dwell_s: 1e-300``) never reaches the generator.

:func:`estimate_size` predicts, before any work, the samples, peak memory and output size of
generating ``n`` traces; :func:`check_budget` refuses a generation over :data:`MEMORY_BUDGET_BYTES`
or :data:`OUTPUT_BUDGET_BYTES` with the estimate in the message (``force=True`` overrides), and a
scenario whose trip is too short to give a trace at all.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .constants import IMU_BODY_FRAME, IMU_FRAME
from .errors import BudgetError, ScenarioError

if TYPE_CHECKING:
    from .scenario import Scenario


@dataclass(frozen=True, slots=True)
class Bound:
    """Inclusive physical range [lo, hi] of a field, its unit and why (one line)."""

    lo: float
    hi: float
    unit: str
    why: str


_COORD = Bound(-1e7, 1e7, "m", "ENU coordinates in a local or projected (UTM) frame")
_PROB = Bound(0.0, 1.0, "", "a probability")

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
    "imu.vibration.fundamental_hz": Bound(0.01, 1000.0, "Hz", "structural vibration"),
    "imu.vibration.amplitude_mps2": Bound(0.0, 1000.0, "m/s^2", "vibration RMS"),
    "imu.vibration.harmonic_weights[]": Bound(0.0, 1e6, "", "relative weights"),
    "imu.vibration.bandwidth_hz": Bound(1e-4, 1000.0, "Hz", "spectral line width"),
    "imu.vibration.axis_gain[]": Bound(0.0, 100.0, "", "per-axis gain"),
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
    "body_imu.vibration.fundamental_hz": Bound(0.01, 1000.0, "Hz", "structural vibration"),
    "body_imu.vibration.amplitude_mps2": Bound(0.0, 1000.0, "m/s^2", "vibration RMS"),
    "body_imu.vibration.harmonic_weights[]": Bound(0.0, 1e6, "", "relative weights"),
    "body_imu.vibration.bandwidth_hz": Bound(1e-4, 1000.0, "Hz", "spectral line width"),
    "body_imu.vibration.axis_gain[]": Bound(0.0, 100.0, "", "per-axis gain"),
    "truth_rate_hz": Bound(1.0, 10_000.0, "Hz", "truth sampling rate"),
    "grid_rate_hz": Bound(1.0, 10_000.0, "Hz", "evaluation grid rate"),
}
"""Dotted field path (``[]`` for any list element; per-anchor overrides use the default's path) ->
physical range."""


def _gb_env(name: str, default_gb: float) -> float:
    try:
        return float(os.environ.get(name, "")) * 1e9
    except ValueError:
        return default_gb * 1e9


MEMORY_BUDGET_BYTES = _gb_env("PHYSYNTH_MEMORY_BUDGET_GB", 4.0)
"""Peak memory a generation may need [bytes]: 4 GB, or ``PHYSYNTH_MEMORY_BUDGET_GB``."""
OUTPUT_BUDGET_BYTES = _gb_env("PHYSYNTH_OUTPUT_BUDGET_GB", 20.0)
"""Size a generated dataset may reach [bytes]: 20 GB, or ``PHYSYNTH_OUTPUT_BUDGET_GB``."""
MIN_TRUTH_SAMPLES = 10
"""A trace shorter than this many truth samples is refused (a zero-length path, an absurd speed)."""

# bytes per sample: about twice the peak tracemalloc measures on the cablecar preset (3.9 MB per trace)
_WORK_BYTES = {"truth": 150, "imu": 80, "uwb": 100}
_TABLE_BYTES = {"truth": 64, "imu": 40, "uwb": 60}
ROW_GROUP_TRACES = 64
# bytes per row on disk, as the Parquet writer stores them: measured 36-44 B per truth row, 12-13 B per IMU
# row and triad (ENU, body accelerometer, body gyroscope), 18-21 B per UWB row (cablecar-descending,
# walk-hanyang, handheld-broad), 8-30 % under these; the estimate also takes the longest trip the spreads
# allow (tests/test_budget_estimate.py keeps it above what is written and within twice of it)
_DISK_BYTES = {"truth": 48, "imu_triad": 16, "uwb": 24}


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


@dataclass(frozen=True, slots=True)
class SizeEstimate:
    """Predicted size of generating ``n_traces`` traces (upper bounds over the per-run spreads)."""

    n_traces: int
    duration_s: float
    min_trip_s: float
    truth_samples: int
    imu_samples: int
    uwb_rows: int
    peak_memory_bytes: float
    output_bytes: float  # on disk, as the Parquet writer stores the traces
    sample_bytes: float = 0.0  # the traces' tables in memory: what generating and reducing them handles
    processes: int = 1  # processes generating at once on this machine, each holding its own traces

    def describe(self) -> str:
        over = f" over {self.processes} processes" if self.processes > 1 else ""
        return (f"{self.n_traces} trace(s) of up to {self.duration_s:.4g} s: {self.truth_samples:,} truth, "
                f"{self.imu_samples:,} IMU and {self.uwb_rows:,} UWB rows per trace, up to about "
                f"{self.peak_memory_bytes / 1e9:.3g} GB of memory{over} and {self.output_bytes / 1e9:.3g} GB on disk")


def estimate_size(scn: Scenario, n_traces: int, processes: int = 1) -> SizeEstimate:
    """Samples, peak memory and output size of ``n_traces`` traces of ``scn``, before any work.

    ``processes`` generate at once on this machine (worker processes), each holding its own traces: the
    peak memory is theirs together, for the run as a whole."""
    from .models.motion import compile_speed_shape
    from .models.path import compile_path

    try:
        length = float(scn.path.length_m) if scn.path.kind == "polynomial" else compile_path(scn.path).length_m
        shape_mean = compile_speed_shape(scn.motion.profile).mean
        if scn.variation is not None and scn.variation.random_route_prob > 0:
            length = max(length, _random_route_bound_m(scn))
    except (ValueError, ArithmeticError) as exc:
        raise ScenarioError(f"scenario '{scn.name}': {exc}") from None
    m = scn.motion
    trip_min, trip_max = trip_range_s(scn, length, shape_mean)
    duration = m.dwell_start_s + trip_max + m.dwell_end_s
    truth = math.floor(duration * scn.truth_rate_hz) + 1
    imu = math.floor(duration * scn.imu.rate_hz) + 1
    n_anchors = len(scn.anchors)
    if scn.variation is not None and scn.variation.layout_distribution is not None:  # drawn layouts: the largest
        n_anchors = max(n_anchors, scn.variation.layout_distribution.anchor_count[1])
    uwb = math.ceil(duration * scn.uwb.burst_rate_hz * (1 + 1e-3)) * n_anchors
    counts = {"truth": truth, "imu": imu, "uwb": uwb}
    work = sum(_WORK_BYTES[k] * v for k, v in counts.items())
    table = sum(_TABLE_BYTES[k] * v for k, v in counts.items())
    triads = (IMU_FRAME in scn.imu_frames) + 2 * (IMU_BODY_FRAME in scn.imu_frames)
    disk = _DISK_BYTES["truth"] * truth + _DISK_BYTES["imu_triad"] * triads * imu + _DISK_BYTES["uwb"] * uwb
    return SizeEstimate(n_traces=n_traces, duration_s=duration, min_trip_s=trip_min, truth_samples=truth,
                        imu_samples=imu, uwb_rows=uwb,
                        peak_memory_bytes=max(1, processes) * (work + min(n_traces, ROW_GROUP_TRACES) * table),
                        output_bytes=n_traces * disk, sample_bytes=n_traces * table, processes=max(1, processes))


def _random_route_bound_m(scn: Scenario) -> float:
    """Upper bound of the length of the scenario's random routes [m] (``variation``), with 20 % for the
    smooth path through the waypoints being longer than their polyline."""
    import numpy as np

    from .models.path import compile_path
    from .models.variation import max_route_length_m

    geo = compile_path(scn.path)
    pts = np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, 200))[0], dtype=float)
    centre = np.mean([a.pos_enu_m for a in scn.anchors], axis=0) if scn.anchors else pts.mean(axis=0)
    return 1.2 * max_route_length_m(scn.variation, pts, np.asarray(centre, dtype=float))


def trip_range_s(scn: Scenario, length_m: float, shape_mean: float) -> tuple[float, float]:
    """(shortest, longest) trip [s] of the scenario's runs over a path of ``length_m`` whose speed profile
    has mean ``shape_mean`` (the spreads of cruise speed and length at their extremes)."""
    m = scn.motion
    v_hi = m.cruise_speed_mps * (1 + m.cruise_speed_spread_frac)
    v_lo = m.cruise_speed_mps * (1 - m.cruise_speed_spread_frac)
    return (length_m * (1 - m.length_spread_frac) / (v_hi * shape_mean),
            length_m * (1 + m.length_spread_frac) / (v_lo * shape_mean))


def check_trip(scn: Scenario, est: SizeEstimate | None = None, *, min_trip_s: float | None = None) -> None:
    """Refuse a scenario whose shortest trip is too short to make traces (every generation path checks
    it: :func:`check_budget`, :func:`physynth.generate.compile_scenario`). The shortest trip comes from
    ``min_trip_s`` (compile_scenario's, from its compiled path and speed profile), else ``est``, else a
    size estimate of one trace.

    Raises
    ------
    ScenarioError
        The shortest trip gives fewer than :data:`MIN_TRUTH_SAMPLES` truth samples (not overridable).
    """
    if min_trip_s is None:
        min_trip_s = (estimate_size(scn, 1) if est is None else est).min_trip_s
    moving = min_trip_s * scn.truth_rate_hz
    if not moving >= MIN_TRUTH_SAMPLES:
        raise ScenarioError(f"scenario '{scn.name}': the trip takes only {min_trip_s:.3g} s "
                            f"({moving:.3g} truth samples at {scn.truth_rate_hz:g} Hz, fewer than "
                            f"{MIN_TRUTH_SAMPLES}): check path length and cruise speed")


def check_budget(scn: Scenario, n_traces: int, *, force: bool = False, writes: bool = True,
                 processes: int = 1) -> SizeEstimate:
    """Refuse, before any work, a generation that is too short to make traces or over budget.

    ``processes``: worker processes generating at once on this machine; the memory budget holds for
    them together (the run as a whole), not for each (:func:`estimate_size`).

    ``writes``: the traces are written (a dataset: their size on disk is held against the output budget);
    False for work that only reduces them (the studies: their samples in memory, a bound on the time).

    Raises
    ------
    ScenarioError
        The shortest trip gives fewer than :data:`MIN_TRUTH_SAMPLES` truth samples (:func:`check_trip`).
    BudgetError
        Unless ``force``: the peak memory or the output size exceeds its budget; the message holds
        the estimate.
    """
    est = estimate_size(scn, n_traces, processes)
    check_trip(scn, est)
    if force:
        return est
    if est.peak_memory_bytes > MEMORY_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.describe()}; the memory budget is "
                          f"{MEMORY_BUDGET_BYTES / 1e9:.3g} GB (PHYSYNTH_MEMORY_BUDGET_GB)")
    if writes and est.output_bytes > OUTPUT_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.describe()}; the output budget is "
                          f"{OUTPUT_BUDGET_BYTES / 1e9:.3g} GB (PHYSYNTH_OUTPUT_BUDGET_GB)")
    if not writes and est.sample_bytes > OUTPUT_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.n_traces} trace(s) of up to {est.duration_s:.4g} s are "
                          f"about {est.sample_bytes / 1e9:.3g} GB of samples to generate and reduce (nothing is "
                          f"written, but it would take long); the output budget is {OUTPUT_BUDGET_BYTES / 1e9:.3g} GB "
                          "(PHYSYNTH_OUTPUT_BUDGET_GB)")
    return est
