"""The evaluation grid and age of information, derived from a trace's UWB rows (DESIGN.md section 5).

Grid steps are ``t_k = t0 + k / rate`` for ``k = 0 .. floor(duration * rate)``; bin ``k`` covers
``(t_k - 1/rate, t_k]``. A bin is *fresh* for anchor ``i`` when at least one valid range of anchor
``i`` has its time in the bin. ``AoI_i(t_k) = t_k - t_i_last``, with ``t_i_last`` the newest valid
measurement time of anchor ``i`` at or before ``t_k``, or the trace start ``t0`` before the first one.

The same function serves real and synthetic traces, so AoI can never drift from the UWB table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import DEFAULT_GRID_RATE_HZ
from ..records import Trace

_EPS_BIN = 1e-6  # tolerance, in bins, for a time that sits exactly on a grid step


@dataclass(frozen=True, slots=True, kw_only=True)
class Grid:
    """A trace on the evaluation grid: times (K,), fresh mask (K, A), AoI (K, A) [s], truth (K, 3) [m]."""

    t_s: np.ndarray
    fresh: np.ndarray
    aoi_s: np.ndarray
    pos_enu_m: np.ndarray
    rate_hz: float


def grid_times(t0_s: float, duration_s: float, rate_hz: float = DEFAULT_GRID_RATE_HZ) -> np.ndarray:
    """Grid step times [s] covering ``[t0, t0 + duration]``."""
    n = int(np.floor(duration_s * rate_hz + _EPS_BIN)) + 1
    return t0_s + np.arange(n) / rate_hz


def bin_index(t_s: np.ndarray, t0_s: float, rate_hz: float) -> np.ndarray:
    """Index k of the bin ``(t_k - dt, t_k]`` that holds each time (times before t0 give k <= 0)."""
    return np.ceil((np.asarray(t_s) - t0_s) * rate_hz - _EPS_BIN).astype(np.int64)


def fresh_mask(trace: Trace, t_s: np.ndarray, rate_hz: float) -> np.ndarray:
    """(K, A) bool: anchor i delivered a valid range in bin k."""
    uwb = trace.uwb
    n_bins, n_anchors = t_s.shape[0], len(trace.anchors)
    fresh = np.zeros((n_bins, n_anchors), dtype=bool)
    ok = uwb.valid
    k = bin_index(uwb.t_s[ok], float(t_s[0]), rate_hz)
    inside = (k >= 0) & (k < n_bins)
    fresh[k[inside], uwb.anchor[ok][inside]] = True
    return fresh


def age_of_information(trace: Trace, t_s: np.ndarray) -> np.ndarray:
    """(K, A) AoI [s] at grid times ``t_s`` from the trace's valid UWB rows (DESIGN.md section 5)."""
    uwb = trace.uwb
    t0 = trace.t0_s
    ok = uwb.valid
    aoi = np.empty((t_s.shape[0], len(trace.anchors)))
    for i in range(len(trace.anchors)):  # one pass per anchor, vectorised over time
        ti = uwb.t_s[ok & (uwb.anchor == i)]
        if ti.size == 0:
            aoi[:, i] = t_s - t0
            continue
        j = np.searchsorted(ti, t_s + 1e-9, side="right") - 1
        last = np.where(j >= 0, ti[np.maximum(j, 0)], t0)
        aoi[:, i] = t_s - np.maximum(last, t0)
    return aoi


def make_grid(trace: Trace, rate_hz: float = DEFAULT_GRID_RATE_HZ) -> Grid:
    """The evaluation grid of one trace."""
    t_s = grid_times(trace.t0_s, trace.duration_s, rate_hz)
    return Grid(
        t_s=t_s,
        fresh=fresh_mask(trace, t_s, rate_hz),
        aoi_s=age_of_information(trace, t_s),
        pos_enu_m=trace.truth.position_at(t_s),
        rate_hz=rate_hz,
    )


def imu_on_grid(trace: Trace, t_s: np.ndarray, rate_hz: float) -> np.ndarray:
    """(K, 3) mean of the ENU gravity-free IMU samples in each grid bin; NaN for a bin with no sample."""
    if trace.imu is None or trace.imu.acc_mps2 is None:
        return np.full((t_s.shape[0], 3), np.nan)
    k = bin_index(trace.imu.t_s, float(t_s[0]), rate_hz)
    inside = (k >= 0) & (k < t_s.shape[0])
    k = k[inside]
    acc = trace.imu.acc_mps2[inside]
    good = np.all(np.isfinite(acc), axis=1)
    k, acc = k[good], acc[good]
    counts = np.bincount(k, minlength=t_s.shape[0]).astype(float)
    out = np.stack([np.bincount(k, weights=acc[:, c], minlength=t_s.shape[0]) for c in range(3)], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return out / counts[:, None]
