"""What one run draws once: its ranging offsets, its tilts of the range law and its lag."""

from __future__ import annotations

import numpy as np

from .params import UwbParams


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
