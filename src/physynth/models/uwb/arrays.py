"""The per-anchor channel as arrays, the records every effect of the UWB model reads."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..obstacles import TerrainGrid


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
