"""The one alternating-renewal sampler: a two-state process with random holding times.

Both the availability model (anchor and tag outages) and the UWB model (NLOS episodes) are
alternating renewal processes observed at sorted times. They differ only in how a pair of holding
times is drawn (exponential on both sides, or an episode of a mixture mode with its own mean length),
so the drawing is passed in and the switching logic lives here once.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

PairDraw = Callable[[int], tuple[np.ndarray, Any]]
"""``draw(n) -> (durations (n, 2), payload)``: n pairs of holding times in order of occurrence (first
the state the process starts in, then the other one), plus anything drawn with them (e.g. a mode per
pair). It is called again with twice as many pairs until the switches cover the time span."""


def switch_counts(t_s: np.ndarray, draw: PairDraw, n_pairs: int, *,
                  ascending: bool | None = None) -> tuple[np.ndarray, Any]:
    """Number of state switches at or before each of the sorted times ``t_s`` (and the payload).

    The first holding time is drawn like every other: with exponential times, memorylessness makes the
    start stationary. Even counts mean the process is in its starting state. ``ascending``: whether
    ``t_s`` is known to be non-decreasing (:func:`is_ascending`), e.g. rows of an array checked once;
    None checks it here.
    """
    t0 = float(t_s[0])
    while True:
        durations, payload = draw(n_pairs)
        switches = durations.ravel().cumsum()  # methods: no numpy function-wrapper overhead per call
        switches += t0
        if switches[-1] > t_s[-1]:
            break
        n_pairs *= 2
    return count_at_or_before(switches, t_s, ascending), payload


def is_ascending(t_s: np.ndarray) -> bool:
    """True when the 1-D ``t_s`` is non-decreasing and holds no NaN (so is every subsequence of it)."""
    return t_s.shape[0] < 2 or bool((t_s[1:] >= t_s[:-1]).all())


def count_at_or_before(switches: np.ndarray, t_s: np.ndarray, ascending: bool | None = None) -> np.ndarray:
    """``numpy.searchsorted(switches, t_s, side="right")`` for sorted ``switches``: with ``t_s`` sorted
    (the usual case), each switch is placed among the times instead (a few hundred searches instead of
    thousands) and the counts are a cumulative sum; the same integers. ``ascending``: as in
    :func:`switch_counts` (None: checked here)."""
    n = t_s.shape[0]
    if 2 * switches.shape[0] > n or not (is_ascending(t_s) if ascending is None else ascending):
        return np.searchsorted(switches, t_s, side="right")  # as many switches as times, or unsorted (NaN) times
    first = t_s.searchsorted(switches, side="left")  # switch s counts at times i >= first (t_i >= s)
    return np.bincount(first, minlength=n + 1)[:n].cumsum()


def initial_pairs(span_s: float, mean_cycle_s: float) -> int:
    """A first guess of the number of (on, off) pairs that covers ``span_s`` (doubled while short)."""
    return int(2.0 * span_s / mean_cycle_s) + 8


def rows_by_label(labels: np.ndarray, n_labels: int) -> list[np.ndarray]:
    """``[numpy.flatnonzero(labels == i) for i in range(n_labels)]`` (the rows of each anchor, ascending),
    comparing the labels as 8-bit integers when they fit (a quarter of the memory traffic of int64)."""
    labels = np.asarray(labels)
    if labels.size and labels.dtype.kind in "iu" and labels.dtype.itemsize > 1:
        lo, hi = int(labels.min()), int(labels.max())
        if -128 <= lo and hi <= 127:
            small = labels.astype(np.int8)
            empty = np.zeros(0, dtype=np.intp)
            return [np.flatnonzero(small == i) if lo <= i <= hi else empty for i in range(n_labels)]
    return [np.flatnonzero(labels == i) for i in range(n_labels)]


def by_label(values: np.ndarray, labels: np.ndarray) -> np.ndarray | np.float64:
    """``values[labels]`` (a per-anchor parameter at every row), or the one value itself when every entry
    of ``values`` is the same, bit for bit: the same number at each row of the arithmetic it enters,
    without the gather."""
    if values.dtype == np.float64 and values.size and (values.view(np.uint64) == values.view(np.uint64)[0]).all():
        return values[0]
    return values[labels]
