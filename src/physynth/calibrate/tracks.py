"""A truth track reduced to what the path, motion and jitter fits need: smoothed, its trip and dwells found.

The floor below :mod:`~physynth.calibrate.geometry` and :mod:`~physynth.calibrate.jitter_fit`, which both
read it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..records import Trace
from ._base import CalibrationError, good_truth, require_truth, smooth_track

STOP_SPEED_FRAC = 0.1
"""A tag is taken as moving while its speed exceeds this fraction of its peak speed (dwell detection)."""
SMOOTH_WINDOW_S = 1.0
"""Savitzky-Golay window used to smooth the truth track before differentiation [s]."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackSummary:
    """A truth track reduced to what path and motion fitting need."""

    label: str
    t_s: np.ndarray  # uniform grid (K,)
    pos_m: np.ndarray  # smoothed (K, 3)
    speed_mps: np.ndarray  # smoothed (K,)
    i_start: int  # first index of the trip
    i_end: int  # last index of the trip
    t0_s: float  # first truth time
    t1_s: float  # last truth time
    s_m: np.ndarray  # travelled distance along the smoothed track (K,), dead-banded at rest
    peak_speed_mps: float
    stop_speed_mps: float

    @property
    def trip_s(self) -> float:
        return float(self.t_s[self.i_end] - self.t_s[self.i_start])

    @property
    def trip_length_m(self) -> float:
        return float(self.s_m[self.i_end] - self.s_m[self.i_start])

    @property
    def dwell_start_s(self) -> float:
        return float(self.t_s[self.i_start] - self.t0_s)

    @property
    def dwell_end_s(self) -> float:
        return float(self.t1_s - self.t_s[self.i_end])


def summarize_track(trace: Trace, label: str, *, stop_speed_frac: float = STOP_SPEED_FRAC,
                    window_s: float = SMOOTH_WINDOW_S) -> TrackSummary:
    """Smooth a truth track and find the trip (first to last movement) and the dwells around it.

    The trip starts where the speed last stood at the rest level (twice the median speed of the
    rest-level samples outside the movement, at least 0.1 % of the peak) before it first exceeds
    ``stop_speed_frac`` of the peak speed (P99.5); it ends symmetrically.
    """
    require_truth(trace, label)
    t, p = good_truth(trace)
    tg, ps, vs = smooth_track(t, p, window_s=window_s)
    speed = np.linalg.norm(vs, axis=1)
    peak = float(np.percentile(speed, 99.5))
    if not peak > 0:
        raise CalibrationError(f"{label}: the ground truth never moves; no path or motion to fit")
    hi = stop_speed_frac * peak
    moving = np.flatnonzero(speed > hi)
    i1, i2 = int(moving[0]), int(moving[-1])
    outside = np.concatenate([speed[:i1], speed[i2 + 1:]])
    rest = outside[outside < 0.25 * hi]  # rest-level samples (not the ramp towards the threshold)
    noise = float(np.median(rest)) if rest.size else 0.0
    lo = float(np.clip(2.0 * noise, 1e-3 * peak, hi))
    before = np.flatnonzero(speed[: i1 + 1] <= lo)
    after = np.flatnonzero(speed[i2:] <= lo)
    i_start = int(before[-1]) if before.size else 0
    i_end = i2 + int(after[0]) if after.size else speed.size - 1
    step = np.linalg.norm(np.diff(ps, axis=0), axis=1)
    mid_speed = 0.5 * (speed[1:] + speed[:-1])
    step = np.where(mid_speed > lo, step, 0.0)  # GNSS jitter at rest adds no path length
    s = np.concatenate([[0.0], np.cumsum(step)])
    return TrackSummary(label=label, t_s=tg, pos_m=ps, speed_mps=speed, i_start=i_start, i_end=i_end,
                        t0_s=float(t[0]), t1_s=float(t[-1]), s_m=s, peak_speed_mps=peak, stop_speed_mps=lo)
