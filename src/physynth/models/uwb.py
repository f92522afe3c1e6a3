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
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import accumulate
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..records import Reason, Uwb
from ._interp import interp_many
from ._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat, Probability, Vec3
from .motion import Kinematics
from .obstacles import Obstacle, TerrainGrid, obstacle_losses
from .renewal import by_label, initial_pairs, is_ascending, rows_by_label, switch_counts


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


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelArrays:
    """Per-anchor parameters of a scenario as arrays (A,) / (A, M) for vectorised sampling."""

    anchor_pos_enu_m: np.ndarray
    attempt_prob: np.ndarray
    los_mean_m: np.ndarray
    los_std_m: np.ndarray
    range_bias_per_m: np.ndarray
    range_bias_per_decade_m: np.ndarray
    nlos_prob: np.ndarray
    mode_cumw: np.ndarray  # (A, M) cumulative weights, last column 1
    mode_mean_m: np.ndarray  # (A, M)
    mode_std_m: np.ndarray  # (A, M)
    mode_dwell_s: np.ndarray  # (A, M) mean NLOS episode length per mode
    mode_fixed_dwell: np.ndarray  # (A, M) bool: episodes of exactly mode_dwell_s
    mode_held_jitter_m: np.ndarray  # (A, M) per-row jitter of a held offset; NaN: offset drawn per row
    max_range_m: np.ndarray
    edge_width_m: np.ndarray
    zone_s_m: np.ndarray  # (Z,)
    zone_half_width_m: np.ndarray
    zone_nlos_prob: np.ndarray
    link: LinkBudgetArrays | None = None  # None: no anchor has a link budget
    obstacles: tuple = ()
    terrain: TerrainGrid | None = None
    tag_prob: float = 0.0  # long-run fraction of tag-side NLOS time (UwbParams.tag_nlos_prob)
    tag_mode: np.ndarray | None = None  # (A,) the mode a tag-side episode gives each anchor (tag_mode_index)
    tag_join: np.ndarray | None = None  # (A,) probability that an anchor takes part in a tag-side episode
    tag_drop: np.ndarray | None = None  # (A,) probability that an own episode of mode tag_mode is dropped
    # derived from the fields above on construction: each anchor's NLOS episode law (None where
    # nlos_prob is 0 or 1: no episodes), the per-scenario constants of nlos_episodes
    episode_laws: tuple[EpisodeLaw | None, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        weights_of = np.diff(self.mode_cumw, axis=1, prepend=0.0)  # mode weights of every anchor
        laws = tuple(episode_law(float(p), weights_of[i], self.mode_dwell_s[i], self.mode_fixed_dwell[i])
                     if 0 < p < 1 else None for i, p in enumerate(self.nlos_prob.tolist()))
        object.__setattr__(self, "episode_laws", laws)


@dataclass(frozen=True, slots=True, kw_only=True)
class EpisodeLaw:
    """The constants of one anchor's NLOS episodes (:func:`nlos_episodes`): cumulative episode-mode
    probabilities, mean episode length per mode, the modes of fixed length (None: none), the mean LOS
    gap and the mean cycle (episode + gap) [s]."""

    nlos_prob: float
    cum_q: np.ndarray
    dwell_s: np.ndarray
    fixed: np.ndarray | None
    mean_off_s: float
    mean_cycle_s: float


def episode_law(nlos_prob: float, weights: np.ndarray, dwell_s: np.ndarray,
                fixed_dwell: np.ndarray | None = None) -> EpisodeLaw:
    """The :class:`EpisodeLaw` of :func:`nlos_episodes`'s parameters (0 < ``nlos_prob`` < 1)."""
    q = weights / dwell_s
    q = q / q.sum()
    mean_on = float((q * dwell_s).sum())
    mean_off = mean_on * (1.0 - nlos_prob) / nlos_prob
    fixed = fixed_dwell if fixed_dwell is not None and fixed_dwell.any() else None  # None: no mode is fixed
    return EpisodeLaw(nlos_prob=nlos_prob, cum_q=q.cumsum(), dwell_s=dwell_s, fixed=fixed, mean_off_s=mean_off,
                      mean_cycle_s=mean_on + mean_off)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkBudgetArrays:
    """Per-anchor link budgets (A,); anchors without one have ``enabled`` False (detection 1)."""

    enabled: np.ndarray
    ref_power_dbm: np.ndarray
    ref_distance_m: np.ndarray
    path_loss_exponent: np.ndarray
    sensitivity_dbm: np.ndarray
    shadowing_std_db: np.ndarray
    ground_reflection: np.ndarray
    ground_u_m: np.ndarray
    wavelength_m: np.ndarray
    tag_height_m: np.ndarray  # NaN: the tag's height above ground_u_m
    boresight_enu: np.ndarray  # (A, 3) unit vectors, zeros where omnidirectional
    front_back_db: np.ndarray


def _link_arrays(anchors: Sequence[AnchorSpec], chans: Sequence[ChannelParams]) -> LinkBudgetArrays | None:
    if all(c.link_budget is None for c in chans):
        return None
    lbs = [c.link_budget or LinkBudgetParams() for c in chans]
    bore = np.zeros((len(anchors), 3))
    for i, a in enumerate(anchors):
        if a.boresight_enu is not None:
            v = np.asarray(a.boresight_enu, dtype=float)
            norm = np.linalg.norm(v)
            bore[i] = v / norm if norm > 0 else 0.0
    return LinkBudgetArrays(
        enabled=np.array([c.link_budget is not None for c in chans]),
        **{f: np.array([np.nan if getattr(lb, f) is None else getattr(lb, f) for lb in lbs], dtype=float)
           for f in LinkBudgetParams.model_fields},
        boresight_enu=bore,
        front_back_db=np.array([a.front_back_db for a in anchors], dtype=float),
    )


def channel_arrays(params: UwbParams, anchors: Sequence[AnchorSpec],
                   channels: Sequence[ChannelParams]) -> ChannelArrays:
    """Arrays of the per-anchor channels (``channels`` resolved per anchor, in anchor order)."""
    chans = list(channels)
    m = max(len(c.nlos_modes) for c in chans)
    cumw = np.ones((len(chans), m))
    mean = np.zeros((len(chans), m))
    std = np.ones((len(chans), m))
    dwell = np.full((len(chans), m), params.nlos_dwell_s)
    fixed = np.zeros((len(chans), m), dtype=bool)
    jitter = np.full((len(chans), m), np.nan)
    for i, c in enumerate(chans):
        w = np.array([mode.weight for mode in c.nlos_modes])
        k = w.size
        cumw[i, :k] = np.cumsum(w) / w.sum()
        mean[i, :k] = [mode.mean_m for mode in c.nlos_modes]
        std[i, :k] = [mode.std_m for mode in c.nlos_modes]
        dwell[i, :k] = [mode.dwell_s or params.nlos_dwell_s for mode in c.nlos_modes]
        fixed[i, :k] = [mode.fixed_dwell for mode in c.nlos_modes]
        jitter[i, :k] = [np.nan if mode.held_jitter_m is None else mode.held_jitter_m for mode in c.nlos_modes]
        mean[i, k:], std[i, k:], dwell[i, k:] = mean[i, k - 1], std[i, k - 1], dwell[i, k - 1]
        fixed[i, k:], jitter[i, k:] = fixed[i, k - 1], jitter[i, k - 1]
    nlos_prob = np.array([c.nlos_prob for c in chans])
    tag = _tag_thinning(params.tag_nlos_prob, nlos_prob, cumw, mean, std) if params.tag_nlos_prob > 0 else {}
    z = params.zones
    return ChannelArrays(
        anchor_pos_enu_m=np.array([a.pos_enu_m for a in anchors], dtype=float),
        attempt_prob=np.array([c.rate_hz for c in chans]) / params.burst_rate_hz,
        los_mean_m=np.array([c.los_mean_m for c in chans]),
        los_std_m=np.array([c.los_std_m for c in chans]),
        range_bias_per_m=np.array([c.range_bias_per_m for c in chans]),
        range_bias_per_decade_m=np.array([c.range_bias_per_decade_m for c in chans]),
        nlos_prob=nlos_prob, mode_cumw=cumw, mode_mean_m=mean, mode_std_m=std, mode_dwell_s=dwell,
        mode_fixed_dwell=fixed,
        mode_held_jitter_m=jitter,
        max_range_m=np.array([c.max_range_m for c in chans]),
        edge_width_m=np.array([c.edge_width_m for c in chans]),
        zone_s_m=np.array([q.s_m for q in z]), zone_half_width_m=np.array([q.half_width_m for q in z]),
        zone_nlos_prob=np.array([q.nlos_prob for q in z]),
        link=_link_arrays(anchors, chans),
        obstacles=tuple(params.obstacles),
        terrain=params.terrain,
        tag_prob=float(params.tag_nlos_prob) if tag else 0.0,
        tag_mode=tag.get("mode"), tag_join=tag.get("join"), tag_drop=tag.get("drop"),
    )


TAG_MODE_MAX_M = 0.5
"""A tag-side episode gives an anchor its near-LOS NLOS mode: the heaviest mode whose mean offset and
std are both within this [m] (a mode of gross outliers, metres off, is the anchor's own radio's)."""


def tag_mode_index(weights: np.ndarray, mean_m: np.ndarray, std_m: np.ndarray) -> int:
    """Index of the NLOS mode a tag-side episode gives (see :data:`TAG_MODE_MAX_M`); -1: none."""
    ok = (np.asarray(weights) > 0) & (np.abs(mean_m) <= TAG_MODE_MAX_M) & (np.asarray(std_m) <= TAG_MODE_MAX_M)
    return int(np.argmax(np.where(ok, weights, -1.0))) if ok.any() else -1


def _tag_thinning(p_tag: float, nlos_prob: np.ndarray, cumw: np.ndarray, mean: np.ndarray,
                  std: np.ndarray) -> dict[str, np.ndarray]:
    """How each anchor's own NLOS episodes make room for a tag-side process of fraction ``p_tag``.

    A tag-side episode gives anchor a its near-LOS mode n (:func:`tag_mode_index`; an anchor without
    one does not join) and is joined by the anchor with probability j = min(1, p_a w_n / p_tag), so the
    tag side brings t = p_tag j of NLOS time in mode n where the anchor's own process is LOS. The
    anchor's own process is drawn as its channel says (the same draws as without a tag side); each of
    its episodes of mode n is then dropped with probability d = (p_a - q) / (p_a w_n), q = (p_a - t) /
    (1 - t), which leaves own NLOS time q: the union q + (1 - q) t is p_a, and the other modes keep
    their time p_a w_m, so the NLOS fraction and every mode's time share stay those of the channel.
    Returns per anchor the tag ``mode``, the ``join`` and ``drop`` probabilities (anchors with p_a of 0
    or 1 keep their own process and do not join).
    """
    weights = np.diff(cumw, axis=1, prepend=0.0)
    found = np.array([tag_mode_index(weights[i], mean[i], std[i]) for i in range(nlos_prob.size)], dtype=np.intp)
    mode = np.maximum(found, 0)
    w_n = np.where(found >= 0, weights[np.arange(nlos_prob.size), mode], 0.0)
    open_ = (nlos_prob > 0) & (nlos_prob < 1) & (found >= 0) & (w_n > 0)
    join = np.where(open_, np.minimum(1.0, nlos_prob * w_n / p_tag), 0.0)
    t = p_tag * join
    q = np.where(open_, (nlos_prob - t) / (1.0 - t), nlos_prob)
    near = np.where(open_, nlos_prob * w_n, 1.0)
    drop = np.where(open_, np.clip((nlos_prob - q) / near, 0.0, 1.0), 0.0)
    return {"mode": mode, "join": join, "drop": drop}


def burst_times(t_start_s: float, t_end_s: float, burst_rate_hz: float, jitter_s: float, min_period_s: float,
                *, rng: np.random.Generator, phase_s: float | None = None) -> np.ndarray:
    """Tag burst start times in [t_start, t_end).

    The tag's clock locks the bursts to a fixed period (random phase at the start); each burst is
    displaced by its own Gaussian jitter of standard deviation ``jitter_s``, so consecutive periods
    scatter by ``sqrt(2) * jitter_s`` without the schedule drifting. Bursts keep at least
    ``min_period_s`` apart (room for every anchor slot).
    """
    period = 1.0 / burst_rate_hz
    n = int(np.ceil((t_end_s - t_start_s) * burst_rate_hz)) + 2
    first = rng.uniform(0.0, period) if phase_s is None else float(phase_s) % period
    t = np.arange(n, dtype=np.float64)  # t_start + first + period k, in one buffer (the same values)
    t *= period
    t += t_start_s + first
    if jitter_s > 0:
        jitter = rng.standard_normal(n)
        jitter *= jitter_s
        np.maximum(jitter, -0.45 * period, out=jitter)  # numpy.clip's values
        np.minimum(jitter, 0.45 * period, out=jitter)
        t += jitter
        gap = np.subtract(t[1:], t[:-1])  # numpy.diff's values
        np.maximum(gap, min_period_s, out=gap)
        np.cumsum(gap, out=t[1:])  # t_0 + the cumulative gaps, into t (t_0 itself stays)
        t[1:] += t[0]
        if not min_period_s >= 0:  # gaps of either sign: not sorted
            return t[(t >= t_start_s) & (t < t_end_s)]
    # sorted times (periods, or gaps of at least min_period_s >= 0): those in [t_start, t_end) are one run
    return t[t.searchsorted(t_start_s, side="left"):t.searchsorted(t_end_s, side="left")]


def link_probability(range_m: np.ndarray, max_range_m: np.ndarray, edge_width_m: np.ndarray) -> np.ndarray:
    """Soft radio horizon: 1 / (1 + exp((r - max_range) / edge_width)), the exponent clipped to [-50, 50]."""
    x = np.subtract(range_m, max_range_m)
    if not isinstance(x, np.ndarray) or x.dtype != np.float64:  # scalars: no buffer to work in
        return 1.0 / (1.0 + np.exp(np.clip(x / edge_width_m, -50.0, 50.0)))
    x /= edge_width_m  # the steps of the line above, in one buffer (numpy.clip's values: max, then min)
    np.maximum(x, -50.0, out=x)
    np.minimum(x, 50.0, out=x)
    np.exp(x, out=x)
    x += 1.0
    return np.divide(1.0, x, out=x)


def ground_gain_db(horiz_m: np.ndarray, h_anchor_m: np.ndarray, h_tag_m: np.ndarray, reflection: np.ndarray,
                   wavelength_m: np.ndarray) -> np.ndarray:
    """Two-ray ground term 20 log10 |1 - rho exp(-j 2 pi Delta / lambda)| [dB] (0 where rho is 0).

    Heights above the ground plane [m] are clipped at 1 cm; Delta is the extra length of the ground path.
    """
    ha = np.maximum(h_anchor_m, 0.01)
    ht = np.maximum(h_tag_m, 0.01)
    delta = np.hypot(horiz_m, ha + ht) - np.hypot(horiz_m, ha - ht)
    phase = 2.0 * np.pi * delta / wavelength_m
    mag = np.hypot(1.0 - reflection * np.cos(phase), reflection * np.sin(phase))
    return 20.0 * np.log10(np.maximum(mag, 1e-6))


def received_power_dbm(tag_enu_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays,
                       obstacle_loss_db: np.ndarray | float = 0.0) -> np.ndarray:
    """Mean first-path power [dBm] of rows (tag (N, 3) [m], anchor index (N,)) under the link budget."""
    lb = ch.link
    assert lb is not None
    d = tag_enu_m - ch.anchor_pos_enu_m[anchor]  # anchor -> tag
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    r0 = lb.ref_distance_m[anchor]
    p = lb.ref_power_dbm[anchor] - 10.0 * lb.path_loss_exponent[anchor] * np.log10(np.maximum(r, r0) / r0)
    bore = lb.boresight_enu[anchor]
    cos_t = np.einsum("ij,ij->i", bore, d) / np.maximum(r, 1e-9)
    has_bore = np.any(bore != 0.0, axis=1)
    p = p - np.where(has_bore, lb.front_back_db[anchor] * (1.0 - cos_t) / 2.0, 0.0)
    rho = lb.ground_reflection[anchor]
    if np.any(rho > 0):
        g = lb.ground_u_m[anchor]
        h_tag = lb.tag_height_m[anchor]
        h_tag = np.where(np.isnan(h_tag), tag_enu_m[:, 2] - g, h_tag)
        p = p + ground_gain_db(np.hypot(d[:, 0], d[:, 1]), ch.anchor_pos_enu_m[anchor, 2] - g, h_tag,
                               rho, lb.wavelength_m[anchor])
    return p - obstacle_loss_db


def detection_probability(power_dbm: np.ndarray, sensitivity_dbm: np.ndarray,
                          shadowing_std_db: np.ndarray) -> np.ndarray:
    """P(power + shadowing > sensitivity) = Phi((power - sensitivity) / sigma) (a step where sigma is 0)."""
    from scipy.special import ndtr

    margin = power_dbm - sensitivity_dbm
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = ndtr(margin / np.where(shadowing_std_db > 0, shadowing_std_db, 1.0))
    return np.where(shadowing_std_db > 0, soft, (margin >= 0).astype(float))


def link_detection_probability(tag_enu_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays,
                               obstacle_loss_db: np.ndarray | float = 0.0) -> np.ndarray:
    """Per-row detection probability of the link budget (1 for anchors without one)."""
    lb = ch.link
    if lb is None:
        return np.ones(anchor.shape[0])
    p = detection_probability(received_power_dbm(tag_enu_m, anchor, ch, obstacle_loss_db),
                              lb.sensitivity_dbm[anchor], lb.shadowing_std_db[anchor])
    return np.where(lb.enabled[anchor], p, 1.0)


def sample_nlos_offset(anchor: np.ndarray, ch: ChannelArrays, *, rng: np.random.Generator,
                       mode: np.ndarray | None = None) -> np.ndarray:
    """NLOS offsets delta [m] for rows of the given anchors (Gaussian mixture per anchor).

    ``mode`` fixes each row's mixture component (the episode's reflector); drawn by weight otherwise.
    """
    if mode is None:
        u = rng.random(anchor.shape[0])
        mode = np.minimum((u[:, None] > ch.mode_cumw[anchor]).sum(axis=1), ch.mode_cumw.shape[1] - 1)
    flat = np.multiply(anchor, ch.mode_mean_m.shape[1], dtype=np.intp)  # [anchor, mode] as flat indices
    flat += mode
    return ch.mode_mean_m.ravel().take(flat) + ch.mode_std_m.ravel().take(flat) * rng.standard_normal(anchor.shape[0])


BIAS_RANGE_FLOOR_M = 0.1
"""Ranges below this [m] enter the received-power bias at this value (log10 of 0 is -inf)."""


def range_decades(true_range_m: np.ndarray | float) -> np.ndarray:
    """log10 of the true range in metres (floored at :data:`BIAS_RANGE_FLOOR_M`): the regressor of the
    received-power ranging bias (free-space path loss falls 20 dB per decade of range)."""
    return np.log10(np.maximum(true_range_m, BIAS_RANGE_FLOOR_M))


def los_error_mean(true_range_m: np.ndarray, los_mean_m: np.ndarray | float,
                   range_bias_per_m: np.ndarray | float,
                   range_bias_per_decade_m: np.ndarray | float = 0.0) -> np.ndarray:
    """Mean LOS range error mu_i + beta_i r + gamma_i log10(r / 1 m) [m].

    beta (``range_bias_per_m``) is a clock-scale error; gamma (``range_bias_per_decade_m``) the
    received-power bias of leading-edge detection, which grows with the path loss, i.e. linearly in
    log range. The gamma term is evaluated only where it is not zero, so scenarios without it draw
    exactly what they drew before it existed.
    """
    out = los_mean_m + range_bias_per_m * true_range_m
    if np.asarray(range_bias_per_decade_m).any():  # (a method: no function-wrapper overhead)
        out = out + range_bias_per_decade_m * range_decades(true_range_m)
    return out


def _norm_logpdf(x: np.ndarray, mean: np.ndarray | float, std: np.ndarray | float) -> np.ndarray:
    return -0.5 * ((x - mean) / std) ** 2 - np.log(std) - 0.5 * np.log(2.0 * np.pi)


def range_error_log_components(err_m: np.ndarray, true_range_m: np.ndarray, *, los_mean_m: float,
                               range_bias_per_m: float, los_std_m: float, nlos_prob: float,
                               mode_weights: np.ndarray, mode_mean_m: np.ndarray,
                               mode_std_m: np.ndarray, range_bias_per_decade_m: float = 0.0) -> np.ndarray:
    """Log joint density of each error component, shape (1 + K, N): row 0 LOS, rows 1.. the NLOS modes.

    This is the distribution :func:`range_error` samples from (eq. 3: NLOS replaces the LOS error),
    written as a mixture over the rows' marginal NLOS probability; the calibration's EM fit
    maximises its log-sum-exp.
    """
    comp = [np.log(max(1.0 - nlos_prob, 1e-300))
            + _norm_logpdf(err_m, los_error_mean(true_range_m, los_mean_m, range_bias_per_m, range_bias_per_decade_m),
                           los_std_m)]
    for w, m, sd in zip(mode_weights, mode_mean_m, mode_std_m, strict=True):
        comp.append(np.log(max(nlos_prob * w, 1e-300)) + _norm_logpdf(err_m, m, sd))
    return np.stack(comp)


def los_errors(true_range_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays, z: np.ndarray) -> np.ndarray:
    """LOS range errors [m] of rows from their standard normal draws ``z``: N(mu_i + beta_i r + gamma_i
    log10 r, sigma_i^2) of each row's anchor i."""
    decade = by_label(ch.range_bias_per_decade_m, anchor) if ch.range_bias_per_decade_m.any() else 0.0  # 0: off
    return (los_error_mean(true_range_m, by_label(ch.los_mean_m, anchor), by_label(ch.range_bias_per_m, anchor),
                           decade)
            + by_label(ch.los_std_m, anchor) * z)


def range_error(true_range_m: np.ndarray, anchor: np.ndarray, nlos: np.ndarray, mode: np.ndarray,
                ch: ChannelArrays, *, rng: np.random.Generator, episode: np.ndarray | None = None) -> np.ndarray:
    """Range errors [m] of rows: LOS Gaussian N(mu_i + beta_i r + gamma_i log10 r, sigma_i^2), replaced where
    NLOS by the offset of the episode's mixture mode (rows made NLOS by a zone alone draw a mode by weight).

    Rows of an episode (``episode``: one id per episode, -1 outside) of a mode with a held offset
    share one draw of the offset plus their own jitter; these draws come after all others, so a
    scenario without held modes draws exactly as before.
    """
    err = los_errors(true_range_m, anchor, ch, rng.standard_normal(true_range_m.shape[0]))
    in_episode = mode >= 0
    ep = np.flatnonzero(in_episode)  # row indices: the NLOS rows are few, each gather then a short one
    nl = np.flatnonzero(nlos)
    zone_only = nl[mode.take(nl) < 0]  # NLOS outside an episode
    err[ep] = sample_nlos_offset(anchor.take(ep), ch, rng=rng, mode=mode.take(ep))
    err[zone_only] = sample_nlos_offset(anchor.take(zone_only), ch, rng=rng)
    if episode is not None and ep.size and np.isfinite(ch.mode_held_jitter_m).any():  # a held mode
        jit = np.full(err.shape[0], np.nan)
        jit[in_episode] = ch.mode_held_jitter_m[anchor[in_episode], mode[in_episode]]
        held = np.isfinite(jit)
        if held.any():
            ids, first, inv = np.unique(episode[held], return_index=True, return_inverse=True)
            a_ep, m_ep = anchor[held][first], mode[held][first]
            value = ch.mode_mean_m[a_ep, m_ep] + ch.mode_std_m[a_ep, m_ep] * rng.standard_normal(ids.size)
            err[held] = value[inv] + jit[held] * rng.standard_normal(int(held.sum()))
    return err


def nlos_episodes(t_s: np.ndarray, nlos_prob: float, weights: np.ndarray, dwell_s: np.ndarray, *,
                  rng: np.random.Generator, fixed_dwell: np.ndarray | None = None, first_episode: int = 0,
                  ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NLOS state and mode at sorted times of one anchor: an alternating renewal process in which each
    NLOS episode keeps one mode m for an exponential time of mean ``dwell_s[m]``.

    Episodes pick mode m with probability proportional to weight_m / dwell_m, so that ``weights`` is
    the share of NLOS *time* in each mode; LOS gaps are exponential with the mean that makes the
    long-run NLOS fraction ``nlos_prob``. A mode with ``fixed_dwell`` lasts exactly ``dwell_s`` (the
    exponential draw is still made, so the stream does not depend on the flag). Returns (nlos (N,)
    bool, mode (N,) int, -1 where LOS, episode (N,) int: ``first_episode`` + index of the episode, -1
    where LOS). ``ascending``: as in :func:`~physynth.models.renewal.switch_counts`.
    """
    k, modes, start_on = episode_switches(t_s, episode_law(nlos_prob, weights, dwell_s, fixed_dwell), rng=rng,
                                          ascending=ascending)
    nlos = (k & 1) == (0 if start_on else 1)  # k >= 0: k & 1 is k % 2 and k >> 1 is k // 2
    pair = np.right_shift(k, 1, out=k)
    np.minimum(pair, modes.size - 1, out=pair)
    mode = np.where(nlos, modes.take(pair), -1)
    if first_episode:
        pair += first_episode
    return nlos, mode, np.where(nlos, pair, -1)


def episode_switches(t_s: np.ndarray, law: EpisodeLaw, *, rng: np.random.Generator,
                     ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
    """The draws of :func:`nlos_episodes`: (switch counts (N,) at the sorted times ``t_s``, the mode of
    each episode, whether the process starts in an episode). Even counts: the starting state; count k
    is in pair k // 2 (episode and gap)."""
    start_on = bool(rng.random() < law.nlos_prob)
    col_on = 0 if start_on else 1
    cum_q, dwell_s, fixed = law.cum_q, law.dwell_s, law.fixed

    def draw(n: int) -> tuple[np.ndarray, np.ndarray]:
        modes = np.minimum(cum_q.searchsorted(rng.random(n), side="right"), cum_q.size - 1)
        pairs = np.empty((n, 2))  # (on, off) or (off, on): the state the process starts in first
        on = rng.exponential(1.0, n)
        on *= dwell_s[modes]
        if fixed is not None:
            on = np.where(fixed[modes], dwell_s[modes], on)
        pairs[:, col_on] = on
        pairs[:, 1 - col_on] = rng.exponential(law.mean_off_s, n)
        return pairs, modes

    k, modes = switch_counts(t_s, draw, initial_pairs(float(t_s[-1] - t_s[0]), law.mean_cycle_s),
                             ascending=ascending)
    return k, modes, start_on


def nlos_states(t_s: np.ndarray, anchor: np.ndarray, s_m: np.ndarray | None, ch: ChannelArrays, *,
                rng: np.random.Generator, blocked: np.ndarray | None = None,
                rows_of: Sequence[np.ndarray] | None = None,
                forced_out: np.ndarray | None = None, zone_prob: np.ndarray | None = None,
                ascending: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NLOS indicator, mode and episode id of each row: per-anchor episodes, raised inside NLOS zones and
    where ``blocked`` (the line of sight meets an obstacle).

    Rows made NLOS by a zone or an obstacle (and not by an episode) draw their mode by weight (mode -1
    marks them). Episode ids are unique over anchors (-1 outside an episode). ``rows_of``: the rows of
    each anchor, ``rows_by_label(anchor, A)``, when the caller has them already. ``forced_out``: a
    boolean array of the rows, set where a zone or ``blocked`` makes a row NLOS (whatever its episodes).
    ``zone_prob``: the zones' NLOS probability of each row (:func:`zone_nlos_prob_at`) when the caller has
    it; ``s_m`` (the rows' path coordinates) is then not read and may be None. ``ascending``: whether
    ``t_s`` is known to be sorted (:func:`~physynth.models.renewal.is_ascending`; None: checked here).
    """
    nlos = np.zeros(t_s.shape[0], dtype=bool)
    mode = np.full(t_s.shape[0], -1, dtype=np.int64)
    episode = np.full(t_s.shape[0], -1, dtype=np.int64)
    if ascending is None:
        ascending = is_ascending(t_s)  # checked once for every anchor's rows
    if rows_of is None:
        rows_of = rows_by_label(anchor, ch.nlos_prob.shape[0])
    parts = []  # (rows, switch counts, episode modes, start_on) of each anchor with episodes
    for i, rows in enumerate(rows_of):  # one renewal process per anchor (the draws anchor by anchor)
        if rows.size == 0 or ch.nlos_prob[i] <= 0:
            continue
        if ch.nlos_prob[i] >= 1:
            nlos[rows] = True
            continue
        parts.append((rows, *episode_switches(t_s.take(rows), ch.episode_laws[i], rng=rng, ascending=ascending)))
    if parts:  # the anchors' rows are disjoint: their states in one pass over all of them
        _write_episodes(parts, nlos, mode, episode)
    forced = nlos if forced_out is None else forced_out  # the zone and obstacle rows: into nlos, or apart
    if ch.zone_s_m.size:
        p_zone = _zone_nlos_prob(s_m, ch) if zone_prob is None else zone_prob
        forced |= rng.random(t_s.shape[0]) < p_zone
    if blocked is not None:
        forced |= blocked
    if forced_out is not None:
        nlos |= forced_out
    return nlos, mode, episode


def _write_episodes(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, bool]], nlos: np.ndarray,
                    mode: np.ndarray, episode: np.ndarray) -> None:
    """Write the anchors' episode states into the columns at their rows: ``parts`` holds (rows, switch
    counts, episode modes, start_on) of each anchor (:func:`episode_switches`), in anchor order. The
    values of :func:`nlos_episodes` anchor by anchor, with ``first_episode`` running over the anchors
    (each anchor's episodes numbered after the last one of the anchors before it); LOS rows keep their
    state (False), mode and episode (-1). The switch counts are changed in place."""
    for _, k, _, start_on in parts:
        if not start_on:  # in an episode exactly where the count with its lowest bit flipped is even;
            np.bitwise_xor(k, 1, out=k)  # there, k >> 1 (the episode's pair) is that of the unflipped count
    k = np.concatenate([q[1] for q in parts])
    rows = np.concatenate([q[0] for q in parts])
    at = np.flatnonzero((k & 1) == 0)  # the few rows in an episode: state, pair, mode and id set there only
    pair = np.right_shift(k.take(at), 1)  # the (episode, gap) pair: k // 2
    mode_at = np.empty_like(pair)
    ends = at.searchsorted(list(accumulate(q[0].size for q in parts))).tolist()  # each anchor's rows in `at`
    start, first = 0, 0  # the anchor's first row in `at`, its first episode id
    for (_, _, modes, _), end in zip(parts, ends, strict=True):
        if end > start:
            p = pair[start:end]  # a view: clipped and numbered in place
            np.minimum(p, modes.size - 1, out=p)
            mode_at[start:end] = modes.take(p)
            last = int(p.max())
            p += first
            first += last + 1
        start = end
    dest = rows.take(at)
    nlos[dest] = True
    mode[dest] = mode_at
    episode[dest] = pair


def _zone_nlos_prob(s_m: np.ndarray, ch: ChannelArrays) -> np.ndarray:
    """(N,) NLOS probability of the zones at path coordinates ``s_m``: the largest of the zones that
    contain each point, 0 outside every zone. One zone at a time (no (N, Z) temporaries)."""
    p = None
    for z_s, half, prob in zip(ch.zone_s_m.tolist(), ch.zone_half_width_m.tolist(), ch.zone_nlos_prob.tolist(),
                               strict=True):
        dist = np.subtract(s_m, z_s)
        np.abs(dist, out=dist)
        here = np.where(dist <= half, prob, 0.0)
        p = here if p is None else np.maximum(p, here, out=p)
    return p


ZONE_MARGIN = 1e-9
"""Relative margin [of the path's scale] by which :func:`zone_nlos_prob_at` widens each zone when it
looks for the rows near it (interpolation rounds by a few ulp, some 1e-16 relative)."""


def zone_nlos_prob_at(t_s: np.ndarray, grid_t_s: np.ndarray, grid_s_m: np.ndarray, ch: ChannelArrays, *,
                      ascending: bool | None = None) -> np.ndarray:
    """``_zone_nlos_prob(numpy.interp(t_s, grid_t_s, grid_s_m), ch)`` (the zones' NLOS probability at the
    sorted times ``t_s`` of a run whose path coordinate is ``grid_s_m`` at ``grid_t_s``), bit for bit.

    When the path coordinate is monotone (the usual run: forwards or backwards along the path), each
    zone is met over one stretch of times: the path coordinate is interpolated only at the rows of that
    stretch (widened by a knot and :data:`ZONE_MARGIN`), the other rows lie outside the zone (0).
    ``ascending``: whether ``t_s`` is known to be sorted (None: checked here).
    """
    n, m = t_s.shape[0], grid_s_m.shape[0]
    if n == 0 or m < 2 or not (is_ascending(t_s) if ascending is None else ascending):
        return _zone_nlos_prob(np.interp(t_s, grid_t_s, grid_s_m), ch)
    forwards = bool(grid_s_m[0] <= grid_s_m[-1])
    key = grid_s_m if forwards else np.negative(grid_s_m)  # ascending when the run is monotone
    if not is_ascending(key):
        return _zone_nlos_prob(np.interp(t_s, grid_t_s, grid_s_m), ch)
    scale = 1.0 + max(abs(float(key[0])), abs(float(key[-1])))
    p = np.zeros(n)
    for z_s, half, prob in zip(ch.zone_s_m.tolist(), ch.zone_half_width_m.tolist(), ch.zone_nlos_prob.tolist(),
                               strict=True):
        centre = z_s if forwards else -z_s
        pad = half + ZONE_MARGIN * (scale + abs(z_s) + half)
        below = int(key.searchsorted(centre - pad, side="left")) - 1  # the last knot before the zone
        above = int(key.searchsorted(centre + pad, side="right"))  # the first knot past it
        lo = 0 if below < 0 else int(t_s.searchsorted(grid_t_s[below], side="left"))
        hi = n if above >= m else int(t_s.searchsorted(grid_t_s[above], side="right"))
        if hi > lo:
            dist = np.interp(t_s[lo:hi], grid_t_s, grid_s_m)
            dist -= z_s
            np.abs(dist, out=dist)
            np.maximum(p[lo:hi], np.where(dist <= half, prob, 0.0), out=p[lo:hi])
    return p


def tag_nlos(bursts_s: np.ndarray, burst: np.ndarray, rows: TagRows, err: np.ndarray, ch: ChannelArrays,
             dwell_s: float, *, rng: np.random.Generator) -> None:
    """Tag-side NLOS episodes (in place on ``rows.nlos`` and ``err``): one alternating renewal process
    over the bursts (fraction ``ch.tag_prob``, exponential episodes of mean ``dwell_s``); each anchor
    joins each episode with probability ``ch.tag_join``; a joined row that its own process left LOS
    becomes NLOS with the error mean + std * z of the anchor's ``ch.tag_mode``, z one draw per burst
    shared by the anchors of that burst. First, each own episode of mode ``ch.tag_mode`` is dropped with
    probability ``ch.tag_drop`` (its rows turn LOS and draw a LOS error; rows a zone or an obstacle
    makes NLOS stay as they are): see :func:`_tag_thinning`. Every draw comes from ``rng``, so the
    anchors' own streams draw what they draw without a tag side. Draws: the process, the joins
    (episodes x anchors), z per burst, one per own episode id, one per dropped row."""
    if bursts_s.size == 0:
        return
    anchor, nlos = rows.anchor, rows.nlos
    law = episode_law(ch.tag_prob, np.ones(1), np.array([dwell_s]))
    k, _, start_on = episode_switches(bursts_s, law, rng=rng, ascending=True)
    if not start_on:
        k = k + 1
    on_burst = (k & 1) == 0
    ep_of_burst = np.right_shift(k, 1) - (0 if start_on else 1)
    n_ep = int(ep_of_burst.max()) + 1
    joins = rng.random((max(n_ep, 1), ch.tag_join.size)) < ch.tag_join
    z = rng.standard_normal(bursts_s.size)
    coin = rng.random(int(rows.episode.max()) + 1) if rows.episode.size else np.empty(0)
    own = np.flatnonzero((rows.episode >= 0) & ~rows.forced)
    a = anchor.take(own)
    gone = own[(rows.mode.take(own) == ch.tag_mode.take(a)) & (coin.take(rows.episode.take(own)) < ch.tag_drop.take(a))]
    nlos[gone] = False
    err[gone] = los_errors(rows.true_range_m.take(gone), anchor.take(gone), ch, rng.standard_normal(gone.size))
    on = on_burst.take(burst)
    hit = np.flatnonzero(on & ~nlos)
    a = anchor.take(hit)
    b = burst.take(hit)
    hit = hit[joins[ep_of_burst.take(b), a]]
    a, b = anchor.take(hit), burst.take(hit)
    m = ch.tag_mode.take(a)
    err[hit] = ch.mode_mean_m[a, m] + ch.mode_std_m[a, m] * z.take(b)
    nlos[hit] = True


@dataclass(frozen=True, slots=True)
class TagRows:
    """The rows' state that :func:`tag_nlos` reads (and changes: ``nlos``): anchor, true range [m],
    NLOS indicator, episode mode and id (-1 outside an own episode), and the rows a zone or an
    obstacle makes NLOS."""

    anchor: np.ndarray
    true_range_m: np.ndarray
    nlos: np.ndarray
    mode: np.ndarray
    episode: np.ndarray
    forced: np.ndarray


SWAY_STEPS_PER_TAU = 20
"""Grid steps per correlation time on which the antenna sway is drawn (then read linearly at the
attempts): 5 % of tau apart, where the process moves by sqrt(2 x 0.05) = 0.32 of its std."""


def antenna_sway(t_s: np.ndarray, t0_s: float, t1_s: float, std_m: float, tau_s: float, *,
                 rng: np.random.Generator) -> np.ndarray:
    """(N, 3) offset [m] of the UWB antenna from the truth point at the times ``t_s`` in [t0, t1]: three
    independent Ornstein-Uhlenbeck processes (std ``std_m``, correlation time ``tau_s``), stationary
    at ``t0_s``, drawn exactly on a grid of tau / :data:`SWAY_STEPS_PER_TAU` and read linearly."""
    from ._filters import ar1

    dt = tau_s / SWAY_STEPS_PER_TAU
    n = int(np.ceil(max(t1_s - t0_s, 0.0) / dt)) + 2
    rho = float(np.exp(-dt / tau_s))
    x = rng.standard_normal((3, n))
    x[:, 1:] *= std_m * np.sqrt(1.0 - rho * rho)  # innovations of the exact discretisation
    x[:, 0] *= std_m  # the stationary start
    path = ar1(x, rho)
    grid = t0_s + dt * np.arange(n)
    return np.stack([np.interp(t_s, grid, path[k]) for k in range(3)], axis=1)


def travelled_m(t_s: np.ndarray, vel_enu_mps: np.ndarray) -> np.ndarray:
    """Distance travelled [m] since the first of the times ``t_s`` (T,): the speed |v| of the velocities
    ``vel_enu_mps`` (T, 3) integrated by the trapezoidal rule (non-decreasing; NaN speeds count as 0)."""
    speed = np.nan_to_num(np.sqrt(np.einsum("ij,ij->i", vel_enu_mps, vel_enu_mps)))
    out = np.zeros(t_s.shape[0])
    if t_s.shape[0] > 1:
        np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t_s), out=out[1:])
    return out


TURN_MIN_SPEED_MPS = 0.3
"""Below this horizontal speed the direction of travel is no heading: :func:`turned_rad` counts no turn."""


def turned_rad(t_s: np.ndarray, vel_enu_mps: np.ndarray, omega_body_radps: np.ndarray | None = None) -> np.ndarray:
    """Angle [rad] the carrier has turned since the first of the times ``t_s`` (T,), non-decreasing: the
    body rate |omega| integrated (``omega_body_radps`` (T, 3), each row held over its step, as the truth
    stores it), or without it the changes of the direction of horizontal travel between samples both
    moving faster than :data:`TURN_MIN_SPEED_MPS`."""
    out = np.zeros(t_s.shape[0])
    if t_s.shape[0] < 2:
        return out
    if omega_body_radps is not None:
        rate = np.nan_to_num(np.sqrt(np.einsum("ij,ij->i", omega_body_radps, omega_body_radps)))
        np.cumsum(rate[:-1] * np.diff(t_s), out=out[1:])
        return out
    v = np.nan_to_num(vel_enu_mps[:, :2])
    speed = np.hypot(v[:, 0], v[:, 1])
    step = np.abs(np.angle(np.exp(1j * np.diff(np.arctan2(v[:, 1], v[:, 0])))))  # wrapped to [0, pi]
    step[(speed[1:] < TURN_MIN_SPEED_MPS) | (speed[:-1] < TURN_MIN_SPEED_MPS)] = 0.0
    np.cumsum(step, out=out[1:])
    return out


def heading_unit(vel_enu_mps: np.ndarray) -> np.ndarray:
    """Unit vectors (T, 2) (east, north) of the direction of horizontal travel of velocities
    ``vel_enu_mps`` (T, 3): where the horizontal speed is below :data:`TURN_MIN_SPEED_MPS` (or NaN) the
    last heading is held, before the first such sample the first heading is taken; a carrier that never
    moves faces east."""
    v = np.nan_to_num(vel_enu_mps[:, :2])
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed >= TURN_MIN_SPEED_MPS
    if not moving.any():
        return np.tile([1.0, 0.0], (v.shape[0], 1))
    idx = np.where(moving, np.arange(v.shape[0]), 0)
    np.maximum.accumulate(idx, out=idx)  # the last moving sample at or before each one
    idx[: int(np.argmax(moving))] = int(np.argmax(moving))
    return v[idx] / speed[idx, None]


def relative_bearing(d_east: np.ndarray, d_north: np.ndarray, head_east: np.ndarray, head_north: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(cos phi, sin phi) of the bearing phi of the horizontal vectors (``d_east``, ``d_north``) (tag to
    anchor) relative to the headings (``head_east``, ``head_north``) (unit vectors): 0 ahead, pi/2 to the
    left. A zero vector (the anchor straight above the tag) counts as ahead."""
    norm = np.hypot(d_east, d_north)
    safe = np.where(norm > 0, norm, 1.0)
    cos_phi = np.where(norm > 0, (d_east * head_east + d_north * head_north) / safe, 1.0)
    sin_phi = np.where(norm > 0, (head_east * d_north - head_north * d_east) / safe, 0.0)
    return cos_phi, sin_phi


def pattern_features(cos_phi: np.ndarray, sin_phi: np.ndarray) -> np.ndarray:
    """(N, 4) [cos phi, sin phi, cos 2 phi, sin 2 phi], the terms of ``UwbParams.tag_pattern_m``."""
    return np.stack([cos_phi, sin_phi, 2.0 * cos_phi * cos_phi - 1.0, 2.0 * sin_phi * cos_phi], axis=1)


def tag_pattern_bias(tag_e: np.ndarray, tag_n: np.ndarray, anchor_e: np.ndarray, anchor_n: np.ndarray,
                     head: np.ndarray, coef: Sequence[float]) -> np.ndarray:
    """Range bias [m] of the tag antenna pattern ``coef`` (``UwbParams.tag_pattern_m``) for tags at
    (``tag_e``, ``tag_n``) ranging anchors at (``anchor_e``, ``anchor_n``) with headings ``head`` (N, 2)."""
    cos_phi, sin_phi = relative_bearing(anchor_e - tag_e, anchor_n - tag_n, head[:, 0], head[:, 1])
    return pattern_features(cos_phi, sin_phi) @ np.asarray(coef, dtype=float)


def heading_at(t_s: np.ndarray, grid_t_s: np.ndarray, vel_enu_mps: np.ndarray) -> np.ndarray:
    """Headings (N, 2) at the times ``t_s``: :func:`heading_unit` of the velocities on ``grid_t_s``,
    interpolated component-wise and renormalised."""
    h = heading_unit(vel_enu_mps)
    he, hn = np.interp(t_s, grid_t_s, h[:, 0]), np.interp(t_s, grid_t_s, h[:, 1])
    norm = np.hypot(he, hn)
    bad = norm < 1e-9  # a reversal between two grid samples: take the earlier heading
    if bad.any():
        k = np.clip(np.searchsorted(grid_t_s, t_s[bad], side="right") - 1, 0, grid_t_s.size - 1)
        he[bad], hn[bad], norm[bad] = h[k, 0], h[k, 1], 1.0
    return np.stack([he / norm, hn / norm], axis=1)


def motion_clock(t_s: np.ndarray, vel_enu_mps: np.ndarray, omega_body_radps: np.ndarray | None, length_m: float,
                 turn_rad: float) -> np.ndarray:
    """The antenna sway's ``motion`` clock (T,): distance travelled over ``length_m`` plus angle turned
    over ``turn_rad`` (:func:`travelled_m`, :func:`turned_rad`); ``turn_rad`` inf: the distance alone."""
    clock = travelled_m(t_s, vel_enu_mps) / length_m
    if np.isfinite(turn_rad):
        clock += turned_rad(t_s, vel_enu_mps, omega_body_radps) / turn_rad
    return clock


def sway_at(t_s: np.ndarray, kin: Kinematics, params: UwbParams, *, rng: np.random.Generator,
            omega_body_radps: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) antenna offset [m] at the times ``t_s`` of a run: :func:`antenna_sway` on the scenario's
    clock, the time, or the truth's motion (:func:`motion_clock`; ``omega_body_radps``: the truth's body
    rate, for the angle turned)."""
    if params.antenna_sway_clock == "time":
        return antenna_sway(t_s, float(kin.t_s[0]), float(kin.t_s[-1]), params.antenna_sway_std_m,
                            params.antenna_sway_tau_s, rng=rng)
    turn = params.antenna_sway_turn_rad if params.antenna_sway_clock == "motion" else np.inf
    c = motion_clock(kin.t_s, kin.vel_enu_mps, omega_body_radps, params.antenna_sway_length_m, turn)
    return antenna_sway(np.interp(t_s, kin.t_s, c), 0.0, float(c[-1]), params.antenna_sway_std_m, 1.0, rng=rng)


def _run_effect(n_anchors: int, common_std: float, anchor_std: float, rng: np.random.Generator) -> np.ndarray:
    """(A,) per-trace draws: one ~ N(0, common_std^2) shared by the anchors plus one ~ N(0, anchor_std^2)
    per anchor, in that order; a spread of 0 draws nothing, so the stream is unchanged without it."""
    out = np.zeros(n_anchors)
    if common_std > 0:
        out += common_std * rng.standard_normal()
    if anchor_std > 0:
        out += anchor_std * rng.standard_normal(n_anchors)
    return out


def run_offsets(n_anchors: int, params: UwbParams, *, rng: np.random.Generator) -> np.ndarray:
    """Per-trace ranging offsets [m] of the anchors, (A,): a common one plus one per anchor.

    Draws nothing (and returns zeros) when both spreads are 0, so that the stream is unchanged.
    """
    return _run_effect(n_anchors, params.run_offset_std_m, params.run_anchor_offset_std_m, rng)


def run_slopes(n_anchors: int, params: UwbParams, *, rng: np.random.Generator) -> np.ndarray:
    """Per-trace tilts of the anchors' range laws [m per decade of range], (A,): a common one plus one
    per anchor. Draws nothing (and returns zeros) when both spreads are 0."""
    return _run_effect(n_anchors, params.run_slope_std_m, params.run_anchor_slope_std_m, rng)


LAG_MARGIN_STDS = 4.0
"""Bursts end this many ``time_offset_std_s`` plus the mean lag before the truth's end, and begin this many
minus the mean lag after its start: stamps stay inside it."""


def trace_time_offset(params: UwbParams, *, rng: np.random.Generator) -> float:
    """The trace's UWB lag [s]: ``time_offset_s``, plus N(0, ``time_offset_std_s``^2) when that is > 0
    (nothing drawn otherwise, so that the stream is unchanged)."""
    if params.time_offset_std_s > 0:
        return params.time_offset_s + params.time_offset_std_s * float(rng.standard_normal())
    return params.time_offset_s


@dataclass(frozen=True, slots=True, kw_only=True)
class UwbAttempts:
    """Every scheduled ranging attempt of one run before availability: rows sorted by true time."""

    bursts_s: np.ndarray  # (B,) true start time of every tag burst
    burst: np.ndarray  # (N,) burst index of each attempt
    anchor: np.ndarray  # (N,) anchor index
    t_true_s: np.ndarray  # (N,) true time of the attempt
    true_range_m: np.ndarray
    measured_m: np.ndarray  # range the radio would report (never negative)
    nlos: np.ndarray
    linked: np.ndarray  # inside the radio horizon
    anchor_rows: tuple[np.ndarray, ...] | None = None  # rows of each anchor (rows_by_label), for the availability
    time_offset_s: float = 0.0  # the trace's lag: stamp = t_true_s + time_offset_s


def simulate_uwb(kin: Kinematics, params: UwbParams, ch: ChannelArrays, *, rng: np.random.Generator,
                 sway_rng: np.random.Generator | None = None,
                 tag_rng: np.random.Generator | None = None,
                 omega_body_radps: np.ndarray | None = None) -> UwbAttempts:
    """All ranging attempts of one run with their true and measured ranges and NLOS state.

    ``omega_body_radps``: the truth's body rate (T, 3), for an antenna sway on the ``motion`` clock.

    ``sway_rng``: the stream of the antenna sway, needed when ``params.antenna_sway_std_m`` > 0;
    ``tag_rng``: that of the tag-side NLOS, needed when the channel has a tag-side process.
    """
    u = params
    n_anchors = ch.anchor_pos_enu_m.shape[0]
    # stamps (true time + the trace's lag) stay inside the truth span, for lags within LAG_MARGIN_STDS
    spread = LAG_MARGIN_STDS * u.time_offset_std_s
    t_end = float(kin.t_s[-1]) - n_anchors * u.slot_s - max(0.0, u.time_offset_s + spread)
    phase = None if u.burst_phase_s is None else u.burst_phase_s - u.time_offset_s  # stamp -> true time
    bursts = burst_times(float(kin.t_s[0]), t_end, u.burst_rate_hz, u.burst_jitter_s,
                         n_anchors * u.slot_s + 1e-4, rng=rng, phase_s=phase)
    lead = spread - u.time_offset_s  # a UWB clock ahead of the truth: no burst whose stamp precedes it
    if lead > 0:
        bursts = bursts[bursts.searchsorted(float(kin.t_s[0]) + lead, side="left"):]
    scheduled = rng.random((bursts.shape[0], n_anchors)) < ch.attempt_prob
    # row-major: sorted by burst, then anchor slot (np.nonzero's indices; flat indices and their quotient
    # and remainder are ~2.5x faster than its 2-D multi-index iteration; // by a number is faster than divmod)
    flat = np.flatnonzero(scheduled)
    b_idx = flat // n_anchors
    anchor = flat - b_idx * n_anchors
    t_true = bursts.take(b_idx) + anchor * u.slot_s
    # the tag's E, N, U at the attempts (rows of one block): numpy.interp's values (the path coordinate
    # only near the zones, where it decides: zone_nlos_prob_at)
    (tag_enu,) = interp_many(t_true, kin.t_s, [kin.pos_enu_m.T])
    sq = None
    for k in range(3):  # |p(t) - a_i|, one ENU component at a time (contiguous, no (N, 3) temporaries)
        d = tag_enu[k] - ch.anchor_pos_enu_m[:, k].take(anchor)  # take: numpy's fastest gather
        d *= d
        sq = d if sq is None else np.add(sq, d, out=sq)  # as 0 + d_E^2 + d_N^2 + d_U^2 (0 + x is x)
    true_range = np.sqrt(sq)

    p_link = link_probability(true_range, by_label(ch.max_range_m, anchor), by_label(ch.edge_width_m, anchor))
    blocked = None
    if ch.obstacles or ch.terrain is not None or ch.link is not None:  # geometry-aware parts (optional)
        tag = np.stack(tag_enu, axis=1)
        loss: np.ndarray | float = 0.0
        if ch.obstacles or ch.terrain is not None:
            blocked, loss = obstacle_losses(tag, ch.anchor_pos_enu_m[anchor], ch.obstacles, ch.terrain)
        p_link = p_link * link_detection_probability(tag, anchor, ch, loss)
    linked = rng.random(t_true.shape[0]) < p_link
    rows_of = _rows_per_anchor(scheduled)
    forced = np.zeros(t_true.shape[0], dtype=bool) if ch.tag_prob > 0 else None
    ascending = is_ascending(t_true)  # checked once for the zones and every anchor's rows
    zone_prob = zone_nlos_prob_at(t_true, kin.t_s, kin.s_m, ch, ascending=ascending) if ch.zone_s_m.size else None
    nlos, mode, episode = nlos_states(t_true, anchor, None, ch, rng=rng, blocked=blocked, rows_of=rows_of,
                                      forced_out=forced, zone_prob=zone_prob, ascending=ascending)
    err = range_error(true_range, anchor, nlos, mode, ch, rng=rng, episode=episode)
    if forced is not None:  # the tag's own obstruction: every anchor at once
        if tag_rng is None:
            raise ValueError("tag-side NLOS needs its random stream (tag_rng)")
        tag_nlos(bursts, b_idx, TagRows(anchor, true_range, nlos, mode, episode, forced), err, ch, u.nlos_dwell_s,
                 rng=tag_rng)
    offsets = run_offsets(n_anchors, u, rng=rng)
    if offsets.any():  # adding zeros would change only a -0.0 error, and true_range + (-0.0) is true_range
        err += offsets[anchor]
    tilts = run_slopes(n_anchors, u, rng=rng)
    if tilts.any():
        err += tilts[anchor] * (range_decades(true_range) - np.log10(u.run_slope_ref_range_m))
    if u.antenna_sway_std_m > 0:  # the range from the swaying antenna: + u . offset
        if sway_rng is None:
            raise ValueError("antenna sway needs its random stream (sway_rng)")
        sway = sway_at(t_true, kin, u, rng=sway_rng, omega_body_radps=omega_body_radps)
        for k in range(3):
            err += (tag_enu[k] - ch.anchor_pos_enu_m[:, k][anchor]) / np.maximum(true_range, 1e-9) * sway[:, k]
    if any(u.tag_pattern_m):  # the tag antenna's delay towards the anchor's bearing (deterministic)
        head = heading_at(t_true, kin.t_s, kin.vel_enu_mps)
        err += tag_pattern_bias(tag_enu[0], tag_enu[1], ch.anchor_pos_enu_m[:, 0].take(anchor),
                                ch.anchor_pos_enu_m[:, 1].take(anchor), head, u.tag_pattern_m)
    err += true_range  # true_range + err
    measured = np.maximum(err, 0.0, out=err)  # a range is never negative
    return UwbAttempts(bursts_s=bursts, burst=b_idx, anchor=anchor, t_true_s=t_true, true_range_m=true_range,
                       measured_m=measured, nlos=nlos, linked=linked, anchor_rows=rows_of,
                       time_offset_s=trace_time_offset(u, rng=rng))


def _rows_per_anchor(scheduled: np.ndarray) -> tuple[np.ndarray, ...]:
    """The attempt rows of each anchor (``rows_by_label(anchor, A)``) from the (bursts, anchors) schedule
    whose row-major nonzeros are the attempts: each scheduled entry's rank among them, anchor by anchor."""
    rank = np.cumsum(scheduled.ravel()).reshape(scheduled.shape)
    rank -= 1
    return tuple(rank[:, i][scheduled[:, i]] for i in range(scheduled.shape[1]))


def uwb_record(att: UwbAttempts, *, outage: np.ndarray, dropped: np.ndarray) -> Uwb:
    """The ``uwb`` record of a run: attempts with the availability applied and stamps on the tag clock
    (``att.time_offset_s`` after the true times)."""
    n = att.t_true_s.shape[0]
    masks = (att.linked, outage, dropped)
    if all(isinstance(m, np.ndarray) and m.dtype == np.bool_ and m.shape == (n,) for m in masks):
        # boolean masks (as simulate_availability returns): the precedence below as the largest code that
        # applies, in 8-bit integer passes (twice as fast as two selections): a dropped row is 1 = DROPOUT,
        # an outage 2 = OUTAGE, no link 3 = NO_LINK, a kept row 0 = OK
        reason = np.left_shift(outage.view(np.int8), 1)
        np.maximum(reason, dropped.view(np.int8), out=reason)
        no_link = np.invert(att.linked).view(np.int8)
        no_link *= np.int8(Reason.NO_LINK)
        np.maximum(reason, no_link, out=reason)
    else:
        reason = np.full(n, Reason.OK, dtype=np.int8)
        reason[dropped] = Reason.DROPOUT
        reason[outage] = Reason.OUTAGE
        reason[~att.linked] = Reason.NO_LINK
    range_m = np.where(reason == np.int8(Reason.OK), att.measured_m, np.nan)  # an enum operand: 7x slower
    return Uwb(t_s=att.t_true_s + att.time_offset_s, anchor=att.anchor, range_m=range_m,
               true_range_m=att.true_range_m, nlos=att.nlos, burst=att.burst, reason=reason, nlos_known=True)


def late_stamps(rec: Uwb, prob: float, delay_s: float, *, rng: np.random.Generator, t_max_s: float = np.inf) -> Uwb:
    """``rec`` (rows in burst order, as :func:`uwb_record` writes them) with each burst, with probability
    ``prob``, a late one: its delivered ranges after the first stamped ``delay_s`` later, then every row
    sorted by stamp (stable). Every other column travels with its row: a range stays the one measured at
    its attempt (:class:`UwbParams`, late stamps). A row whose late stamp would pass ``t_max_s`` (the end
    of the truth) keeps its own, so that every stamp stays inside the truth span; one draw per burst from
    ``rng``, so the trace's other draws stay those without late stamps."""
    if rec.t_s.shape[0] == 0:
        return rec
    if rec.burst[0] < 0 or (rec.burst[1:] < rec.burst[:-1]).any():
        raise ValueError("late_stamps needs the rows of uwb_record: burst ids (no -1), in burst order")
    late_burst = rng.random(int(rec.burst[-1]) + 1) < prob
    rows = np.flatnonzero((rec.reason == np.int8(Reason.OK)) & late_burst.take(rec.burst))
    if rows.size:
        b = rec.burst.take(rows)
        rows = rows[1:][b[1:] == b[:-1]]  # each late burst's first delivered range keeps its stamp
        rows = rows[rec.t_s.take(rows) + delay_s <= t_max_s]
    if rows.size == 0:
        return rec
    t = rec.t_s.copy()
    t[rows] += delay_s
    order = np.argsort(t, kind="stable")
    return rec.rows(order, t_s=t.take(order))
