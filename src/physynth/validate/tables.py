"""Validation tables, one model and two renderings (Markdown and HTML): the paper's Table II layout with
the synthetic ensemble's band, the IMU table, the extended statistics and the per-anchor table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .report_model import EXTENDED_STATISTICS, MIN_BAND_TRACES, ValidationReport, band_note, truth_past_uwb_line


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return f"{x:.{digits}f}"



# ---------------------------------------------------------------- tables (one model, two renderings)
@dataclass(frozen=True, slots=True)
class _Table:
    title: str
    headers: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    note: str = ""
    text_columns: tuple[int, ...] = (0,)  # left-aligned; the others are numbers (right-aligned)


def _pct(x: Any) -> str:
    return _fmt(x, 1)


def table_imu(report: ValidationReport) -> _Table | None:
    """The paper's Table I: IMU acceleration std per axis (100 Hz grid), or None without IMU on a side."""
    real, synth = report.real["imu_std_mps2"], report.synthetic["imu_std_mps2"]
    r = np.array([np.nan if v is None else v for v in real], dtype=float)
    s = np.array([np.nan if v is None else v for v in synth], dtype=float)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(s))):
        return None
    d = np.abs(s - r)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero real std has no relative deviation (shown as —)
        rel = d / np.abs(r) * 100.0
    rows = [(axis, _fmt(r[i]), _fmt(s[i]), _fmt(d[i]), _pct(rel[i]))
            for i, axis in enumerate(("East", "North", "Up"))]
    rows.append(("Mean", _fmt(r.mean()), _fmt(s.mean()), _fmt(d.mean()), _pct(rel.mean())))
    return _Table("Table I. IMU acceleration noise: real vs synthetic",
                  ("Axis", "σ_real (m/s²)", "σ_synth (m/s²)", "|Δσ| (m/s²)", "Rel. (%)"), tuple(rows),
                  "Standard deviation per axis of the acceleration on the 100 Hz grid (mean of the samples "
                  "in each 10 ms bin). Rel. = |σ_synth − σ_real| / σ_real × 100; the mean row averages "
                  "each column, as in the paper.")


_TABLE2_ROWS = (
    ("Duration (s)", "duration_s", 1),
    ("UWB ≥ 1 (frac.)", "uwb_ge1_frac", 3),
    ("UWB ≥ 2 (frac.)", "uwb_ge2_frac", 3),
    ("Residual std (m)", "residual_std_m", 3),
    ("Residual med. (m)", "residual_median_m", 3),
    ("|r| P95 (m)", "abs_residual_p95_m", 3),
    ("|r| P99 (m)", "abs_residual_p99_m", 3),
    ("KS statistic", None, 3),
    ("Mean AoI (s)", "mean_aoi_s", 2),
)


def _deviation_cell(c: dict[str, Any] | None, digits: int) -> str:
    if not c:
        return "—"
    if c.get("deviation_kind") == "absolute":
        d = c.get("deviation")
        return "—" if d is None else f"{d:+.{digits}f}"
    return _pct(c.get("deviation"))


def band_cells(c: dict[str, Any] | None, digits: int) -> tuple[str, str]:
    """The two band cells of Table II for one metric's comparison ``c`` (an entry of
    ``report.comparison``): the synthetic 5-95 % band as ``"lo – hi"`` and whether the real value lies
    inside (``yes``, ``NO``, or ``—`` when unknown); ``("—", "—")`` without a band. The ends get
    ``digits`` decimals, up to 3 more while two different ends would read the same (a narrow band)."""
    if not c or c.get("band_5_95") is None:
        return "—", "—"
    lo, hi = c["band_5_95"]
    inside = c.get("real_in_band")
    d = digits
    while d < digits + 3 and lo != hi and _fmt(lo, d) == _fmt(hi, d):  # a narrow band: digits until it shows
        d += 1
    return f"{_fmt(lo, d)} – {_fmt(hi, d)}", ("—" if inside is None else "yes" if inside else "NO")


def table_validation(report: ValidationReport) -> _Table:
    """The paper's Table II layout: real, synthetic, deviation and the synthetic 5-95 % band per metric."""
    rows = []
    comp = report.comparison or {}
    for label, key, digits in _TABLE2_ROWS:
        if key is None:
            rows.append((label, "—", _fmt(report.ks_statistic), "—", "—", "—"))
            continue
        c = comp.get(key)
        if c is None:  # a report written before the comparison existed
            dev = report.relative_deviation_pct.get(key)
            rows.append((label, _fmt(report.real[key], digits), _fmt(report.synthetic[key], digits), _pct(dev),
                         "—", "—"))
            continue
        synth = _fmt(report.synthetic[key], digits)
        if c.get("typical") is not None:  # heavy-tailed: the deviation is against the median synthetic run
            synth += f" (median run {_fmt(c['typical'], digits + 1)})"
        rows.append((label, _fmt(report.real[key], digits), synth, _deviation_cell(c, digits), *band_cells(c, digits)))
    rows.append(("Fidelity score S", "—", _fmt(report.fidelity_score), "—", "—", "—"))
    few = few_band_traces(report)
    return _Table("Table II. Generator validation",
                  ("Metric", "Real", "Synth", "Δ", "Synth 5–95 %", "Real in band"), tuple(rows),
                  ("" if few is None else band_note(few) + " ")
                  + "Δ = |Synth − Real| / |Real| × 100 (%), except for the signed residual median: Synth − Real "
                  "in metres; for the mean AoI, against the median synthetic run (one rare long outage "
                  "multiplies a run's mean AoI by ten, so the pooled value is no typical run). "
                  "Synth 5–95 %: percentiles of the metric over the synthetic traces taken one by one; "
                  "Real in band: whether the real value lies inside. Metrics as defined in docs/data-and-metrics.md "
                  "(100 Hz grid; residuals pooled over anchors and traces; KS of the signed residuals). "
                  "S = d_avail + d_med/10 + d_P95/20 with the absolute differences |Synth − Real| of UWB ≥ 1 "
                  "(fraction) and of the residual median and P95 (m), not the Δ column (lower is better).")


def few_band_traces(report: ValidationReport) -> int | None:
    """The number of synthetic traces behind the bands when too few for one (:data:`MIN_BAND_TRACES`),
    else None."""
    comp = [c for c in (report.comparison or {}).values() if isinstance(c, dict) and "n_traces_in_band" in c]
    few = [c["n_traces_in_band"] for c in comp
           if c.get("band_5_95") is None and c["n_traces_in_band"] < MIN_BAND_TRACES]
    return max(few) if few else None


def _extended_value(name: str, value: Any) -> str:
    if value is None:
        return "—"
    if name == "gap_quantiles_s":
        return ("real " + " / ".join(_fmt(v, 2) for v in value["real"]) + "; synth "
                + " / ".join(_fmt(v, 2) for v in value["synthetic"]) + " (P50/P95/P99/max)")
    if name in ("residual_acf", "residual_acf_inliers"):
        return ("lag 1,2,5,10 real " + ", ".join(_fmt(value["real"][i], 2) for i in (0, 1, 4, 9))
                + "; synth " + ", ".join(_fmt(value["synthetic"][i], 2) for i in (0, 1, 4, 9)))
    if name == "residual_burst_deviation_std_m":
        return f"real {_fmt(value['real'], 4)}; synth {_fmt(value['synthetic'], 4)}"
    if name == "residual_still_correlation":
        return "; ".join(f"{k} real {_fmt(value[k]['real'], 2)}, synth {_fmt(value[k]['synthetic'], 2)}"
                         for k in ("still", "moving"))
    if name == "imu_allan_ratio":
        taus = value["tau_s"]
        return "; ".join(f"{ax.upper()}: " + ", ".join(f"{_fmt(r, 2)}@{t:g}s" for r, t in zip(row, taus, strict=True))
                         for ax, row in zip(value["axes"], value["ratio"], strict=True))
    if name == "imu_log_spectral_distance_db":
        return (" / ".join(_fmt(v, 2) for v in value["per_axis"]) + f" (E/N/U); mean {_fmt(value['mean'], 2)}")
    return _fmt(value, 4)


def table_extended(report: ValidationReport) -> _Table:
    rows = []
    for name, (unit, meaning) in EXTENDED_STATISTICS.items():
        rows.append((name, _extended_value(name, report.extended.get(name)), unit, meaning))
    note = ("IMU statistics left out: " + report.extended["imu_note"] + ".") if report.extended.get("imu_note") else ""
    return _Table("Extended fidelity statistics", ("Statistic", "Value", "Unit", "Meaning"), tuple(rows), note,
                  text_columns=(0, 1, 2, 3))


def table_per_anchor(report: ValidationReport) -> _Table:
    rows = []
    for a, d in report.per_anchor.items():
        r, s = d.get("real") or {}, d.get("synthetic") or {}
        aoi = (d.get("typical") or s).get("mean_aoi_s")  # the median synthetic run's, as in Table II
        rows.append((a, f"{r.get('n_ranges', '—')} / {s.get('n_ranges', '—')}",
                     f"{_fmt(r.get('fresh_frac'))} / {_fmt(s.get('fresh_frac'))}",
                     f"{_fmt(r.get('mean_aoi_s'), 2)} / {_fmt(aoi, 2)}",
                     f"{_fmt(r.get('residual_median_m'))} / {_fmt(s.get('residual_median_m'))}",
                     f"{_fmt(r.get('abs_residual_p95_m'))} / {_fmt(s.get('abs_residual_p95_m'))}",
                     _fmt(d.get("ks_statistic")), _fmt(d.get("residual_wasserstein_m"), 4),
                     _fmt(d.get("gap_ks_statistic"))))
    return _Table("Per anchor (real / synthetic)",
                  ("Anchor", "ranges", "fresh frac.", "mean AoI (s)", "residual med. (m)", "|r| P95 (m)",
                   "KS", "W1 (m)", "gap KS"), tuple(rows),
                  "KS and W1: signed residuals of this anchor; gap KS: gaps between its consecutive valid ranges; "
                  "mean AoI: the median synthetic run's, as in Table II (report.json also keeps the pooled one).")


def _inputs_lines(report: ValidationReport) -> list[str]:
    inp = report.inputs
    real = inp.get("real", {})
    syn = inp.get("synthetic", {})
    n = inp.get("n_traces", {})
    lines = [f"Real: {real.get('path', '?')} ({n.get('real', '?')} trace(s); anchors "
             f"{', '.join(real.get('anchors', []))})"]
    if "scenario" in syn:
        lines.append(f"Synthetic: {n.get('synthetic', '?')} trace(s) generated from scenario "
                     f"'{syn.get('scenario_name')}' ({syn.get('scenario')}), root seed {syn.get('root_seed')}"
                     + (", transferred to the real run's geometry" if syn.get("transfer") else ""))
    else:
        lines.append(f"Synthetic: {syn.get('path', '?')} ({n.get('synthetic', '?')} trace(s); scenario "
                     f"{syn.get('scenario_name')}, root seed {syn.get('root_seed')})")
    nres = inp.get("n_residuals", {})
    lines.append(f"Residuals: {nres.get('real', '?')} real, {nres.get('synthetic', '?')} synthetic; "
                 f"grid {inp.get('grid_rate_hz', '?')} Hz; physynth {inp.get('physynth_version', '?')}; "
                 f"created {inp.get('created_utc', '?')}")
    if inp.get("anchor_subset") is not None:
        lines.append(anchor_subset_line(inp))
    truth = real.get("truth") or {}
    if truth.get("untrusted_truth_ranges"):
        lines.append(truth_line(truth))
    past = truth_past_uwb_line(real.get("truth_past_last_uwb_s") or 0.0)
    if past:
        lines.append(past)
    src = str(real.get("source") or "")
    if "hanyang" in src.lower():
        lines.append("Real data: Hanyang outdoor UWB dataset (ADIP lab, Hanyang University), "
                     "DOI 10.5281/zenodo.15226105, Apache-2.0.")
    return lines


def anchor_subset_line(inputs: dict) -> str:
    """The relaxed anchor-subset comparison, said where the tables are read (report.md, report.html, the
    CLI summary): the synthetic side has fewer anchors, so its availability is lower by design."""
    subset = inputs.get("anchor_subset") or []
    real = inputs.get("real", {}).get("anchors", [])
    return (f"Anchor subset: the synthetic traces use only {', '.join(subset)} ({len(subset)} of the "
            f"{len(real)} anchors); the real dataset is compared on all {len(real)} (the anchor study's "
            "relaxed comparison), so the availability (UWB >= k) and AoI rows compare fewer anchors with "
            "more by design, not a model failure.")


def truth_line(truth: dict) -> str:
    """What was done with the real ranges at an untrusted truth (report.md, report.html, the CLI summary)."""
    n, total = truth.get("untrusted_truth_ranges", 0), truth.get("valid_ranges", 0)
    how = "left out of the residual metrics" if truth.get("untrusted_left_out_of_residuals") else "compared too"
    return f"Real truth: {n} of {total} valid ranges lie where the recording says its truth errs; {how}."


def _transfer_lines(report: ValidationReport) -> list[str]:
    t = report.transfer
    if not t:
        return []
    lines = [f"Policy: {t.get('policy')}.",
             f"Taken from the real dataset ({t.get('real_dataset')}): {', '.join(t.get('from_real', []))}.",
             f"Kept from scenario '{t.get('scenario')}': {', '.join(t.get('from_scenario', []))}.",
             f"Sections that actually changed: {', '.join(t.get('changed_sections', [])) or 'none'}."]
    if t.get("unexpected_changes"):
        lines.append(f"WARNING: sections outside the policy changed: {', '.join(t['unexpected_changes'])}.")
    an = t.get("anchors", {})
    lines.append(f"Anchors: scenario {', '.join(an.get('scenario', []))} -> transferred "
                 f"{', '.join(an.get('transferred', []))} (real {', '.join(an.get('real', []))}).")
    if an.get("pooled_channel"):
        lines.append(f"No channel of their own in the scenario (calibrated on other anchors): "
                     f"{', '.join(an['pooled_channel'])}; they range with the scenario's pooled channel.")
    return lines


_IMU_ERROR_ROWS = (("imu", "mps2", "ENU acceleration (m/s²)", "ENU"),
                   ("acc_body", "mps2", "Accelerometer (m/s²)", "xyz"),
                   ("gyro", "radps", "Gyroscope (rad/s)", "xyz"))


def table_imu_errors(report: ValidationReport) -> _Table | None:
    """IMU error (IMU minus truth) std per axis, deviation, log-spectral distance and Allan ratio at
    1 s, for the kinds both sides have; None when there are none."""
    ie = report.imu_errors
    if not ie:
        return None
    rows = []
    for kind, unit, label, axes in _IMU_ERROR_ROWS:
        key = f"{kind}_error_std_{unit}"
        r, s, dev = ie["real"].get(key), ie["synthetic"].get(key), ie["relative_deviation_pct"].get(key)
        if r is None or s is None:
            continue
        lsd = (ie["extended"].get(f"{kind}_log_spectral_distance_db") or {}).get("per_axis") or [None] * 3
        allan = ie["extended"].get(f"{kind}_allan_ratio")
        at1 = [None] * 3
        if allan and 1.0 in allan["tau_s"]:
            at1 = allan["ratio"][allan["tau_s"].index(1.0)]
        for k, axis in enumerate(axes if axes != "ENU" else ("E", "N", "U")):
            rows.append((f"{label} {axis}", f"{r[k]:.4g}", f"{s[k]:.4g}", _pct(dev[k]), _fmt(lsd[k], 2),
                         _fmt(at1[k], 2)))
    if not rows:
        return None
    return _Table("IMU errors: real vs synthetic",
                  ("Error", "σ_real", "σ_synth", "Dev. (%)", "Log-spectral dist. (dB)", "Allan ratio at 1 s"),
                  tuple(rows),
                  "IMU minus what the truth says it should read (the truth low-passed at 10 Hz), pooled over "
                  "traces; Dev. = (σ_synth / σ_real − 1) × 100. Log-spectral distance: RMS of 10 log10 of the "
                  "Welch spectra's ratio over 0.2 Hz to 0.95 × Nyquist. Allan ratio: synthetic / real "
                  "overlapping Allan deviation.")


def _tables(report: ValidationReport) -> list[_Table]:
    t1 = table_imu(report)
    return [t for t in (t1, table_imu_errors(report), table_validation(report), table_extended(report),
                        table_per_anchor(report)) if t is not None]


