"""The UWB model's parameters: the acquisition (:class:`UwbParams`), the channel of an anchor
(:class:`ChannelParams`, its NLOS modes, zones and link budget) and the anchors.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from .._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat, Probability, Vec3
from ..obstacles import Obstacle, TerrainGrid


class NlosMode(ParamsModel):
    """One Gaussian component of the NLOS range offset delta [m].

    ``weight`` is the share of NLOS measurements in this mode. An NLOS episode keeps one mode (one
    reflector) for its whole length, of mean ``dwell_s`` (default: ``uwb.nlos_dwell_s``), exponential
    unless ``fixed_dwell`` (every episode lasts exactly ``dwell_s``: a wrong range that the radio keeps
    reporting for a fixed hold time, as the Hanyang gross outliers do for ~3 attempts).

    ``held_jitter_m``: when set, an episode draws its offset N(mean_m, std_m^2) once and keeps it
    (one reflector, one excess path), each row adding only N(0, held_jitter_m^2); when None (default)
    every row of the episode draws its own offset.
    """

    weight: PositiveFloat
    mean_m: FiniteFloat
    std_m: PositiveFloat
    dwell_s: PositiveFloat | None = None
    fixed_dwell: bool = False
    held_jitter_m: PositiveFloat | None = None


class NlosZone(ParamsModel):
    """A stretch of path (e.g. around a support pylon) where NLOS probability rises."""

    s_m: NonNegFloat
    half_width_m: PositiveFloat
    nlos_prob: Probability
    label: str = "pylon"


class LinkBudgetParams(ParamsModel):
    """Detection probability from a link budget (log-distance path loss, shadowing, sensitivity).

    The first-path power received at range r [m] is

        P(r) = ref_power_dbm - 10 * path_loss_exponent * log10(max(r, ref_distance_m) / ref_distance_m)
               + G_antenna + G_ground - L_obstacles   [dBm]

    and an attempt is detected with probability Phi((P(r) - sensitivity_dbm) / shadowing_std_db)
    (log-normal shadowing, independent per attempt; a step when ``shadowing_std_db`` is 0). ``G_antenna``
    is the anchor's orientation gain (:class:`AnchorSpec`), ``L_obstacles`` the ``loss_db`` of the
    obstacles met. ``G_ground`` is the two-ray ground term, on when ``ground_reflection`` > 0: with
    antenna heights h_a, h_t above the ground plane U = ``ground_u_m`` and horizontal distance d, the
    ground path is longer by Delta = sqrt(d^2 + (h_a + h_t)^2) - sqrt(d^2 + (h_a - h_t)^2) and
    G_ground = 20 log10 |1 - rho e^(-j 2 pi Delta / wavelength_m)| with rho = ``ground_reflection``.
    h_t is the tag's height above U, or ``tag_height_m`` where set: the tag antenna's own height when
    the path follows another point of the carrier (a walker's RTK antenna, a vehicle's reference).
    Defaults: a free-space budget of a DW1000-class radio on channel 5 at the regulatory limit
    (-41.3 dBm/MHz over 500 MHz, 48.7 dB free-space loss at 1 m: P0 = -63 dBm; sensitivity -106 dBm in
    the 110 kb/s mode; 4 dB outdoor shadowing): 50 % detection near 140 m. A fit to a recording:
    :func:`physynth.calibrate.link_budget.fit_link_budget_hanyang_static` (docs/anchors.md).
    """

    ref_power_dbm: FiniteFloat = -63.0
    ref_distance_m: PositiveFloat = 1.0
    path_loss_exponent: PositiveFloat = 2.0
    sensitivity_dbm: FiniteFloat = -106.0
    shadowing_std_db: NonNegFloat = 4.0
    ground_reflection: Probability = 0.0
    ground_u_m: FiniteFloat = 0.0
    wavelength_m: PositiveFloat = 0.0462
    tag_height_m: PositiveFloat | None = None


class ChannelParams(ParamsModel):
    """Ranging channel of one anchor: LOS Gaussian, NLOS mixture, effective rate and link range.

    The LOS error has mean ``los_mean_m + range_bias_per_m * r + range_bias_per_decade_m * log10(r / 1 m)``
    (r the true range; :func:`los_error_mean`): a clock-scale term and a received-power term.

    ``link_budget`` (optional, off by default) makes detection fall with distance, antenna gain and
    obstacle loss (:class:`LinkBudgetParams`).
    """

    rate_hz: PositiveFloat = 18.5
    los_mean_m: FiniteFloat = 0.0
    los_std_m: PositiveFloat = 0.1
    range_bias_per_m: FiniteFloat = 0.0
    range_bias_per_decade_m: FiniteFloat = 0.0
    nlos_prob: Probability = 0.0
    nlos_modes: list[NlosMode] = Field(default=[NlosMode(weight=1.0, mean_m=1.0, std_m=0.5)], min_length=1)
    max_range_m: PositiveFloat = 300.0
    edge_width_m: PositiveFloat = 5.0
    link_budget: LinkBudgetParams | None = None


class ChannelOverride(ParamsModel):
    """Per-anchor changes to the default channel; fields left out keep the default."""

    rate_hz: PositiveFloat | None = None
    los_mean_m: FiniteFloat | None = None
    los_std_m: PositiveFloat | None = None
    range_bias_per_m: FiniteFloat | None = None
    range_bias_per_decade_m: FiniteFloat | None = None
    nlos_prob: Probability | None = None
    nlos_modes: list[NlosMode] | None = None
    max_range_m: PositiveFloat | None = None
    edge_width_m: PositiveFloat | None = None
    link_budget: LinkBudgetParams | None = None


class UwbParams(ParamsModel):
    """Burst-based acquisition shared by all anchors.

    The tag ranges in bursts near ``burst_rate_hz`` (period jitter ``burst_jitter_s``); within a burst
    anchor j is ranged ``j * slot_s`` after the burst start, and only with probability
    rate_hz / burst_rate_hz (effective per-anchor rate). Stamps lag true time by ``time_offset_s``;
    with ``time_offset_std_s`` > 0 each trace draws its own lag ~ N(``time_offset_s``,
    ``time_offset_std_s``^2) once (the clocks of the ranging and the truth system are aligned anew for
    every run), kept in the trace's ``meta["uwb_time_offset_s"]``.
    The bursts are locked to the tag clock; ``burst_phase_s`` is the stamp time of the first burst
    after the trace start, modulo the period (``None``: drawn uniformly per trace, the usual choice for
    training data; a number: a recording's own alignment, which decides how often a burst straddles
    two 10 ms grid bins and so the grid availability metrics).
    NLOS episodes last ``nlos_dwell_s`` on average.

    Run-to-run ranging offsets: each trace adds one offset ~ N(0, ``run_offset_std_m``^2) to every
    range of every anchor (a truth-system or tag-antenna offset that changes from run to run) and one
    offset ~ N(0, ``run_anchor_offset_std_m``^2) per anchor (an anchor re-placed and re-surveyed for
    each run). Run-to-run range law: each trace also tilts the range law about
    ``run_slope_ref_range_m`` by a slope ~ N(0, ``run_slope_std_m``^2) common to its anchors plus one ~
    N(0, ``run_anchor_slope_std_m``^2) per anchor [m per decade of range]: every range gains
    slope * log10(r / ``run_slope_ref_range_m``) (the real walks' received-power bias grows by 13-15 cm
    per decade of range in one run and 20-26 cm in the three others, every anchor of a run alike;
    docs/calibration.md). All four are 0 by default; they, and the per-trace lag, are drawn after every
    other draw of the trace's UWB stream, so a scenario without them generates exactly what it did
    before they existed.
    ``obstacles`` and ``terrain`` (optional) block the line of sight: an attempt whose tag-anchor
    segment meets one is NLOS (:mod:`physynth.models.obstacles`), in addition to the ``zones``.

    Antenna sway: the UWB antenna is not exactly at the truth point (a tag worn on a walking body, a
    truth system's reference elsewhere on the carrier). With ``antenna_sway_std_m`` > 0 its offset
    from the truth is a 3-D Ornstein-Uhlenbeck process, std ``antenna_sway_std_m`` per ENU axis and
    correlation time ``antenna_sway_tau_s`` (stationary from the trace start), and every range is
    measured from the antenna: its error gains u . offset, with u the unit vector from the anchor to
    the tag. A slow error shared by the anchors the tag sees in one direction, as the real ranges of a
    walk have (docs/calibration.md). It draws from its own stream (``uwb_sway``); 0 (the default) draws
    nothing. ``antenna_sway_clock``: what the offset evolves with: ``time`` (correlation time
    ``antenna_sway_tau_s``), ``distance``, the path the tag has travelled (correlation length
    ``antenna_sway_length_m``), or ``motion``: the distance over ``antenna_sway_length_m`` plus the angle
    the carrier turned over ``antenna_sway_turn_rad`` (:func:`motion_clock`). On the two motion clocks
    the offset holds while the tag stands still and changes faster on a faster or turning carrier, as
    the real walks' slow error does (it holds over 3 s of standing still and changes most where the
    walker turns; docs/calibration.md).

    Tag antenna pattern: the tag's antenna delays a range by an amount that depends on where the anchor
    lies as seen from the carrier, which holds the antenna in one way relative to its direction of
    travel. ``tag_pattern_m`` = (c1, s1, c2, s2) adds c1 cos(phi) + s1 sin(phi) + c2 cos(2 phi) +
    s2 sin(2 phi) [m] to every range, phi being the anchor's horizontal bearing from the tag relative to
    the tag's heading (0 ahead, pi/2 to the left; :func:`relative_bearing`), the heading being the
    direction of horizontal travel, held while the carrier stands (:func:`heading_unit`). The real walks'
    ranges are about 3.7 cm longer with the anchors ahead or behind than beside the walker (c2 = 1.84 cm
    pooled over four runs), and step by up to as much at the turns (docs/calibration.md). Deterministic;
    all zero (the default) adds nothing.

    Tag-side NLOS: with ``tag_nlos_prob`` > 0, part of the NLOS time is the tag's own (a body, a pole
    or the ground next to the tag antenna): one episode process for the whole tag (long-run fraction
    ``tag_nlos_prob``, episodes of mean ``nlos_dwell_s``) whose episodes strike every anchor at once,
    with one error draw per burst shared by all of them (:func:`tag_nlos`). A far tag sees its anchors
    within a narrow angle, so the real walks' wide range errors come to all anchors together (their
    range differences, which carry the direction to the tag, stay clean). Each anchor's own episodes
    are thinned so that its NLOS fraction and mode mixture stay what its channel says
    (:func:`channel_arrays`). Draws from its own stream (``uwb_tag``); 0 (the default) draws nothing.

    Late stamps: with ``late_burst_prob`` > 0 each burst is, with that probability, a late one: every
    range it delivers after its first is stamped ``late_burst_delay_s`` later than its attempt (measured
    in its slot, delivered late by the receiving chain; the rows are then sorted by stamp). About 1.5 %
    of the real walks' bursts are such, their rows after the first stamped ~31 ms late, from every anchor
    alike, and the late rows' residuals follow the range rate times that delay, so the delay is on the
    stamp, not on the measurement (docs/calibration.md). A late row falls in a later 10 ms grid bin than
    its burst, which the grid availability metrics count. Draws from its own stream (``uwb_late``,
    :func:`late_stamps`); 0 (the default) draws nothing.
    """

    burst_rate_hz: PositiveFloat = 23.0
    burst_jitter_s: NonNegFloat = 0.003
    burst_phase_s: NonNegFloat | None = None
    slot_s: NonNegFloat = 0.0015
    time_offset_s: FiniteFloat = 0.0
    time_offset_std_s: NonNegFloat = 0.0
    nlos_dwell_s: PositiveFloat = 0.5
    zones: list[NlosZone] = []
    run_offset_std_m: NonNegFloat = 0.0
    run_anchor_offset_std_m: NonNegFloat = 0.0
    run_slope_std_m: NonNegFloat = 0.0
    run_anchor_slope_std_m: NonNegFloat = 0.0
    run_slope_ref_range_m: PositiveFloat = 10.0
    obstacles: list[Obstacle] = []
    terrain: TerrainGrid | None = None
    antenna_sway_std_m: NonNegFloat = 0.0
    antenna_sway_tau_s: PositiveFloat = 2.0
    antenna_sway_clock: Literal["time", "distance", "motion"] = "time"
    antenna_sway_length_m: PositiveFloat = 2.0
    antenna_sway_turn_rad: PositiveFloat = 1.0
    tag_nlos_prob: Probability = 0.0
    tag_pattern_m: Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)] = [0.0, 0.0, 0.0, 0.0]
    late_burst_prob: Probability = 0.0
    late_burst_delay_s: NonNegFloat = 0.03


class AnchorSpec(ParamsModel):
    """One anchor: id, antenna position in ENU [m] and (optionally) its antenna orientation.

    ``boresight_enu`` (a direction, normalised here) and ``front_back_db`` give the antenna gain
    G(theta) = -front_back_db * (1 - cos theta) / 2 [dB] towards a tag seen at angle theta from the
    boresight: 0 dB in front, -front_back_db behind (an anchor on a wall or a mast facing the route).
    It enters the link budget only (:class:`LinkBudgetParams`); without one it has no effect.
    """

    id: Annotated[str, Field(min_length=1)]
    pos_enu_m: Vec3
    name: str | None = None
    boresight_enu: Vec3 | None = None
    front_back_db: NonNegFloat = 0.0
