"""The anchors' channel parameters composed into arrays (:func:`channel_arrays`), once per trace."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .arrays import ChannelArrays, LinkBudgetArrays
from .params import AnchorSpec, ChannelParams, LinkBudgetParams, UwbParams
from .tag_nlos import tag_thinning


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
    tag = tag_thinning(params.tag_nlos_prob, nlos_prob, cumw, mean, std) if params.tag_nlos_prob > 0 else {}
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
