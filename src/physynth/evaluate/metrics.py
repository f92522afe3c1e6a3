"""The metrics of docs/data-and-metrics.md (section 3), written once; generator tests, ``inspect``, calibration checks,
validation and the studies all call this module.

Pooling over several traces: durations are averaged; grid fractions and mean AoI are taken over all
grid bins of all traces; residual statistics over all valid ranges of all traces; IMU standard
deviations over the concatenated 100 Hz-grid IMU values. Traces are reduced one at a time
(:class:`MetricsAccumulator`): sums exactly, quantiles with :mod:`physynth.evaluate.sketch`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from .._args import check_number
from ..constants import DEFAULT_GRID_RATE_HZ
from ..errors import ArgumentError
from ..records import TRUTH_UNTRUSTED_KEY, Trace, trace_iterable, untrusted_truth
from .grid import age_of_information as _aoi
from .grid import fresh_mask, grid_times, imu_on_grid
from .sketch import Moments, QuantileSketch
from .stats import ks_statistic  # noqa: F401 (a section-5 metric; defined with the other tests)

METRIC_KEYS = (
    "duration_s",
    "uwb_ge1_frac",
    "uwb_ge2_frac",
    "residual_std_m",
    "residual_median_m",
    "abs_residual_p95_m",
    "abs_residual_p99_m",
    "mean_aoi_s",
    "imu_std_mps2",
)
"""Keys of a metrics dictionary, in the order of the paper's tables (plus ``per_anchor``)."""


def residuals(trace: Trace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed range residuals r = range - |p_truth(t) - a_i| of every valid range [m].

    Returns (residual_m, anchor_index, t_s); ranges outside the truth time span are left out, and so
    are those inside a span where the recording says its own truth errs (``trace.meta`` key
    ``truth_untrusted_s``, :func:`physynth.records.untrusted_truth`; e.g. an RTK receiver without a fix):
    against a wrong truth the difference is not a ranging error.
    """
    uwb = trace.uwb
    ok = uwb.valid
    t = uwb.t_s[ok]
    idx = uwb.anchor[ok].astype(np.intp)
    pos = trace.truth.position_at(t)
    geom = np.linalg.norm(pos - trace.anchors.pos_enu_m[idx], axis=1)
    r = uwb.range_m[ok] - geom
    keep = np.isfinite(r)
    if trace.meta.get(TRUTH_UNTRUSTED_KEY):
        keep &= ~untrusted_truth(trace.meta, t)
    return r[keep], idx[keep], t[keep]


@dataclass(frozen=True, slots=True, kw_only=True)
class TraceSummary:
    """Per-trace ingredients of the pooled metrics."""

    duration_s: float
    anchor_ids: tuple[str, ...]
    n_bins: int
    ge1: int
    ge2: int
    fresh_per_anchor: np.ndarray  # (A,) count of fresh bins
    aoi_sum_per_anchor: np.ndarray  # (A,) sum over bins of AoI [s]
    residual_m: np.ndarray
    residual_anchor: np.ndarray
    residual_anchor_index: np.ndarray  # (R,) index into anchor_ids
    imu_grid_mps2: np.ndarray  # (K, 3), NaN rows when no IMU


def summarize(trace: Trace, rate_hz: float = DEFAULT_GRID_RATE_HZ) -> TraceSummary:
    """Reduce one trace to what the pooled metrics need."""
    t = grid_times(trace.t0_s, trace.duration_s, rate_hz)
    fresh = fresh_mask(trace, t, rate_hz)
    n_fresh = fresh.sum(axis=1)
    aoi = _aoi(trace, t)
    r, idx, _ = residuals(trace)
    return TraceSummary(
        duration_s=trace.duration_s,
        anchor_ids=trace.anchors.ids,
        n_bins=int(t.shape[0]),
        ge1=int(np.count_nonzero(n_fresh >= 1)),
        ge2=int(np.count_nonzero(n_fresh >= 2)),
        fresh_per_anchor=fresh.sum(axis=0),
        aoi_sum_per_anchor=aoi.sum(axis=0),
        residual_m=r,
        residual_anchor=np.asarray(trace.anchors.ids, dtype=object)[idx] if r.size else np.array([], object),
        residual_anchor_index=idx,
        imu_grid_mps2=imu_on_grid(trace, t, rate_hz),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class Metrics:
    """Pooled section-5 metrics of a set of traces. ``to_dict`` gives the JSON form."""

    duration_s: float
    uwb_ge1_frac: float
    uwb_ge2_frac: float
    residual_std_m: float
    residual_median_m: float
    abs_residual_p95_m: float
    abs_residual_p99_m: float
    mean_aoi_s: float
    imu_std_mps2: tuple[float, float, float]
    per_anchor: dict[str, dict[str, float]] = field(default_factory=dict)
    n_traces: int = 0
    n_residuals: int = 0

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in METRIC_KEYS}
        d["imu_std_mps2"] = list(self.imu_std_mps2)
        d["per_anchor"] = self.per_anchor
        return d

    def scalar(self, key: str) -> float:
        return float(getattr(self, key))


class MetricsAccumulator:
    """Pooled section-5 metrics of traces added one at a time, in memory that does not grow with them.

    Counts and sums are added exactly; standard deviations come from exact running moments and the
    residual quantiles from a :class:`~physynth.evaluate.sketch.QuantileSketch` (exact up to
    :data:`~physynth.evaluate.sketch.EXACT_LIMIT` residuals, then within 0.01 % relative error).
    """

    def __init__(self) -> None:
        self.n_traces = 0
        self.duration_sum = 0.0
        self.n_bins = 0
        self.ge1 = 0
        self.ge2 = 0
        self.anchor_ids: list[str] = []
        self.fresh: dict[str, int] = {}
        self.aoi_sum: dict[str, float] = {}
        self.bins: dict[str, int] = {}
        self.residual = QuantileSketch()
        self.residual_moments = Moments()
        self.abs_residual = QuantileSketch()
        self.per_anchor_residual: dict[str, tuple[QuantileSketch, QuantileSketch, Moments]] = {}
        self.imu = Moments(3)

    def add(self, s: TraceSummary) -> None:
        """Add one trace's summary (:func:`summarize`)."""
        self.n_traces += 1
        self.duration_sum += s.duration_s
        self.n_bins += s.n_bins
        self.ge1 += s.ge1
        self.ge2 += s.ge2
        for j, a in enumerate(s.anchor_ids):
            if a not in self.fresh:
                self.anchor_ids.append(a)
                self.fresh[a], self.aoi_sum[a], self.bins[a] = 0, 0.0, 0
                self.per_anchor_residual[a] = (QuantileSketch(), QuantileSketch(), Moments())
            self.fresh[a] += int(s.fresh_per_anchor[j])
            self.aoi_sum[a] += float(s.aoi_sum_per_anchor[j])
            self.bins[a] += s.n_bins
        r = s.residual_m
        self.residual.add(r)
        self.abs_residual.add(np.abs(r))
        self.residual_moments.add(r)
        if r.size:
            for j, a in enumerate(s.anchor_ids):
                ra = r[s.residual_anchor_index == j]
                if ra.size == 0:
                    continue
                sk, sk_abs, mom = self.per_anchor_residual[a]
                sk.add(ra)
                sk_abs.add(np.abs(ra))
                mom.add(ra)
        imu = s.imu_grid_mps2
        self.imu.add(imu[np.all(np.isfinite(imu), axis=1)])

    @staticmethod
    def _residual_stats(sk: QuantileSketch, sk_abs: QuantileSketch, mom: Moments) -> dict[str, float]:
        if sk.n == 0:
            nan = float("nan")
            return {"residual_std_m": nan, "residual_median_m": nan, "abs_residual_p95_m": nan,
                    "abs_residual_p99_m": nan}
        p95, p99 = sk_abs.quantile(np.array([0.95, 0.99]))
        return {
            "residual_std_m": float(mom.std()[0]),
            "residual_median_m": float(sk.quantile(0.5)),
            "abs_residual_p95_m": float(p95),
            "abs_residual_p99_m": float(p99),
        }

    def result(self) -> Metrics:
        """The pooled metrics of every trace added so far (:class:`~physynth.errors.ArgumentError`, also a
        ``ValueError``, when there are none)."""
        if self.n_traces == 0:
            raise ArgumentError("no traces to compute metrics on")
        per_anchor = {}
        for a in self.anchor_ids:
            sk, sk_abs, mom = self.per_anchor_residual[a]
            per_anchor[a] = {
                "n_ranges": int(sk.n),
                "fresh_frac": self.fresh[a] / self.bins[a],
                "mean_aoi_s": self.aoi_sum[a] / self.bins[a],
                **self._residual_stats(sk, sk_abs, mom),
            }
        total_anchor_bins = sum(self.bins.values())
        imu_std = tuple(float(v) for v in self.imu.std()) if self.imu.n > 1 else (np.nan,) * 3
        return Metrics(
            duration_s=self.duration_sum / self.n_traces,
            uwb_ge1_frac=self.ge1 / self.n_bins,
            uwb_ge2_frac=self.ge2 / self.n_bins,
            mean_aoi_s=sum(self.aoi_sum.values()) / total_anchor_bins if total_anchor_bins else float("nan"),
            imu_std_mps2=imu_std,  # type: ignore[arg-type]
            per_anchor=per_anchor,
            n_traces=self.n_traces,
            n_residuals=int(self.residual.n),
            **self._residual_stats(self.residual, self.abs_residual, self.residual_moments),
        )


def pool(summaries: Iterable[TraceSummary]) -> Metrics:
    """Pooled metrics of per-trace summaries (consumed one at a time)."""
    acc = MetricsAccumulator()
    for s in summaries:
        acc.add(s)
    return acc.result()


def compute_metrics(traces: Iterable[Trace], rate_hz: float = DEFAULT_GRID_RATE_HZ,
                    on_trace: Callable[[], None] | None = None) -> Metrics:
    """Pooled section-5 metrics of traces, reduced one at a time (any iterable, e.g. a streamed dataset).

    ``traces`` is an iterable of at least one :class:`~physynth.records.Trace` (for one trace, ``[trace]``);
    ``rate_hz`` the evaluation grid rate [Hz]. ``on_trace()`` is called after each trace (progress display).

    Raises
    ------
    ArgumentError
        ``rate_hz`` is not a positive finite number, ``traces`` is a single Trace or holds none.
    """
    rate_hz = check_number(rate_hz, "rate_hz", positive=True, unit="Hz")
    acc = MetricsAccumulator()
    for t in trace_iterable(traces):
        acc.add(summarize(t, rate_hz))
        if on_trace is not None:
            on_trace()
    return acc.result()


def relative_deviation_pct(real: float, synth: float) -> float:
    """|synth - real| / |real| * 100 (NaN when real is 0 and synth is not)."""
    if real == synth:
        return 0.0
    if real == 0 or not np.isfinite(real):
        return float("nan")
    return abs(synth - real) / abs(real) * 100.0


def fidelity_score(real: Metrics, synth: Metrics) -> float:
    """S = d_avail + d_med / 10 + d_p95 / 20 (absolute deviations; lower is better)."""
    return (
        abs(synth.uwb_ge1_frac - real.uwb_ge1_frac)
        + abs(synth.residual_median_m - real.residual_median_m) / 10.0
        + abs(synth.abs_residual_p95_m - real.abs_residual_p95_m) / 20.0
    )
