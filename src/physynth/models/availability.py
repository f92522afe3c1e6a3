"""Availability model: per-anchor per-burst dropout, per-anchor and tag outages with exponential durations.

An anchor alternates between *up* and *outage*. Outages start with probability ``outage_onset_prob``
per burst while up (a rate of onset_prob * burst_rate_hz per second) and last an exponentially
distributed time of mean ``outage_mean_s``. While up, each scheduled attempt is lost on its own with
probability ``dropout_prob``. An optional tag-level process silences every anchor of a burst at once.
The alternating-renewal sampler (:mod:`physynth.models.renewal`) is the one the UWB model's NLOS
episodes use.

Rare events carry their uncertainty: an outage onset rate estimated from a handful of events is a
Gamma posterior (:func:`gamma_rate_posterior`, prior :data:`RATE_PRIOR_SHAPE`, :data:`RATE_PRIOR_RATE_S`).
When ``outage_onset_shape`` / ``tag_outage_onset_shape`` is set, every trace draws its own rate
onset_prob x G with G ~ Gamma(shape, 1 / shape) (mean 1: the posterior of the rate, scaled), so an
ensemble spreads as widely as the evidence allows; unset (the default), the rate is fixed and nothing
is drawn, so scenarios without it generate what they always did.

Long outages (``long_outage_*``): links also fade for seconds where the margin is thin, far from the
anchor. Each anchor gets a second outage process, overlaid on the first: onsets form a Poisson process
of rate ``long_outage_rate_per_s * exp(long_outage_range_slope_per_m * (r - long_outage_ref_range_m))``
at the tag-anchor range r (r clipped to ``long_outage_max_range_m`` when set, so that the rate is not
extrapolated beyond the ranges it was fitted on), each lasting an exponential time of mean
``long_outage_mean_s``; overlapping outages merge. Anchors are not alike: some placements fade far
more than others (an antenna turned away, a wall near the anchor). With ``long_outage_frailty_shape``
k set, each trace draws for each anchor a factor G ~ Gamma(k, 1/k) (mean 1) on its long-outage rate,
so that most anchors of a trace fade rarely and a few often. With ``long_outage_rate_per_s`` 0 (the
default) nothing is drawn. :mod:`physynth.calibrate.outage_range` fits it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat, Probability
from .renewal import by_label, initial_pairs, is_ascending, rows_by_label, switch_counts

RATE_PRIOR_SHAPE = 0.5
"""Shape of the Gamma prior on an event rate: Jeffreys' prior for a Poisson rate (with no prior
exposure, :data:`RATE_PRIOR_RATE_S` = 0). It adds half an event: one event in 250 s gives a posterior
mean of 1.5 / 250 s and a 90 % interval of about [0.35, 5.2] / 1000 s, not a certainty of 4 / 1000 s."""
RATE_PRIOR_RATE_S = 0.0
"""Rate (prior exposure [s]) of the Gamma prior on an event rate."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RatePosterior:
    """Gamma posterior of a Poisson event rate [1/s]: Gamma(prior_shape + events, prior_rate_s + exposure_s)."""

    events: float
    exposure_s: float
    prior_shape: float = RATE_PRIOR_SHAPE
    prior_rate_s: float = RATE_PRIOR_RATE_S

    @property
    def shape(self) -> float:
        return self.prior_shape + self.events

    @property
    def rate_s(self) -> float:
        return self.prior_rate_s + self.exposure_s

    @property
    def mean_per_s(self) -> float:
        return self.shape / self.rate_s

    def interval_per_s(self, lo: float = 0.05, hi: float = 0.95) -> tuple[float, float]:
        """Equal-tailed credible interval of the rate [1/s]."""
        from scipy import stats  # imported where used

        q = stats.gamma.ppf([lo, hi], a=self.shape, scale=1.0 / self.rate_s)
        return float(q[0]), float(q[1])


def gamma_rate_posterior(events: float, exposure_s: float, *, prior_shape: float = RATE_PRIOR_SHAPE,
                         prior_rate_s: float = RATE_PRIOR_RATE_S) -> RatePosterior:
    """Posterior of a Poisson rate after ``events`` events in ``exposure_s`` seconds of exposure."""
    if events < 0 or not exposure_s > 0:
        raise ValueError(f"events must be >= 0 and exposure positive, got {events}, {exposure_s}")
    return RatePosterior(events=float(events), exposure_s=float(exposure_s), prior_shape=prior_shape,
                         prior_rate_s=prior_rate_s)


class AvailabilityParams(ParamsModel):
    """Per-anchor per-burst dropout, outage onset per burst, outage durations [s].

    ``tag_outage_*`` is an optional outage process of the tag itself (antenna shadowed by the carrier,
    radio reset): while it lasts no anchor is heard. Real recordings show such all-anchor gaps
    (Hanyang LOS Case_2 loses every anchor for ~22 s); per-anchor outages alone cannot make them.

    ``outage_onset_shape`` / ``tag_outage_onset_shape``: when set, each trace draws its onset rate
    from a Gamma law of this shape and mean ``*_onset_prob`` (the rate's posterior, see the module
    docstring); None keeps the rate fixed.
    """

    dropout_prob: Probability = 0.04
    outage_onset_prob: Probability = 0.003
    outage_mean_s: PositiveFloat = 16.0
    tag_outage_onset_prob: Probability = 0.0
    tag_outage_mean_s: PositiveFloat = 16.0
    start_stationary: bool = True
    outage_onset_shape: PositiveFloat | None = None
    tag_outage_onset_shape: PositiveFloat | None = None
    long_outage_rate_per_s: NonNegFloat = 0.0
    long_outage_mean_s: PositiveFloat = 1.5
    long_outage_range_slope_per_m: FiniteFloat = 0.0
    long_outage_ref_range_m: NonNegFloat = 0.0
    long_outage_max_range_m: PositiveFloat | None = None
    long_outage_frailty_shape: PositiveFloat | None = None


class AvailabilityOverride(ParamsModel):
    dropout_prob: Probability | None = None
    outage_onset_prob: Probability | None = None
    outage_mean_s: PositiveFloat | None = None
    outage_onset_shape: PositiveFloat | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilityArrays:
    """Per-anchor availability parameters as arrays (A,), plus the tag-level process."""

    dropout_prob: np.ndarray
    outage_onset_prob: np.ndarray
    outage_mean_s: np.ndarray
    tag_outage_onset_prob: float
    tag_outage_mean_s: float
    start_stationary: bool
    outage_onset_shape: np.ndarray  # (A,) Gamma shape of the per-trace rate; NaN: fixed rate
    tag_outage_onset_shape: float  # NaN: fixed rate
    long_outage: tuple[float, float, float, float, float] = (0.0, 1.5, 0.0, 0.0, np.inf)
    """(rate [1/s] at the reference range, mean [s], slope [1/m], reference range [m], range cap [m])."""
    long_outage_frailty_shape: float = np.nan  # NaN: every anchor at the same rate


def availability_arrays(params: AvailabilityParams, per_anchor: Sequence[AvailabilityParams]) -> AvailabilityArrays:
    """Arrays of the resolved per-anchor parameters (``per_anchor`` in anchor order)."""
    return AvailabilityArrays(
        dropout_prob=np.array([a.dropout_prob for a in per_anchor], dtype=float),
        outage_onset_prob=np.array([a.outage_onset_prob for a in per_anchor], dtype=float),
        outage_mean_s=np.array([a.outage_mean_s for a in per_anchor], dtype=float),
        tag_outage_onset_prob=float(params.tag_outage_onset_prob),
        tag_outage_mean_s=float(params.tag_outage_mean_s),
        start_stationary=bool(params.start_stationary),
        outage_onset_shape=np.array([np.nan if a.outage_onset_shape is None else a.outage_onset_shape
                                     for a in per_anchor], dtype=float),
        tag_outage_onset_shape=(np.nan if params.tag_outage_onset_shape is None
                                else float(params.tag_outage_onset_shape)),
        long_outage=(float(params.long_outage_rate_per_s), float(params.long_outage_mean_s),
                     float(params.long_outage_range_slope_per_m), float(params.long_outage_ref_range_m),
                     np.inf if params.long_outage_max_range_m is None else float(params.long_outage_max_range_m)),
        long_outage_frailty_shape=(np.nan if params.long_outage_frailty_shape is None
                                   else float(params.long_outage_frailty_shape)),
    )


def draw_trace_rates(av: AvailabilityArrays, *, rng: np.random.Generator) -> AvailabilityArrays:
    """The onset probabilities of one trace: those with a Gamma shape scaled by Gamma(shape, 1/shape).

    Draws nothing and returns ``av`` itself when no shape is set.
    """
    shapes = np.append(av.outage_onset_shape, av.tag_outage_onset_shape)
    drawn = np.isfinite(shapes)
    if not drawn.any():
        return av
    factor = np.ones(shapes.size)
    factor[drawn] = rng.gamma(shapes[drawn], 1.0 / shapes[drawn])
    return AvailabilityArrays(
        dropout_prob=av.dropout_prob, outage_onset_prob=np.clip(av.outage_onset_prob * factor[:-1], 0.0, 1.0),
        outage_mean_s=av.outage_mean_s, tag_outage_onset_prob=float(min(av.tag_outage_onset_prob * factor[-1], 1.0)),
        tag_outage_mean_s=av.tag_outage_mean_s, start_stationary=av.start_stationary,
        outage_onset_shape=av.outage_onset_shape, tag_outage_onset_shape=av.tag_outage_onset_shape,
        long_outage=av.long_outage, long_outage_frailty_shape=av.long_outage_frailty_shape)


def alternating_renewal(t_s: np.ndarray, mean_on_s: float, mean_off_s: float, *, start_on_prob: float,
                        rng: np.random.Generator, ascending: bool | None = None) -> np.ndarray:
    """State of a two-state process with exponential holding times at sorted times ``t_s``.

    Returns a bool array, True where the process is *on*. The process starts *on* with probability
    ``start_on_prob``; both mean holding times must be positive and finite. ``ascending``: as in
    :func:`~physynth.models.renewal.switch_counts`.
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

    k, _ = switch_counts(t_s, draw, initial_pairs(float(t_s[-1] - t_s[0]), mean_on_s + mean_off_s),
                         ascending=ascending)
    return (k & 1) == (0 if on else 1)  # k >= 0: k & 1 is k % 2; an even count is the starting state


def outage_mask(t_s: np.ndarray, onset_prob_per_burst: float, burst_rate_hz: float, outage_mean_s: float,
                *, start_stationary: bool, rng: np.random.Generator, ascending: bool | None = None) -> np.ndarray:
    """True where the anchor is in an outage at times ``t_s`` (``ascending``: as in :func:`alternating_renewal`)."""
    if onset_prob_per_burst <= 0:
        return np.zeros(np.shape(t_s), dtype=bool)
    mean_up_s = 1.0 / (onset_prob_per_burst * burst_rate_hz)
    p_up = mean_up_s / (mean_up_s + outage_mean_s) if start_stationary else 1.0
    return ~alternating_renewal(t_s, mean_up_s, outage_mean_s, start_on_prob=p_up, rng=rng, ascending=ascending)


def stationary_availability(onset_prob_per_burst: float, burst_rate_hz: float, outage_mean_s: float) -> float:
    """Long-run fraction of time an anchor is up."""
    if onset_prob_per_burst <= 0:
        return 1.0
    mean_up_s = 1.0 / (onset_prob_per_burst * burst_rate_hz)
    return mean_up_s / (mean_up_s + outage_mean_s)


def long_outage_mask(t_s: np.ndarray, range_m: np.ndarray, rate_per_s: float, mean_s: float, slope_per_m: float,
                     ref_range_m: float, max_range_m: float = np.inf, *, start_stationary: bool = True,
                     rng: np.random.Generator) -> np.ndarray:
    """True where one anchor is in a long outage, at its sorted attempt times ``t_s`` with ranges ``range_m``.

    Onsets: a Poisson process of rate ``rate_per_s * exp(slope_per_m * (min(r, max_range_m) - ref_range_m))``,
    drawn by inverting its cumulative rate (trapezoids between attempts); durations exponential of mean
    ``mean_s``; overlapping outages merge. With ``start_stationary`` the process also runs for 10 mean
    durations before the first attempt at the first attempt's rate, so a trace can start inside one.
    """
    t = np.asarray(t_s, dtype=float)
    if t.size == 0 or rate_per_s <= 0:
        return np.zeros(t.shape, dtype=bool)
    r = np.minimum(np.nan_to_num(np.asarray(range_m, dtype=float), nan=ref_range_m), max_range_m)
    rate = rate_per_s * np.exp(slope_per_m * (r - ref_range_m))
    lead_s = 10.0 * mean_s if start_stationary else 0.0
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))]) + rate[0] * lead_s
    n = rng.poisson(cum[-1])
    u = np.sort(rng.uniform(0.0, cum[-1], n))
    lead = u < rate[0] * lead_s
    onset = np.where(lead, t[0] - (rate[0] * lead_s - u) / rate[0], np.interp(u, cum, t))
    end = np.sort(onset + rng.exponential(mean_s, n))
    return np.searchsorted(onset, t, side="right") > np.searchsorted(end, t, side="right")


def simulate_availability(t_s: np.ndarray, anchor: np.ndarray, burst: np.ndarray, bursts_s: np.ndarray,
                          av: AvailabilityArrays, burst_rate_hz: float, *, range_m: np.ndarray | None = None,
                          rng: np.random.Generator, rows_of: Sequence[np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Outage and dropout flags of ranging attempts (true times ``t_s``, anchor and burst indices).

    ``bursts_s`` holds the start time of every tag burst (the tag-level process runs on the bursts);
    ``range_m`` (N,), the true range of every attempt, is needed only by long outages.
    Returns (outage, dropped), both (N,) bool. Rates with a Gamma shape are drawn for the trace first.
    ``rows_of``: the rows of each anchor (``rows_by_label(anchor, A)``, e.g. ``UwbAttempts.anchor_rows``)
    when the caller has them already.
    """
    av = draw_trace_rates(av, rng=rng)
    outage = np.zeros(t_s.shape[0], dtype=bool)
    if rows_of is None:
        rows_of = rows_by_label(anchor, av.dropout_prob.shape[0])
    ascending = is_ascending(t_s)  # checked once for every anchor's rows
    for i, rows in enumerate(rows_of):  # one outage process per anchor
        outage[rows] = outage_mask(t_s.take(rows), av.outage_onset_prob[i], burst_rate_hz, av.outage_mean_s[i],
                                   start_stationary=av.start_stationary, rng=rng, ascending=ascending)
    if av.tag_outage_onset_prob > 0:  # one process for the tag, applied to every anchor of a burst
        tag_out = outage_mask(bursts_s, av.tag_outage_onset_prob, burst_rate_hz, av.tag_outage_mean_s,
                              start_stationary=av.start_stationary, rng=rng)
        outage |= tag_out.take(burst)
    dropped = rng.random(t_s.shape[0]) < by_label(av.dropout_prob, anchor)
    if av.long_outage[0] > 0:  # drawn last: scenarios without long outages draw what they always did
        if range_m is None:
            raise ValueError("long outages need the range of every attempt (range_m)")
        n_a, k = av.dropout_prob.shape[0], av.long_outage_frailty_shape
        frailty = rng.gamma(k, 1.0 / k, n_a) if np.isfinite(k) else np.ones(n_a)
        rate, *rest = av.long_outage
        for i, rows in enumerate(rows_of):
            outage[rows] |= long_outage_mask(t_s[rows], range_m[rows], rate * frailty[i], *rest,
                                             start_stationary=av.start_stationary, rng=rng)
    return outage, dropped
