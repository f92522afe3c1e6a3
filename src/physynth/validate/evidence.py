"""Evidence: one side of a validation (real or synthetic) reduced trace by trace.

:class:`_SideAccumulator` takes traces one at a time and keeps only what the report needs: the
section-5 metric accumulators, streaming quantile sketches of residuals, gaps and AoI, the
autocorrelation sums, the pooled Allan-variance sums and Welch spectra of the IMU, each trace's own
metrics (for the ensemble's band) and, for at most ``MAX_PLOT_TRACES`` traces, the series the figures
draw. Memory does not grow with the number of traces beyond those few numbers per trace.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..evaluate.grid import age_of_information, fresh_mask, grid_times
from ..evaluate.metrics import Metrics, MetricsAccumulator, pool, summarize
from ..evaluate.sketch import REPRESENTATIVES, QuantileSketch
from ..evaluate.stats import overlapping_allan_variance_sums
from ..records import Anchors, Trace

ACF_MAX_LAG = 10
"""Residual autocorrelation is reported at lags 1..ACF_MAX_LAG measurements of one anchor."""
INLIER_HALF_WIDTH_M = 0.5
STILL_LAG_S = (1.0, 3.0)
"""Pairs of one anchor's inlier residuals this far apart in time [s] give the still and moving
correlations (``residual_still_correlation``)."""
STILL_MAX_M = 0.1
MOVING_MIN_M = 1.0
"""A pair is still when the tag travelled less than STILL_MAX_M [m] between its two ranges, moving when
it travelled MOVING_MIN_M [m] or more."""
BURST_GAP_S = 0.02
"""Ranges of one trace less than this apart [s] (and less than half an anchor's own ranging period)
belong to one burst (the anchors ranged one after another in a few milliseconds)."""
"""The inlier autocorrelation keeps the residuals within this of their anchor's median in the trace:
without the gross outliers, whose held values dominate every sum of products."""

ALLAN_TAUS_S = (0.1, 1.0, 10.0)
"""Averaging times [s] at which the IMU Allan-deviation ratio synthetic / real is reported."""

WELCH_SEGMENT_S = 5.12
"""Welch segment length [s] of the IMU acceleration spectrum (512 samples on the 100 Hz grid)."""

IMU_MIN_FINITE_FRAC = 0.8
"""A trace's IMU enters the spectrum and Allan deviation only when this fraction of its grid bins
holds at least one sample; the empty bins are filled by linear interpolation."""

MAX_PLOT_TRACES = 100
"""At most this many traces per side keep their path, speed and per-step series for the figures."""

TYPICAL_METRICS = ("mean_aoi_s",)
"""Heavy-tailed metrics whose deviation is taken against the ensemble's typical value, not its pooled one.

The mean AoI integrates the square of every gap, so one rare long outage moves a run's value by an order
of magnitude (Hanyang LOS Case_2: 1.04 s against 0.06-0.12 s for the other runs). The pooled synthetic
value is the expectation over runs, dominated by the rare ones; a single real run is one draw, most often
without such an outage. Its deviation is therefore taken against
:func:`physynth.validate.compare.typical_value`, the median over groups of as many synthetic traces as
the real side holds; ``synthetic`` keeps the pooled value and the band says whether the real run could be
one of the synthetic ones. The per-anchor table does the same with each anchor's own value."""

PER_TRACE_ANCHOR_KEY = "per_anchor_typical"
"""Key of :attr:`SideEvidence.per_trace` entries holding each anchor's own :data:`TYPICAL_METRICS` in that trace."""


# ---------------------------------------------------------------- small numeric helpers
def _num(x: Any) -> float:
    """A JSON number back to float (None -> NaN)."""
    return float("nan") if x is None else float(x)


def _fill_gaps(y: np.ndarray) -> np.ndarray | None:
    """(K, 3) grid IMU with NaN rows -> linearly filled copy, or None when too few rows are finite."""
    ok = np.all(np.isfinite(y), axis=1)
    if y.shape[0] < 2 or ok.mean() < IMU_MIN_FINITE_FRAC:
        return None
    if ok.all():
        return y
    k = np.arange(y.shape[0])
    return np.stack([np.interp(k, k[ok], y[ok, c]) for c in range(y.shape[1])], axis=1)


def _allan_m_grid(rate_hz: float) -> np.ndarray:
    """Averaging factors: log-spaced from one grid step to ~300 s, plus the reported taus exactly."""
    top = max(np.log10(300.0 * rate_hz), 1.0)
    m = np.round(np.logspace(0.0, top, int(10 * top) + 1))
    m = np.concatenate([m, np.round(np.asarray(ALLAN_TAUS_S) * rate_hz)])
    return np.unique(np.maximum(m, 1)).astype(np.int64)


# ---------------------------------------------------------------- evidence (arrays for the figures)
@dataclass(frozen=True, slots=True, kw_only=True)
class SideEvidence:
    """Everything the figures need about one side (real or synthetic), reduced from its traces.

    Positions ENU [m], times [s] since each trace's start, residuals [m]. Per-trace lists hold at
    most :data:`MAX_PLOT_TRACES` entries.
    """

    n_traces: int
    anchors: Anchors
    metrics: Metrics
    residual_m: np.ndarray
    residual_anchor: np.ndarray  # (R,) anchor id (object) of each residual
    gap_s: np.ndarray
    gap_anchor: np.ndarray  # (G,) anchor id (object) of each gap
    aoi_s: np.ndarray  # every AoI value of every anchor and grid step, pooled
    n_fresh_counts: np.ndarray  # (A+1,) grid steps with 0..A fresh anchors
    paths_enu_m: tuple[np.ndarray, ...]  # decimated truth positions, (T', 3) each
    speeds: tuple[tuple[np.ndarray, np.ndarray], ...]  # (t_s, speed_mps) each, decimated
    mean_aoi_series: tuple[np.ndarray, ...]  # per grid step, mean AoI over anchors [s]
    n_fresh_series: tuple[np.ndarray, ...]  # per grid step, number of fresh anchors
    sample: Trace  # the first trace, for the range-versus-time figure
    acf: np.ndarray  # (ACF_MAX_LAG,)
    acf_inliers: np.ndarray  # (ACF_MAX_LAG,), residuals within INLIER_HALF_WIDTH_M of their anchor's median
    burst_deviation_std_m: float  # within-burst deviation of the inlier residuals (NaN: no burst of 2+)
    still_correlation: dict[str, float]  # "still", "moving": inlier residual correlation 1-3 s apart (NaN: no pair)
    psd_f_hz: np.ndarray | None
    psd_mps2_sq_per_hz: np.ndarray | None  # (3, F)
    allan_tau_s: np.ndarray | None
    allan_dev_mps2: np.ndarray | None  # (3, M), NaN where no trace is long enough
    rate_hz: float
    per_trace: tuple[dict[str, Any], ...]  # each trace's own metrics (Metrics.to_dict without per_anchor), and
    # PER_TRACE_ANCHOR_KEY: {metric: {anchor id: value}} for the per-anchor typical values


@dataclass(frozen=True, slots=True, kw_only=True)
class Evidence:
    """The arrays behind a report (for :mod:`physynth.validate.render`); never serialised."""

    real: SideEvidence
    synthetic: SideEvidence


class _SideAccumulator:
    """Reduces traces one at a time to their summaries and the extended-statistics ingredients."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.n_traces = 0
        self.metrics = MetricsAccumulator()
        self.per_trace: list[dict[str, Any]] = []
        self.residuals: dict[str, QuantileSketch] = {}  # per anchor id
        self.gaps: dict[str, QuantileSketch] = {}  # per anchor id
        self.aoi = QuantileSketch()
        self.n_fresh_counts = np.zeros(1, dtype=np.int64)
        self.paths: list[np.ndarray] = []
        self.speeds: list[tuple[np.ndarray, np.ndarray]] = []
        self.mean_aoi_series: list[np.ndarray] = []
        self.n_fresh_series: list[np.ndarray] = []
        self.sample: Trace | None = None
        self.anchors: Anchors | None = None
        self.acf_num = np.zeros(ACF_MAX_LAG)
        self.acf_den = 0.0
        self.acf_in_num = np.zeros(ACF_MAX_LAG)
        self.acf_in_den = 0.0
        self.burst_dev_ss = 0.0
        self.burst_dev_n = 0
        self.still_sums = {k: np.zeros(3) for k in ("still", "moving")}  # sum x_i x_j, x_i^2, x_j^2
        self.allan_m = _allan_m_grid(rate_hz)
        self.allan_sums = np.zeros((3, self.allan_m.size))
        self.allan_counts = np.zeros(self.allan_m.size, dtype=np.int64)
        self.nperseg = max(int(round(WELCH_SEGMENT_S * rate_hz)), 8)
        self.psd_sum: np.ndarray | None = None
        self.psd_f: np.ndarray | None = None
        self.psd_weight = 0.0

    def add(self, trace: Trace) -> None:
        rate = self.rate_hz
        if self.sample is None:
            self.sample, self.anchors = trace, trace.anchors
        s = summarize(trace, rate)  # the section-5 ingredients, from physynth.evaluate.metrics
        self.metrics.add(s)
        # the trace's own metrics (a few numbers, for the ensemble's 5-95 % band), not its arrays
        own = pool([s]).to_dict()
        anchors = own.pop("per_anchor", None) or {}
        own[PER_TRACE_ANCHOR_KEY] = {k: {a: m.get(k) for a, m in anchors.items()} for k in TYPICAL_METRICS}
        self.per_trace.append(own)
        self.n_traces += 1
        ids = np.asarray(trace.anchors.ids, dtype=object)
        for a in trace.anchors.ids:
            if a not in self.residuals:
                self.residuals[a], self.gaps[a] = QuantileSketch(), QuantileSketch()
        for j, a in enumerate(trace.anchors.ids):
            self.residuals[a].add(s.residual_m[s.residual_anchor_index == j])

        # grid: fresh anchors per step and AoI (physynth.evaluate.grid, the one definition)
        t = grid_times(trace.t0_s, trace.duration_s, rate)
        fresh = fresh_mask(trace, t, rate)
        aoi = age_of_information(trace, t)
        n_fresh = fresh.sum(axis=1)
        counts = np.bincount(n_fresh, minlength=len(trace.anchors) + 1)
        if counts.size > self.n_fresh_counts.size:
            self.n_fresh_counts = np.pad(self.n_fresh_counts, (0, counts.size - self.n_fresh_counts.size))
        self.n_fresh_counts[:counts.size] += counts
        self.aoi.add(aoi.ravel())

        # gaps between consecutive valid ranges of one anchor
        uwb = trace.uwb
        ok = uwb.valid
        tv, av = uwb.t_s[ok], uwb.anchor[ok]
        order = np.lexsort((tv, av))
        tv, av = tv[order], av[order]
        same = av[1:] == av[:-1]
        gap, gap_a = np.diff(tv)[same], av[1:][same]
        for j in np.unique(gap_a):
            self.gaps[str(ids[j])].add(gap[gap_a == j])

        # residual autocorrelation within each anchor's (time-ordered) sequence
        if s.residual_m.size:
            a_idx = s.residual_anchor_index
            order = np.argsort(a_idx, kind="stable")  # keeps time order within an anchor
            x, a = s.residual_m[order], a_idx[order]
            with np.errstate(invalid="ignore", divide="ignore"):  # anchors without residuals: never indexed
                x = x - (np.bincount(a, weights=x) / np.bincount(a))[a]
            self.acf_den += float(x @ x)
            for k in range(1, ACF_MAX_LAG + 1):
                if x.size > k:
                    same_k = a[k:] == a[:-k]
                    self.acf_num[k - 1] += float(np.dot(x[k:][same_k], x[:-k][same_k]))
            self._add_inlier_acf(s.residual_m[order], a)
            self._add_burst_deviation(trace)
            self._add_still_correlation(trace)

        # IMU: Allan variance and Welch spectrum of the 100 Hz-grid acceleration
        y = _fill_gaps(s.imu_grid_mps2) if trace.imu is not None else None
        if y is not None:
            sums, cnt = overlapping_allan_variance_sums(y, self.allan_m, rate)
            self.allan_sums += sums
            self.allan_counts += cnt
            if y.shape[0] >= self.nperseg:
                from scipy import signal  # imported where used: 0.9 s that most commands do not need

                f, p = signal.welch(y, fs=rate, nperseg=self.nperseg, axis=0, detrend="constant")
                w = y.shape[0] / self.nperseg
                self.psd_sum = p.T * w if self.psd_sum is None else self.psd_sum + p.T * w
                self.psd_f = f
                self.psd_weight += w

        # per-trace series for the figures (capped)
        if len(self.paths) < MAX_PLOT_TRACES:
            step = max(1, trace.truth.t_s.size // 1500)
            tt = trace.truth.t_s[::step]
            self.paths.append(trace.truth.pos_enu_m[::step].copy())
            self.speeds.append((tt - trace.t0_s, np.linalg.norm(trace.truth.vel_enu_mps[::step], axis=1)))
            self.mean_aoi_series.append(aoi.mean(axis=1).astype(np.float32))
            self.n_fresh_series.append(n_fresh.astype(np.int8))

    def _add_inlier_acf(self, r: np.ndarray, a: np.ndarray) -> None:
        """Lag sums of the residuals within INLIER_HALF_WIDTH_M of their anchor's median (anchor-sorted
        ``a``, time order within an anchor), each anchor's inlier mean removed, consecutive inliers."""
        starts = np.flatnonzero(np.r_[True, a[1:] != a[:-1]])
        med = np.repeat(np.array([np.median(r[i:j]) for i, j in zip(starts, np.r_[starts[1:], a.size], strict=True)]),
                        np.diff(np.r_[starts, a.size]))  # one median per anchor: a loop over anchors
        keep = np.abs(r - med) < INLIER_HALF_WIDTH_M
        x, b = r[keep], a[keep]
        if x.size < 2:
            return
        x = x - (np.bincount(b, weights=x) / np.maximum(np.bincount(b), 1))[b]
        self.acf_in_den += float(x @ x)
        for k in range(1, ACF_MAX_LAG + 1):
            if x.size > k:
                same_k = b[k:] == b[:-k]
                self.acf_in_num[k - 1] += float(np.dot(x[k:][same_k], x[:-k][same_k]))

    def _add_burst_deviation(self, trace: Trace) -> None:
        """Sums of the within-burst deviations: each inlier residual (within INLIER_HALF_WIDTH_M of its
        anchor's median, that median removed) minus the mean of its burst, bursts of two anchors or
        more, scaled by sqrt(n / (n - 1)) so that independent errors of std s give s."""
        from ..evaluate.metrics import residuals

        r, a, t = residuals(trace)
        if r.size < 2:
            return
        med = np.zeros(len(trace.anchors))
        for j in np.unique(a):  # one median per anchor: a loop over anchors
            med[j] = np.median(r[a == j])
        x = r - med[a]
        keep = np.abs(x) < INLIER_HALF_WIDTH_M
        order = np.argsort(t[keep], kind="stable")
        x, a, t = x[keep][order], a[keep][order], t[keep][order]
        if x.size < 2:
            return
        same = np.diff(t)
        per_anchor = [np.median(np.diff(t[a == j])) for j in np.unique(a) if np.count_nonzero(a == j) > 1]
        gap = min(BURST_GAP_S, 0.5 * float(np.min(per_anchor))) if per_anchor else BURST_GAP_S
        burst = np.concatenate([[0], np.cumsum(same > gap)])
        n = np.bincount(burst)
        mean = np.bincount(burst, weights=x) / n
        multi = n[burst] >= 2
        dev = (x - mean[burst])[multi]
        self.burst_dev_ss += float(np.sum(dev * dev * (n[burst][multi] / (n[burst][multi] - 1.0))))
        self.burst_dev_n += int(dev.size)

    def _add_still_correlation(self, trace: Trace) -> None:
        """Sums of the products of one anchor's inlier residuals (within INLIER_HALF_WIDTH_M of its median,
        its inlier mean removed) in pairs STILL_LAG_S apart, by the distance the tag travelled between
        them (truth speed integrated): less than STILL_MAX_M (still) or MOVING_MIN_M and more (moving).
        A slow error tied to the tag's place and carriage holds while it stands still; one tied to the
        clock fades alike in both."""
        from ..evaluate.metrics import residuals
        from ..models.uwb import travelled_m

        r, a, t = residuals(trace)
        clock = np.interp(t, trace.truth.t_s, travelled_m(trace.truth.t_s, trace.truth.vel_enu_mps))
        for j in np.unique(a):  # one anchor at a time: its rows in time order
            m = a == j
            x, tj, cj = r[m], t[m], clock[m]
            order = np.argsort(tj, kind="stable")
            x, tj, cj = x[order], tj[order], cj[order]
            keep = np.abs(x - np.median(x)) < INLIER_HALF_WIDTH_M
            x, tj, cj = x[keep], tj[keep], cj[keep]
            if x.size < 2:
                continue
            x = x - x.mean()
            for k in range(1, x.size):
                dt = tj[k:] - tj[:-k]
                if dt.min() > STILL_LAG_S[1]:
                    break
                pair = (dt >= STILL_LAG_S[0]) & (dt <= STILL_LAG_S[1])
                dc = cj[k:] - cj[:-k]
                for key, sel in (("still", pair & (dc < STILL_MAX_M)), ("moving", pair & (dc >= MOVING_MIN_M))):
                    xi, xj = x[:-k][sel], x[k:][sel]
                    self.still_sums[key] += (float(xi @ xj), float(xi @ xi), float(xj @ xj))

    def finish(self) -> tuple[SideEvidence, np.ndarray]:
        metrics = self.metrics.result()  # exactly what metrics.compute_metrics returns
        assert self.sample is not None and self.anchors is not None
        r, r_anchor = _pooled(self.residuals)
        gap, gap_anchor = _pooled(self.gaps)
        with np.errstate(invalid="ignore", divide="ignore"):
            acf = self.acf_num / self.acf_den if self.acf_den > 0 else np.full(ACF_MAX_LAG, np.nan)
            acf_in = self.acf_in_num / self.acf_in_den if self.acf_in_den > 0 else np.full(ACF_MAX_LAG, np.nan)
            allan = np.sqrt(self.allan_sums / np.where(self.allan_counts > 0, self.allan_counts, np.nan))
        has_allan = bool(np.any(self.allan_counts > 0))
        ev = SideEvidence(
            n_traces=self.n_traces,
            anchors=self.anchors,
            metrics=metrics,
            residual_m=r,
            residual_anchor=r_anchor,
            gap_s=gap,
            gap_anchor=gap_anchor,
            aoi_s=self.aoi.values(),
            n_fresh_counts=self.n_fresh_counts,
            paths_enu_m=tuple(self.paths),
            speeds=tuple(self.speeds),
            mean_aoi_series=tuple(self.mean_aoi_series),
            n_fresh_series=tuple(self.n_fresh_series),
            sample=self.sample,
            acf=acf,
            acf_inliers=acf_in,
            burst_deviation_std_m=(float(np.sqrt(self.burst_dev_ss / self.burst_dev_n)) if self.burst_dev_n
                                   else float("nan")),
            still_correlation={k: (float(v[0] / np.sqrt(v[1] * v[2])) if v[1] > 0 and v[2] > 0 else float("nan"))
                               for k, v in self.still_sums.items()},
            psd_f_hz=self.psd_f,
            psd_mps2_sq_per_hz=None if self.psd_sum is None else self.psd_sum / self.psd_weight,
            allan_tau_s=self.allan_m / self.rate_hz if has_allan else None,
            allan_dev_mps2=allan if has_allan else None,
            rate_hz=self.rate_hz,
            per_trace=tuple(self.per_trace),
        )
        return ev, r


def _pooled(sketches: Mapping[str, QuantileSketch]) -> tuple[np.ndarray, np.ndarray]:
    """Values of per-anchor sketches pooled, with the anchor id of each value.

    Exact values while a sketch is exact; a folded sketch stands in with evenly spaced quantiles in
    proportion to its count (:mod:`physynth.evaluate.sketch`), so pooled statistics keep its weight.
    """
    total = sum(sk.n for sk in sketches.values())
    vals, labels = [], []
    for a, sk in sketches.items():
        if sk.n == 0:
            continue
        k = max(1, round(REPRESENTATIVES * sk.n / total)) if sk.folded else sk.n
        v = sk.values(k)
        vals.append(v)
        labels.append(np.full(v.size, a, dtype=object))
    if not vals:
        return np.zeros(0), np.array([], dtype=object)
    return np.concatenate(vals), np.concatenate(labels)


