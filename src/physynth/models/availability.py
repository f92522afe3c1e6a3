"""Availability model: per-anchor per-burst dropout, per-anchor and tag outages with exponential durations.

An anchor alternates between *up* and *outage*. Outages start with probability ``outage_onset_prob``
per burst while up (a rate of onset_prob * burst_rate_hz per second) and last an exponentially
distributed time of mean ``outage_mean_s``. While up, each scheduled attempt is lost on its own with
probability ``dropout_prob``. An optional tag-level process silences every anchor of a burst at once.
The alternating-renewal sampler (:mod:`physynth.models.renewal`) is the one the UWB model's NLOS
episodes use.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ._params import ParamsModel, PositiveFloat, Probability
from .renewal import initial_pairs, switch_counts


class AvailabilityParams(ParamsModel):
    """Per-anchor per-burst dropout, outage onset per burst, outage durations [s].

    ``tag_outage_*`` is an optional outage process of the tag itself (antenna shadowed by the carrier,
    radio reset): while it lasts no anchor is heard. Real recordings show such all-anchor gaps
    (Hanyang LOS Case_2 loses every anchor for ~22 s); per-anchor outages alone cannot make them.
    """

    dropout_prob: Probability = 0.04
    outage_onset_prob: Probability = 0.003
    outage_mean_s: PositiveFloat = 16.0
    tag_outage_onset_prob: Probability = 0.0
    tag_outage_mean_s: PositiveFloat = 16.0
    start_stationary: bool = True


class AvailabilityOverride(ParamsModel):
    dropout_prob: Probability | None = None
    outage_onset_prob: Probability | None = None
    outage_mean_s: PositiveFloat | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilityArrays:
    """Per-anchor availability parameters as arrays (A,), plus the tag-level process."""

    dropout_prob: np.ndarray
    outage_onset_prob: np.ndarray
    outage_mean_s: np.ndarray
    tag_outage_onset_prob: float
    tag_outage_mean_s: float
    start_stationary: bool


def availability_arrays(params: AvailabilityParams, per_anchor: Sequence[AvailabilityParams]) -> AvailabilityArrays:
    """Arrays of the resolved per-anchor parameters (``per_anchor`` in anchor order)."""
    return AvailabilityArrays(
        dropout_prob=np.array([a.dropout_prob for a in per_anchor], dtype=float),
        outage_onset_prob=np.array([a.outage_onset_prob for a in per_anchor], dtype=float),
        outage_mean_s=np.array([a.outage_mean_s for a in per_anchor], dtype=float),
        tag_outage_onset_prob=float(params.tag_outage_onset_prob),
        tag_outage_mean_s=float(params.tag_outage_mean_s),
        start_stationary=bool(params.start_stationary),
    )


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
    on = bool(rng.random() < start_on_prob)
    means = np.array([mean_on_s, mean_off_s]) if on else np.array([mean_off_s, mean_on_s])

    def draw(n: int) -> tuple[np.ndarray, None]:
        return rng.exponential(1.0, (n, 2)) * means, None

    k, _ = switch_counts(t_s, draw, initial_pairs(float(t_s[-1] - t_s[0]), mean_on_s + mean_off_s))
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


def simulate_availability(t_s: np.ndarray, anchor: np.ndarray, burst: np.ndarray, bursts_s: np.ndarray,
                          av: AvailabilityArrays, burst_rate_hz: float, *,
                          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Outage and dropout flags of ranging attempts (true times ``t_s``, anchor and burst indices).

    ``bursts_s`` holds the start time of every tag burst (the tag-level process runs on the bursts).
    Returns (outage, dropped), both (N,) bool.
    """
    outage = np.zeros(t_s.shape[0], dtype=bool)
    for i in range(av.dropout_prob.shape[0]):  # one outage process per anchor
        rows = np.flatnonzero(anchor == i)
        outage[rows] = outage_mask(t_s[rows], av.outage_onset_prob[i], burst_rate_hz, av.outage_mean_s[i],
                                   start_stationary=av.start_stationary, rng=rng)
    if av.tag_outage_onset_prob > 0:  # one process for the tag, applied to every anchor of a burst
        tag_out = outage_mask(bursts_s, av.tag_outage_onset_prob, burst_rate_hz, av.tag_outage_mean_s,
                              start_stationary=av.start_stationary, rng=rng)
        outage |= tag_out[burst]
    dropped = rng.random(t_s.shape[0]) < av.dropout_prob[anchor]
    return outage, dropped
