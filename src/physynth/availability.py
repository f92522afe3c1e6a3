"""Availability model: per-anchor per-burst dropout and outages with exponential durations.

An anchor alternates between *up* and *outage*. Outages start with probability ``outage_onset_prob``
per burst while up (a rate of onset_prob * burst_rate_hz per second) and last an exponentially
distributed time of mean ``outage_mean_s``. While up, each scheduled attempt is lost on its own with
probability ``dropout_prob``. The same alternating-renewal sampler drives the NLOS episodes of the
UWB model.
"""

from __future__ import annotations

import numpy as np


def alternating_renewal(t_s: np.ndarray, mean_on_s: float, mean_off_s: float, *, start_on_prob: float,
                        rng: np.random.Generator) -> np.ndarray:
    """State of a two-state process with exponential holding times at sorted times ``t_s``.

    Returns a bool array, True where the process is *on*. The process starts *on* with probability
    ``start_on_prob``; both mean holding times must be positive and finite.
    """
    t_s = np.asarray(t_s, dtype=float)
    if not (0 < mean_on_s < np.inf and 0 < mean_off_s < np.inf):
        raise ValueError(f"holding times must be positive and finite, got {mean_on_s}, {mean_off_s}")
    if t_s.size == 0:
        return np.zeros(0, dtype=bool)
    t0, span = float(t_s[0]), float(t_s[-1] - t_s[0])
    on = bool(rng.random() < start_on_prob)
    means = np.array([mean_on_s, mean_off_s]) if on else np.array([mean_off_s, mean_on_s])
    n_pairs = int(2.0 * span / (mean_on_s + mean_off_s)) + 8
    while True:
        # the first holding time is also exponential: memorylessness makes the start stationary
        durations = rng.exponential(1.0, (n_pairs, 2)) * means
        switches = t0 + np.cumsum(durations.ravel())
        if switches[-1] > t_s[-1]:
            break
        n_pairs *= 2
    k = np.searchsorted(switches, t_s, side="right")  # number of switches at or before t
    return (k % 2 == 0) == on


def outage_mask(t_s: np.ndarray, onset_prob_per_burst: float, burst_rate_hz: float, outage_mean_s: float,
                *, start_stationary: bool, rng: np.random.Generator) -> np.ndarray:
    """True where the anchor is in an outage at times ``t_s``."""
    if onset_prob_per_burst <= 0:
        return np.zeros(np.shape(t_s), dtype=bool)
    mean_up_s = 1.0 / (onset_prob_per_burst * burst_rate_hz)
    p_up = mean_up_s / (mean_up_s + outage_mean_s) if start_stationary else 1.0
    return ~alternating_renewal(t_s, mean_up_s, outage_mean_s, start_on_prob=p_up, rng=rng)


def stationary_availability(onset_prob_per_burst: float, burst_rate_hz: float, outage_mean_s: float) -> float:
    """Long-run fraction of time an anchor is up."""
    if onset_prob_per_burst <= 0:
        return 1.0
    mean_up_s = 1.0 / (onset_prob_per_burst * burst_rate_hz)
    return mean_up_s / (mean_up_s + outage_mean_s)
