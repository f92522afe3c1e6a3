"""UWB ranging model: burst schedule, link/visibility, LOS/NLOS errors per anchor, availability.

For anchor i at a_i the geometric range is r = |p(t) - a_i| (paper eq. 2) and the measured range
(eq. 3) is r + (1 - z) N(mu_i + beta_i r, sigma_i^2) + z delta_i with z the NLOS indicator and
delta_i drawn from the anchor's Gaussian mixture (bimodal allowed). ``beta_i`` is an optional
range-proportional bias (clock/antenna scale error; Hanyang's static sweeps show ~+0.4 cm per m).

z follows an alternating renewal process in time (NLOS episodes of mean ``nlos_dwell_s``, or of the
mode's own ``dwell_s``, and long-run probability ``nlos_prob``); an episode keeps one mixture mode
(one reflector) throughout. z is forced up with probability ``zone.nlos_prob`` while the tag is in
an NLOS zone along the path (support pylons). Every scheduled attempt is a row: dropped, outage and
out-of-link attempts keep a NaN range and their :class:`~physynth.records.Reason`.

Geometry-aware parts, each optional and off by default (a scenario without them draws exactly the
same numbers as before they existed):

- obstacles (``uwb.obstacles``: boxes, walls, prisms; ``uwb.terrain``: a height grid,
  :mod:`physynth.models.obstacles`): an attempt whose tag-anchor segment meets one is NLOS (z = 1)
  for exactly as long as the segment crosses it, with an offset drawn from the anchor's NLOS mixture;
- a link budget (``channel.link_budget``, :class:`LinkBudgetParams`): the received first-path power
  P(r) = P0 - 10 n log10(r / r0) + G_ant + G_ground - L_obst [dBm] and the detection probability
  Phi((P(r) - sensitivity) / sigma_shadow), multiplied into the soft radio horizon;
- per-anchor antenna orientation (``AnchorSpec.boresight_enu``, ``front_back_db``: a cardioid-like
  gain -front_back_db * (1 - cos theta) / 2) and height (the two-ray ground reflection of the link
  budget, ``ground_reflection``: interference nulls where the ground path is a whole number of
  wavelengths longer, the pattern the Hanyang static sweeps show at every antenna height).

One module per effect; :func:`~physynth.models.uwb.simulate.simulate_uwb` composes them (docs/design.md,
"Adding a model effect").
"""

from .arrays import ChannelArrays, EpisodeLaw, LinkBudgetArrays, episode_law
from .channel import channel_arrays
from .link_budget import (
    detection_probability,
    ground_gain_db,
    link_detection_probability,
    link_probability,
    received_power_dbm,
)
from .nlos import ZONE_MARGIN, episode_switches, nlos_episodes, nlos_states, zone_nlos_prob_at
from .params import AnchorSpec, ChannelOverride, ChannelParams, LinkBudgetParams, NlosMode, NlosZone, UwbParams
from .pattern import heading_at, heading_unit, pattern_features, relative_bearing, tag_pattern_bias
from .ranging_error import (
    BIAS_RANGE_FLOOR_M,
    los_error_mean,
    los_errors,
    range_decades,
    range_error,
    range_error_log_components,
    sample_nlos_offset,
)
from .run_effects import LAG_MARGIN_STDS, run_offsets, run_slopes, trace_time_offset
from .schedule import burst_times, late_stamps
from .simulate import UwbAttempts, simulate_uwb, uwb_record
from .sway import SWAY_STEPS_PER_TAU, TURN_MIN_SPEED_MPS, antenna_sway, motion_clock, sway_at, travelled_m, turned_rad
from .tag_nlos import TAG_MODE_MAX_M, TagRows, tag_mode_index, tag_nlos

__all__ = [
    "AnchorSpec",
    "BIAS_RANGE_FLOOR_M",
    "ChannelArrays",
    "ChannelOverride",
    "ChannelParams",
    "EpisodeLaw",
    "LAG_MARGIN_STDS",
    "LinkBudgetArrays",
    "LinkBudgetParams",
    "NlosMode",
    "NlosZone",
    "SWAY_STEPS_PER_TAU",
    "TAG_MODE_MAX_M",
    "TURN_MIN_SPEED_MPS",
    "TagRows",
    "UwbAttempts",
    "UwbParams",
    "ZONE_MARGIN",
    "antenna_sway",
    "burst_times",
    "channel_arrays",
    "detection_probability",
    "episode_law",
    "episode_switches",
    "ground_gain_db",
    "heading_at",
    "heading_unit",
    "late_stamps",
    "link_detection_probability",
    "link_probability",
    "los_error_mean",
    "los_errors",
    "motion_clock",
    "nlos_episodes",
    "nlos_states",
    "pattern_features",
    "range_decades",
    "range_error",
    "range_error_log_components",
    "received_power_dbm",
    "relative_bearing",
    "run_offsets",
    "run_slopes",
    "sample_nlos_offset",
    "simulate_uwb",
    "sway_at",
    "tag_mode_index",
    "tag_nlos",
    "tag_pattern_bias",
    "trace_time_offset",
    "travelled_m",
    "turned_rad",
    "uwb_record",
    "zone_nlos_prob_at",
]
