"""The metrics of DESIGN.md section 5, written once; generator tests, ``inspect``, calibration checks,
validation and the studies all call this module.

Pooling over several traces: durations are averaged; grid fractions and mean AoI are taken over all
grid bins of all traces; residual statistics over all valid ranges of all traces; IMU standard
deviations over the concatenated 100 Hz-grid IMU values.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_GRID_RATE_HZ
from ..records import Trace
from .grid import age_of_information as _aoi
from .grid import fresh_mask, grid_times, imu_on_grid
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

    Returns (residual_m, anchor_index, t_s); ranges outside the truth time span are left out.
    """
    uwb = trace.uwb
    ok = uwb.valid
    t = uwb.t_s[ok]
    idx = uwb.anchor[ok].astype(np.intp)
    pos = trace.truth.position_at(t)
    geom = np.linalg.norm(pos - trace.anchors.pos_enu_m[idx], axis=1)
    r = uwb.range_m[ok] - geom
    keep = np.isfinite(r)
    return r[keep], idx[keep], t[keep]


def _residual_stats(r: np.ndarray) -> dict[str, float]:
    if r.size == 0:
        nan = float("nan")
        return {"residual_std_m": nan, "residual_median_m": nan, "abs_residual_p95_m": nan,
                "abs_residual_p99_m": nan}
    a = np.abs(r)
    p95, p99 = np.percentile(a, [95.0, 99.0])
    return {
        "residual_std_m": float(np.std(r)),
        "residual_median_m": float(np.median(r)),
        "abs_residual_p95_m": float(p95),
        "abs_residual_p99_m": float(p99),
    }


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


def pool(summaries: Sequence[TraceSummary]) -> tuple[Metrics, np.ndarray]:
    """Pooled metrics and the pooled signed residuals of per-trace summaries."""
    if not summaries:
        raise ValueError("no traces to compute metrics on")
    n_bins = sum(s.n_bins for s in summaries)
    r = np.concatenate([s.residual_m for s in summaries])
    r_anchor = np.concatenate([s.residual_anchor for s in summaries])
    anchor_ids: list[str] = []
    for s in summaries:
        anchor_ids += [a for a in s.anchor_ids if a not in anchor_ids]
    fresh = dict.fromkeys(anchor_ids, 0)
    aoi_sum = dict.fromkeys(anchor_ids, 0.0)
    bins = dict.fromkeys(anchor_ids, 0)
    for s in summaries:
        for j, a in enumerate(s.anchor_ids):
            fresh[a] += int(s.fresh_per_anchor[j])
            aoi_sum[a] += float(s.aoi_sum_per_anchor[j])
            bins[a] += s.n_bins
    per_anchor = {}
    for a in anchor_ids:
        ra = r[r_anchor == a]
        per_anchor[a] = {
            "n_ranges": int(ra.size),
            "fresh_frac": fresh[a] / bins[a],
            "mean_aoi_s": aoi_sum[a] / bins[a],
            **_residual_stats(ra),
        }
    imu = np.concatenate([s.imu_grid_mps2 for s in summaries])
    imu = imu[np.all(np.isfinite(imu), axis=1)]
    imu_std = tuple(float(v) for v in np.std(imu, axis=0)) if imu.shape[0] > 1 else (np.nan,) * 3
    total_anchor_bins = sum(bins.values())
    metrics = Metrics(
        duration_s=float(np.mean([s.duration_s for s in summaries])),
        uwb_ge1_frac=sum(s.ge1 for s in summaries) / n_bins,
        uwb_ge2_frac=sum(s.ge2 for s in summaries) / n_bins,
        mean_aoi_s=sum(aoi_sum.values()) / total_anchor_bins if total_anchor_bins else float("nan"),
        imu_std_mps2=imu_std,  # type: ignore[arg-type]
        per_anchor=per_anchor,
        n_traces=len(summaries),
        n_residuals=int(r.size),
        **_residual_stats(r),
    )
    return metrics, r


def compute_metrics(traces: Iterable[Trace], rate_hz: float = DEFAULT_GRID_RATE_HZ) -> Metrics:
    """Pooled section-5 metrics of traces."""
    return pool([summarize(t, rate_hz) for t in traces])[0]


def pooled_residuals(traces: Iterable[Trace]) -> np.ndarray:
    """All signed residuals of the traces, concatenated [m]."""
    parts = [residuals(t)[0] for t in traces]
    return np.concatenate(parts) if parts else np.array([])


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
