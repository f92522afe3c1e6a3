"""Validation: real traces against synthetic traces -> a frozen, JSON-able :class:`ValidationReport`
(the record itself lives in :mod:`physynth.validate.report_model`, the floor below, and is named here too).

The paper's tables (section IV, Tables I-II) are computed with :mod:`physynth.evaluate.metrics`
(written once there; docs/data-and-metrics.md): pooled section-5 metrics of each side, their relative deviations,
the KS statistic of the pooled signed residuals and the fidelity score. On top of them the report
holds *extended* statistics that a reviewer of synthetic data asks for (docs/validation.md):

- distances between the residual distributions beyond KS: Wasserstein-1 and Anderson-Darling;
- KS of the gap lengths between consecutive valid measurements of an anchor and of the AoI values;
- residual autocorrelation at lags 1..10 measurements (per anchor sequence, pooled);
- IMU Allan-deviation ratio at tau = 0.1, 1, 10 s and the log-spectral distance of the acceleration
  power spectral densities (only when both sides have IMU data).

Traces are reduced one at a time (:mod:`physynth.validate.evidence`), so the synthetic ensemble is
never held in memory as a whole; the arrays that the figures need travel with the report as
:class:`~physynth.validate.evidence.Evidence` (not part of the JSON form).

All computations are vectorised over samples; the loops that remain run over anchors, lags or
averaging times.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__
from .._json import jsonable
from ..constants import DEFAULT_GRID_RATE_HZ
from ..errors import PhySynthError
from ..evaluate.metrics import (
    METRIC_KEYS,
    fidelity_score,
    relative_deviation_pct,
)
from ..evaluate.stats import (
    anderson_darling,
    ks_statistic,
    wasserstein,
)
from ..records import Trace
from .evidence import (
    ACF_MAX_LAG,
    ALLAN_TAUS_S,
    PER_TRACE_ANCHOR_KEY,
    TYPICAL_METRICS,
    Evidence,
    SideEvidence,
    _num,
    _SideAccumulator,
)
from .report_model import EXTENDED_STATISTICS as EXTENDED_STATISTICS  # the record, a floor below: named here as before
from .report_model import MIN_BAND_TRACES, ValidationReport
from .report_model import TRUTH_PAST_UWB_S as TRUTH_PAST_UWB_S
from .report_model import band_note as band_note
from .report_model import read_report as read_report
from .report_model import truth_past_uwb_line as truth_past_uwb_line

if TYPE_CHECKING:
    from ..scenario import Scenario

SIGNED_METRICS = ("residual_median_m",)
"""Metrics that are signed and may lie near zero: compared by their absolute difference synth - real
(a relative deviation of a 1 cm median is meaningless); ``relative_deviation_pct`` holds None for them."""

BAND_PERCENTILES = (5.0, 95.0)
"""The synthetic ensemble's band of a metric: these percentiles of its per-trace values."""


TRANSFER_FROM_REAL = ("path", "motion", "anchors")
"""Scenario sections that ``--transfer`` takes from the real dataset (paper section IV.C)."""
TRANSFER_FROM_REAL_FIELDS = {"uwb": ("burst_phase_s",)}
"""Single fields taken from the real run: the burst clock's alignment with the recording's time base."""


def _deviations(real: Mapping[str, Any], synth: Mapping[str, Any], keys: Iterable[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k in keys:
        if k in SIGNED_METRICS:
            out[k] = None
            continue
        a, b = real.get(k), synth.get(k)
        if isinstance(a, (list, tuple)):
            out[k] = [relative_deviation_pct(_num(x), _num(y)) for x, y in zip(a, b, strict=True)]
        else:
            out[k] = relative_deviation_pct(_num(a), _num(b))
    return out


def typical_value(per_trace: Sequence[Mapping[str, Any]], key: str, group: int) -> float:
    """Median over consecutive groups of ``group`` synthetic traces of the metric pooled within each group.

    A group's value is the duration-weighted mean of its traces' values (exact for time averages such as
    the mean AoI, whose grid steps are proportional to the duration). With fewer traces than ``group``,
    the one group holds them all, i.e. the pooled value.
    """
    v = np.array([_num(t[key]) for t in per_trace], dtype=float)
    d = np.array([_num(t.get("duration_s", 1.0)) for t in per_trace], dtype=float)
    if v.size == 0:
        return float("nan")
    g = max(1, v.size // max(1, int(group)))
    n = g * max(1, min(int(group), v.size))
    vg, dg = v[:n].reshape(g, -1), d[:n].reshape(g, -1)
    ok = np.isfinite(vg) & np.isfinite(dg) & (dg > 0)
    w = np.where(ok, dg, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_group = np.sum(np.where(ok, vg, 0.0) * w, axis=1) / np.sum(w, axis=1)
    per_group = per_group[np.isfinite(per_group)]
    return float(np.median(per_group)) if per_group.size else float("nan")


def _compare_one(real: float, synth: float, values: np.ndarray, signed: bool,
                 typical: float | None = None) -> dict[str, Any]:
    vals = values[np.isfinite(values)]
    if vals.size < MIN_BAND_TRACES:  # one value, or the segment between two: no band to be inside of
        band = None
    else:
        band = [float(v) for v in np.percentile(vals, BAND_PERCENTILES)]
    diff = synth - real
    ref = synth if typical is None else typical
    extra = {} if typical is None else {"typical": typical, "deviation_against": "typical"}
    return {"real": real, "synthetic": synth, "difference": diff, **extra,
            "deviation": diff if signed else relative_deviation_pct(real, ref),
            "deviation_kind": "absolute" if signed else "relative_pct",
            "band_5_95": band, "n_traces_in_band": int(vals.size),
            "real_in_band": bool(band[0] <= real <= band[1]) if np.isfinite(real) and band is not None else None}


def comparison_table(real: Mapping[str, Any], synth: Mapping[str, Any], per_trace: Sequence[Mapping[str, Any]],
                     keys: Iterable[str] = METRIC_KEYS, n_real: int = 1) -> dict[str, Any]:
    """Per metric: both values, the deviation (absolute for signed metrics) and the synthetic 5-95 % band.

    ``per_trace`` holds the metrics of every synthetic trace on its own; the band is the
    :data:`BAND_PERCENTILES` of their values, so it shows how far one synthetic run strays from
    another, and ``real_in_band`` whether the real run could be one of them. For the
    :data:`TYPICAL_METRICS` the deviation is against :func:`typical_value` over groups of ``n_real``
    traces (the real side's number of traces), recorded as ``typical``.
    """
    out: dict[str, Any] = {}
    for k in keys:
        a, b = real.get(k), synth.get(k)
        signed = k in SIGNED_METRICS
        if isinstance(a, (list, tuple)):
            vals = np.array([[_num(x) for x in t[k]] for t in per_trace], dtype=float).reshape(len(per_trace), -1)
            out[k] = [_compare_one(_num(x), _num(y), vals[:, i], signed)
                      for i, (x, y) in enumerate(zip(a, b, strict=True))]
        else:
            typ = None
            if k in TYPICAL_METRICS and per_trace:  # one group of every trace: exactly the pooled value
                typ = _num(b) if len(per_trace) <= n_real else typical_value(per_trace, k, n_real)
            out[k] = _compare_one(_num(a), _num(b), np.array([_num(t[k]) for t in per_trace], dtype=float), signed,
                                  typ)
    return jsonable(out)


def _quantiles(x: np.ndarray) -> list[float]:
    if x.size == 0:
        return [float("nan")] * 4
    return [float(v) for v in np.percentile(x, [50.0, 95.0, 99.0])] + [float(x.max())]


def _finite(x: float) -> float | None:
    """``x``, or None (JSON null) where it is NaN or infinite."""
    return float(x) if np.isfinite(x) else None


def _extended(real: SideEvidence, synth: SideEvidence) -> dict[str, Any]:
    ad, ad_p = anderson_darling(real.residual_m, synth.residual_m)
    ext: dict[str, Any] = {
        "residual_wasserstein_m": wasserstein(real.residual_m, synth.residual_m),
        "residual_anderson_darling": ad,
        "residual_anderson_darling_pvalue": ad_p,
        "gap_ks_statistic": ks_statistic(real.gap_s, synth.gap_s),
        "gap_quantiles_s": {"quantiles": ["p50", "p95", "p99", "max"],
                            "real": _quantiles(real.gap_s), "synthetic": _quantiles(synth.gap_s)},
        "aoi_ks_statistic": ks_statistic(real.aoi_s, synth.aoi_s),
        "residual_acf": {"lags": list(range(1, ACF_MAX_LAG + 1)), "real": real.acf.tolist(),
                         "synthetic": synth.acf.tolist()},
        "residual_acf_max_abs_diff": float(np.max(np.abs(synth.acf - real.acf))),
        "residual_acf_inliers": {"lags": list(range(1, ACF_MAX_LAG + 1)), "real": real.acf_inliers.tolist(),
                                 "synthetic": synth.acf_inliers.tolist()},
        "residual_acf_inliers_max_abs_diff": float(np.max(np.abs(synth.acf_inliers - real.acf_inliers))),
        "residual_burst_deviation_std_m": {"real": _finite(real.burst_deviation_std_m),
                                           "synthetic": _finite(synth.burst_deviation_std_m)},
        "residual_burst_deviation_ratio": _finite(synth.burst_deviation_std_m / real.burst_deviation_std_m
                                                  if real.burst_deviation_std_m > 0 else float("nan")),
        "residual_still_correlation": {k: {"real": _finite(real.still_correlation[k]),
                                           "synthetic": _finite(synth.still_correlation[k])}
                                       for k in ("still", "moving")},
    }
    both_imu = real.allan_dev_mps2 is not None and synth.allan_dev_mps2 is not None
    if both_imu:
        m = np.round(np.asarray(ALLAN_TAUS_S) * real.rate_hz).astype(np.int64)
        idx = np.searchsorted(np.round(real.allan_tau_s * real.rate_hz).astype(np.int64), m)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = synth.allan_dev_mps2[:, idx] / real.allan_dev_mps2[:, idx]  # (3, len(taus))
        ext["imu_allan_ratio"] = {"tau_s": list(ALLAN_TAUS_S), "axes": ["e", "n", "u"],
                                  "ratio": ratio.tolist(),
                                  "real_mps2": real.allan_dev_mps2[:, idx].tolist(),
                                  "synthetic_mps2": synth.allan_dev_mps2[:, idx].tolist()}
    else:
        ext["imu_allan_ratio"] = None
    if both_imu and real.psd_mps2_sq_per_hz is not None and synth.psd_mps2_sq_per_hz is not None \
            and np.array_equal(real.psd_f_hz, synth.psd_f_hz):
        f = real.psd_f_hz
        band = f > 0
        tiny = np.finfo(float).tiny
        ratio_db = 10.0 * np.log10(np.maximum(synth.psd_mps2_sq_per_hz[:, band], tiny)
                                   / np.maximum(real.psd_mps2_sq_per_hz[:, band], tiny))
        lsd = np.sqrt(np.mean(ratio_db**2, axis=1))
        ext["imu_log_spectral_distance_db"] = {"axes": ["e", "n", "u"], "per_axis": lsd.tolist(),
                                               "mean": float(lsd.mean()),
                                               "band_hz": [float(f[band][0]), float(f[band][-1])]}
    else:
        ext["imu_log_spectral_distance_db"] = None
    if not both_imu:
        ext["imu_note"] = (("neither side has" if real.allan_dev_mps2 is None and synth.allan_dev_mps2 is None
                            else "the real data has no" if real.allan_dev_mps2 is None
                            else "the synthetic data has no") + " usable IMU samples")
    return ext


PER_ANCHOR_DEVIATION_KEYS = ("fresh_frac", "mean_aoi_s", "residual_std_m", "residual_median_m",
                             "abs_residual_p95_m", "abs_residual_p99_m")


def _anchor_typical(synth: SideEvidence, anchor: str, pooled: Mapping[str, Any], n_real: int) -> dict[str, float]:
    """The :data:`TYPICAL_METRICS` of one anchor over groups of ``n_real`` synthetic traces (as Table II's)."""
    out = {}
    for k in TYPICAL_METRICS:
        if len(synth.per_trace) <= n_real:  # one group of every trace: exactly the pooled value
            out[k] = _num(pooled.get(k))
            continue
        rows = [{k: t[PER_TRACE_ANCHOR_KEY][k].get(anchor), "duration_s": t.get("duration_s")}
                for t in synth.per_trace]
        out[k] = typical_value(rows, k, n_real)
    return out


def _per_anchor(real: SideEvidence, synth: SideEvidence) -> dict[str, Any]:
    ids = list(real.metrics.per_anchor) + [a for a in synth.metrics.per_anchor if a not in real.metrics.per_anchor]
    out: dict[str, Any] = {}
    for a in ids:
        ra = real.residual_m[real.residual_anchor == a]
        sa = synth.residual_m[synth.residual_anchor == a]
        pr, ps = real.metrics.per_anchor.get(a), synth.metrics.per_anchor.get(a)
        typical = _anchor_typical(synth, a, ps, real.n_traces) if ps is not None else {}
        deviations = None
        if pr is not None and ps is not None:
            deviations = _deviations(pr, ps, PER_ANCHOR_DEVIATION_KEYS)
            deviations.update({k: relative_deviation_pct(_num(pr.get(k)), v) for k, v in typical.items()})
        out[a] = {
            "real": pr,
            "synthetic": ps,
            "typical": typical or None,
            "relative_deviation_pct": deviations,
            "ks_statistic": ks_statistic(ra, sa),
            "residual_wasserstein_m": wasserstein(ra, sa),
            "gap_ks_statistic": ks_statistic(real.gap_s[real.gap_anchor == a], synth.gap_s[synth.gap_anchor == a]),
        }
    return out


def compare(real: Iterable[Trace], synthetic: Iterable[Trace], *, rate_hz: float = DEFAULT_GRID_RATE_HZ,
            inputs: Mapping[str, Any] | None = None, transfer: Mapping[str, Any] | None = None,
            on_trace: Callable[[], None] | None = None) -> ValidationReport:
    """Compare real traces with synthetic traces.

    Parameters
    ----------
    real, synthetic : iterable of Trace
        Consumed once, one trace at a time (a generator of synthetic traces is never held whole).
    rate_hz : float
        Evaluation grid rate [Hz] (docs/data-and-metrics.md: 100 Hz).
    inputs, transfer : mapping, optional
        Provenance copied into the report.
    on_trace : callable, optional
        Called with no argument after each synthetic trace (progress display).

    Returns
    -------
    ValidationReport
        With :class:`Evidence` attached for :func:`physynth.validate.render.write_report`.

    Raises
    ------
    PhySynthError
        When a side holds no trace.
    """
    from .imu_errors import ImuErrorAccumulator

    sides, imu_err = {}, {}
    for name, traces in (("real", real), ("synthetic", synthetic)):
        acc, errs = _SideAccumulator(rate_hz), ImuErrorAccumulator(BODY_IMU_ERRORS)
        for tr in traces:
            acc.add(tr)
            errs.add(tr)
            if name == "synthetic" and on_trace is not None:
                on_trace()
        if not acc.n_traces:
            raise PhySynthError(f"the {name} side holds no traces")
        sides[name], imu_err[name] = acc.finish(), errs.finish()
    (ev_r, r_real), (ev_s, r_synth) = sides["real"], sides["synthetic"]
    m_real, m_synth = ev_r.metrics.to_dict(), ev_s.metrics.to_dict()
    comparison = comparison_table(m_real, m_synth, ev_s.per_trace, n_real=ev_r.n_traces)
    deviations = _deviations(m_real, m_synth, METRIC_KEYS)
    deviations.update({k: comparison[k]["deviation"] for k in TYPICAL_METRICS if "typical" in comparison[k]})
    info = {
        "n_traces": {"real": ev_r.n_traces, "synthetic": ev_s.n_traces},
        "n_residuals": {"real": int(r_real.size), "synthetic": int(r_synth.size)},
        "grid_rate_hz": float(rate_hz),
        "physynth_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        **(dict(inputs) if inputs else {}),
    }
    return ValidationReport(
        real=m_real,
        synthetic=m_synth,
        relative_deviation_pct=deviations,
        ks_statistic=ks_statistic(r_real, r_synth),
        fidelity_score=fidelity_score(ev_r.metrics, ev_s.metrics),
        extended=_extended(ev_r, ev_s),
        per_anchor=_per_anchor(ev_r, ev_s),
        inputs=jsonable(info),
        transfer=jsonable(dict(transfer)) if transfer is not None else None,
        comparison=comparison,
        imu_errors=_imu_errors(imu_err["real"], imu_err["synthetic"]),
        evidence=Evidence(real=ev_r, synthetic=ev_s),
    )


BODY_IMU_ERRORS = ("acc_body", "gyro")
"""IMU error kinds compared by :func:`compare` (body-frame accelerometer and gyroscope, when both sides
have them). The ENU acceleration is compared by Table I, the spectrum and the Allan deviation of the
extended statistics; its error against the truth is compared by the IMU-only validation."""


def _imu_errors(rs: dict[str, Any], ss: dict[str, Any]) -> dict[str, Any] | None:
    """The ``imu_errors`` block: IMU error statistics of the kinds both sides have, else None."""
    from .imu_errors import imu_error_comparison

    if not set(rs) & set(ss):
        return None
    r, s, dev, ext = imu_error_comparison(rs, ss)
    return jsonable({"real": r, "synthetic": s, "relative_deviation_pct": dev, "extended": ext})


# ---------------------------------------------------------------- datasets and scenarios (the CLI's entry)
def anchor_ids(traces: Sequence[Trace]) -> list[str]:
    ids: list[str] = []
    for tr in traces:
        ids += [a for a in tr.anchors.ids if a not in ids]
    return ids


MIN_VALID_RANGES = 30
"""Fewest valid real ranges a validation accepts (a KS statistic from 3 ranges says nothing)."""


def check_validate_budget(scn: Any, n: int, *, force: bool = False) -> None:
    """Refuse, before any work, a validation whose synthetic side is too big to generate and reduce.

    Unlike a generation (:func:`physynth.bounds.check_budget`), a validation writes no trace: it
    streams them, one in memory at a time. So the memory budget applies to one trace, and the volume of
    samples of all ``n`` (against the output budget, which bounds what a generation may make) is a
    bound on the time it takes, not on disk use. A scenario whose trip is too short is refused always.

    Raises
    ------
    ScenarioError, BudgetError
        As :func:`~physynth.bounds.check_budget`, with messages about memory and time.
    """
    from ..bounds import MEMORY_BUDGET_BYTES, OUTPUT_BUDGET_BYTES, check_trip, estimate_size
    from ..errors import BudgetError

    one, est = estimate_size(scn, 1), estimate_size(scn, n)
    check_trip(scn, one)
    if force:
        return
    if one.peak_memory_bytes > MEMORY_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': one trace of up to {one.duration_s:.4g} s needs about "
                          f"{one.peak_memory_bytes / 1e9:.3g} GB of memory (validate holds one trace at a time); "
                          f"the memory budget is {MEMORY_BUDGET_BYTES / 1e9:.3g} GB (PHYSYNTH_MEMORY_BUDGET_GB)")
    if est.sample_bytes > OUTPUT_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {n} trace(s) of up to {est.duration_s:.4g} s are about "
                          f"{est.sample_bytes / 1e9:.3g} GB of samples to generate and reduce (validate writes "
                          f"none of them, but it would take long), more than the "
                          f"{OUTPUT_BUDGET_BYTES / 1e9:.3g} GB a generation may make (PHYSYNTH_OUTPUT_BUDGET_GB); "
                          "compare with fewer traces")


def truth_past_uwb_s(traces: Sequence[Trace]) -> float:
    """The longest span [s] by which a trace's finite truth runs on past its last UWB row (0 without)."""
    worst = 0.0
    for tr in traces:
        fin = np.all(np.isfinite(tr.truth.pos_enu_m), axis=1)
        if fin.any() and tr.uwb.t_s.size:
            worst = max(worst, float(tr.truth.t_s[fin][-1] - np.max(tr.uwb.t_s)))
    return worst


def check_real(traces: Sequence[Trace], where: str) -> None:
    """Refuse real data that cannot be validated against: no truth, no anchors, no valid range."""
    from ..evaluate.metrics import residuals
    from ..records import TRUTH_UNTRUSTED_KEY

    for i, tr in enumerate(traces):
        n_truth = int(np.count_nonzero(np.all(np.isfinite(tr.truth.pos_enu_m), axis=1)))
        if n_truth < 2:
            raise PhySynthError(f"{where}: trace {i} has no ground truth ({n_truth} finite truth position(s)); "
                                "validation needs truth to compute range residuals")
        if len(tr.anchors) == 0:
            raise PhySynthError(f"{where}: trace {i} has no UWB anchors (an IMU-only recording cannot be "
                                "validated)")
    n_valid = sum(residuals(tr)[0].size for tr in traces)
    span = "inside the truth time span" + (" where the truth is trusted" if any(
        tr.meta.get(TRUTH_UNTRUSTED_KEY) for tr in traces) else "")
    if not n_valid:
        raise PhySynthError(f"{where} has no valid UWB range {span}: nothing to compare")
    if n_valid < MIN_VALID_RANGES:
        raise PhySynthError(f"{where} has only {n_valid} valid UWB range(s) {span}; the "
                            f"statistics (KS, quantiles) need at least {MIN_VALID_RANGES}")


def describe_anchor_mismatch(real_ids: Sequence[str], other_ids: Sequence[str], other: str) -> str | None:
    only_real = [a for a in real_ids if a not in other_ids]
    only_other = [a for a in other_ids if a not in real_ids]
    if not only_real and not only_other:
        return None
    parts = []
    if only_real:
        parts.append(f"only in the real dataset: {', '.join(only_real)}")
    if only_other:
        parts.append(f"only in {other}: {', '.join(only_other)}")
    return f"anchor ids differ between the real dataset and {other} ({'; '.join(parts)})"


def transfer_record(before: Scenario, after: Scenario, real_path: str, real_ids: Sequence[str]) -> dict[str, Any]:
    """What ``--transfer`` took from the real dataset and what it kept from the scenario."""
    from ..scenario import scenario_to_dict

    b, a = scenario_to_dict(before), scenario_to_dict(after)
    bookkeeping = ("name", "description", "provenance")
    sections = [k for k in a if k not in bookkeeping]
    changed = [k for k in sections if a.get(k) != b.get(k)]
    for sec, fields in TRANSFER_FROM_REAL_FIELDS.items():  # compare those sections without the run's fields
        if sec in changed and {k: v for k, v in a[sec].items() if k not in fields} == {
                k: v for k, v in b[sec].items() if k not in fields}:
            changed.remove(sec)
    per_anchor_maps = ("channel_per_anchor", "availability_per_anchor")
    # a per-anchor map restricted to the real anchors is still the scenario's: only new or altered
    # entries are a change of sensor/channel/availability parameters
    unexpected = [k for k in changed if k not in TRANSFER_FROM_REAL
                  and not (k in per_anchor_maps and all(b[k].get(i) == v for i, v in a[k].items()))]
    return {
        "policy": "paper section IV.C: path geometry, motion and anchor layout from the real dataset; "
                  "every sensor, channel and availability parameter as in the scenario",
        "scenario": before.name,
        "real_dataset": real_path,
        "from_real": [k for k in sections if k in TRANSFER_FROM_REAL]
        + [f"{sec}.{f}" for sec, fields in TRANSFER_FROM_REAL_FIELDS.items() for f in fields],
        "from_scenario": [k for k in sections if k not in TRANSFER_FROM_REAL],
        "changed_sections": changed,
        "unexpected_changes": unexpected,
        "anchors": {"scenario": list(before.anchor_ids), "real": list(real_ids),
                    "transferred": list(after.anchor_ids),
                    # real anchors the scenario has no channel of its own for (when it has per-anchor ones)
                    "pooled_channel": [i for i in after.anchor_ids
                                       if before.channel_per_anchor and i not in before.channel_per_anchor]},
        "fit": (after.provenance or {}).get("transfer"),
    }

