"""The validation report's record: :class:`ValidationReport`, :func:`read_report` and what a rendering
of it needs to say (:data:`EXTENDED_STATISTICS`, the band and truth notes).

The floor below :mod:`physynth.validate.compare` (which computes a report) and the modules that turn a
report into files (:mod:`~physynth.validate.tables`, :mod:`~physynth.validate.figures`,
:mod:`~physynth.validate.render`): they all import it, it imports none of them. The names stay
importable from :mod:`physynth.validate.compare` as well.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._json import jsonable
from ..errors import PhySynthError
from .evidence import Evidence

EXTENDED_STATISTICS: dict[str, tuple[str, str]] = {
    "residual_wasserstein_m": (
        "m", "Wasserstein-1 (earth mover's) distance between the pooled signed residuals: the mean "
             "shift, in metres, needed to turn one distribution into the other (0 = identical)."),
    "residual_anderson_darling": (
        "-", "Anderson-Darling k-sample statistic of the pooled signed residuals (scipy midrank "
             "variant): like KS but weighted towards the tails; larger = more different."),
    "residual_anderson_darling_pvalue": (
        "-", "Its tabulated p-value, floored at 0.001 and capped at 0.25 by scipy (residuals of one "
             "run are correlated, so read it as a scale, not as a test)."),
    "gap_ks_statistic": (
        "-", "KS statistic between the gap lengths (time between consecutive valid ranges of one "
             "anchor), pooled over anchors and traces: do outages and dropouts last as long?"),
    "gap_quantiles_s": (
        "s", "Median, P95, P99 and maximum gap length, real and synthetic."),
    "aoi_ks_statistic": (
        "-", "KS statistic between the AoI values of all anchors and 100 Hz grid steps."),
    "residual_acf": (
        "-", "Autocorrelation of the residuals at lags 1..10 measurements within each anchor's "
             "sequence (mean removed per trace and anchor, pooled), real and synthetic."),
    "residual_acf_max_abs_diff": (
        "-", "Largest |ACF_synthetic - ACF_real| over lags 1..10: is the error correlated alike?"),
    "residual_acf_inliers": (
        "-", "The same autocorrelation of the residuals within 0.5 m of their anchor's median in the trace "
             "(the gross outliers left out, whose held values dominate residual_acf): the time structure "
             "of the ranging error a tracker filters."),
    "residual_acf_inliers_max_abs_diff": (
        "-", "Largest |ACF_synthetic - ACF_real| of residual_acf_inliers over lags 1..10."),
    "residual_burst_deviation_std_m": (
        "m", "Std of the within-burst deviation of the residuals (within 0.5 m of their anchor's median, "
             "that median removed, each minus the mean of its burst of 2+ anchors), real and synthetic: "
             "the error of the range differences, which carry the direction to a far tag."),
    "residual_burst_deviation_ratio": (
        "-", "residual_burst_deviation_std_m synthetic / real; 1 = range differences as clean as the real ones."),
    "residual_still_correlation": (
        "-", "Correlation of one anchor's residuals (within 0.5 m of its median) 1-3 s apart, for pairs "
             "between which the tag travelled under 0.1 m (still) or 1 m or more (moving), real and "
             "synthetic: a slow error tied to the tag's place holds while it stands; one tied to the clock "
             "fades alike in both."),
    "imu_allan_ratio": (
        "-", "Allan deviation of the acceleration, synthetic / real, per axis (E, N, U) at tau = 0.1, "
             "1 and 10 s (overlapping estimator on the 100 Hz grid); 1 = equal."),
    "imu_log_spectral_distance_db": (
        "dB", "Log-spectral distance sqrt(mean_f (10 log10(P_synth / P_real))^2) between the Welch "
              "acceleration PSDs per axis (E, N, U) and their mean; 0 = equal spectra."),
}
"""Name -> (unit, one-line meaning) of every entry of ``report.json["extended"]`` (docs/validation.md)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ValidationReport:
    """Real versus synthetic: the paper's tables plus extended fidelity statistics.

    Every field except ``evidence`` is plain JSON data (NaN written as null); :meth:`to_dict` is
    the content of ``report.json`` and :meth:`from_dict` reads it back (without evidence).

    Attributes
    ----------
    real, synthetic : dict
        ``physynth.evaluate.metrics.Metrics.to_dict()`` of each side (keys
        :data:`~physynth.evaluate.metrics.METRIC_KEYS` plus ``per_anchor``).
    relative_deviation_pct : dict
        |synth - real| / |real| * 100 per metric key; ``imu_std_mps2`` gives one value per axis. For the
        :data:`~physynth.validate.evidence.TYPICAL_METRICS` (the mean AoI), synth is the ensemble's
        typical value (``comparison[key]["typical"]``), not the pooled one.
    ks_statistic : float
        KS statistic of the pooled signed residuals (docs/data-and-metrics.md).
    fidelity_score : float
        S = d_avail + d_med / 10 + d_p95 / 20 (lower is better).
    extended : dict
        The statistics of :data:`EXTENDED_STATISTICS`.
    per_anchor : dict
        Per anchor id: real and synthetic per-anchor metrics, their deviations, residual KS and W1.
    inputs : dict
        Provenance: datasets, scenario, seed, number of traces, grid rate, version, time.
    transfer : dict or None
        With ``--transfer``: which scenario sections came from the real dataset and which from the
        scenario.
    comparison : dict
        Per metric key: real and synthetic values, ``difference`` (synth - real), ``deviation`` and
        ``deviation_kind`` (``relative_pct`` or, for :data:`~physynth.validate.compare.SIGNED_METRICS`,
        ``absolute`` in the metric's unit), the synthetic ensemble's per-trace ``band_5_95`` and ``real_in_band``
        (docs/validation.md). Lists per axis for ``imu_std_mps2``.
    imu_errors : dict or None
        When both sides hold a body-frame IMU (:data:`~physynth.validate.compare.BODY_IMU_ERRORS`: the
        accelerometer's specific force and the gyroscope's rate minus what the truth says they should
        read): ``real`` and ``synthetic`` error std per axis, ``relative_deviation_pct`` and ``extended``
        log-spectral distance and Allan ratio, with the keys of :mod:`physynth.validate.imu_errors`
        (``imu_*`` keys there are None here). None otherwise.
    """

    real: dict[str, Any]
    synthetic: dict[str, Any]
    relative_deviation_pct: dict[str, Any]
    ks_statistic: float | None
    fidelity_score: float | None
    extended: dict[str, Any]
    per_anchor: dict[str, Any]
    inputs: dict[str, Any] = field(default_factory=dict)
    transfer: dict[str, Any] | None = None
    comparison: dict[str, Any] = field(default_factory=dict)
    imu_errors: dict[str, Any] | None = None
    evidence: Evidence | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``report.json``)."""
        from .. import __version__

        return jsonable({
            "generator": {"name": "physynth", "version": __version__},  # marks PhySynth output (io.safety)
            "real": self.real,
            "synthetic": self.synthetic,
            "relative_deviation_pct": self.relative_deviation_pct,
            "ks_statistic": self.ks_statistic,
            "fidelity_score": self.fidelity_score,
            "extended": self.extended,
            "per_anchor": self.per_anchor,
            "inputs": self.inputs,
            "transfer": self.transfer,
            "comparison": self.comparison,
            "imu_errors": self.imu_errors,
        })

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ValidationReport:
        """A report from its JSON form (``evidence`` is None)."""
        try:
            return cls(real=dict(data["real"]), synthetic=dict(data["synthetic"]),
                       relative_deviation_pct=dict(data["relative_deviation_pct"]),
                       ks_statistic=data["ks_statistic"], fidelity_score=data.get("fidelity_score"),
                       extended=dict(data["extended"]), per_anchor=dict(data["per_anchor"]),
                       inputs=dict(data.get("inputs") or {}), transfer=data.get("transfer"),
                       comparison=dict(data.get("comparison") or {}), imu_errors=data.get("imu_errors"))
        except (KeyError, TypeError) as exc:
            raise PhySynthError(f"not a validation report: missing or bad field {exc}") from None


def read_report(path: str | Path) -> ValidationReport:
    """Read ``report.json`` (or a report directory holding it)."""
    p = Path(path)
    if p.is_dir():
        p = p / "report.json"
    try:
        return ValidationReport.from_dict(json.loads(p.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PhySynthError(f"cannot read validation report {p}: {exc}") from None


MIN_BAND_TRACES = 3
"""Fewest synthetic traces (with a finite value of the metric) behind a 5-95 % band: with one the band
is that one value and with two the segment between them, so every real value would read as outside it.
With fewer the band and ``real_in_band`` are null and :func:`band_note` says why."""


def band_note(n_traces: int) -> str:
    """Why a metric's synthetic 5-95 % band is not available (report.md, report.html, the CLI summary)."""
    return (f"Synth 5–95 % band not available: {n_traces} synthetic trace(s) behind it, fewer than the "
            f"{MIN_BAND_TRACES} a band needs (docs/validation.md); generate more traces to compare with a band.")


TRUTH_PAST_UWB_S = 5.0
"""Seconds the real truth may run on past its trace's last UWB row before the report warns: the grid
follows the truth, so every second after the last range counts as a UWB outage (availability, AoI)."""


def truth_past_uwb_line(seconds: float) -> str | None:
    """The one-line warning of the report and the CLI when the real truth runs on more than
    :data:`TRUTH_PAST_UWB_S` past its last UWB row, else None."""
    if not seconds > TRUTH_PAST_UWB_S:
        return None
    return (f"Warning: the real truth runs on {seconds:.1f} s past its last UWB row; that time counts as a UWB "
            "outage (lower availability, larger mean AoI). Import the recording cropped to its UWB span.")
