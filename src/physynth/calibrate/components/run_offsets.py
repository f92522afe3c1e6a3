"""The run-to-run ranging offsets and range-law tilts (random effects over runs and anchors).

Part of the ``ranging`` component, which removes them from the rows before its final mixture fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...models.uwb import range_decades
from ...records import Trace
from ..anchor_channels import Channels, RunOffsets, RunSlopes
from ..report import ReportBuilder
from ..run_spread import batch_mean_var, cell_slope, two_way_spread
from ..uwb_fit import MIN_ANCHOR_ROWS


def _los_cells(trs: Sequence[Trace], labels: Sequence[str], chan: Channels):
    """(run label, anchor id, LOS residuals after the anchor's range law, their true ranges, the anchor's
    LOS std) of every cell with at least :data:`MIN_ANCHOR_ROWS` LOS rows (posterior NLOS probability
    < 0.5), rows in time order."""
    for aid, (ra, ga, _) in chan.per_anchor_rows.items():
        f = chan.mix[aid]
        runs_of = [lab for t, lab in zip(trs, labels, strict=True) if aid in t.anchors.ids]
        start = 0
        for lab, nlos in zip(runs_of, chan.flags[aid], strict=True):  # the anchor's rows, run by run
            sl = slice(start, start + nlos.size)
            start += nlos.size
            x = ra[sl] - f.los_centre(ga[sl])
            if int((~nlos).sum()) >= MIN_ANCHOR_ROWS:
                yield lab, aid, x[~nlos], ga[sl][~nlos], f.los_std_m


def run_offset_table(trs: Sequence[Trace], labels: Sequence[str], chan: Channels) -> tuple[RunOffsets, dict[str, Any]]:
    """Per-run LOS ranging offsets of every anchor and their run-to-run spreads (random effects).

    For run r and anchor a, d_ra is the mean LOS residual of the run (rows the anchor's mixture calls
    LOS, posterior NLOS probability < 0.5, after its range-proportional bias). Model:
    d_ra = mu_a + u_r + e_ra + eps_ra, with an offset u_r common to every anchor of a run
    (``run_offset_std_m``: the truth system or the tag antenna moved), a per-anchor remainder e_ra
    (``run_anchor_offset_std_m``: an anchor re-placed and re-surveyed) and the sampling error eps_ra of
    the run's mean, whose variance is estimated for each cell from its block means in time (at least
    sigma_LOS^2 / n_ra, pooled over the anchor's runs); :func:`~physynth.calibrate.run_spread.two_way_spread`
    (REML; 0 below :data:`RUN_OFFSET_LR_MIN`). The offsets returned for removal from the rows are each
    run's own d_ra minus the anchor's mean over runs, 0 when the spreads are (the best linear unbiased
    predictions, shrunk by the sampling variances, are in the report: removing those instead moved the
    left-out Hanyang medians by up to 1 cm, two of three for the worse).
    """
    raw, n_los = {}, {}
    for lab, aid, xl, _, los_std in _los_cells(trs, labels, chan):
        raw[(lab, aid)] = (float(np.mean(xl)), batch_mean_var(xl, los_std**2 / float(xl.size)))
        n_los[(lab, aid)] = int(xl.size)
    offsets, d = two_way_spread(raw, n_los, labels, unit="m")
    diag: dict[str, Any] = {"per_run": d["per_run"], "identifiable": d["identifiable"]}
    if not d["identifiable"]:
        diag.update(why=d["why"], run_offset_std_m=0.0, run_anchor_offset_std_m=0.0)
        return {}, diag
    diag.update(n_runs=d["n_runs"], n_anchors=d["n_anchors"], run_means_m=d["run_means"],
                run_offset_std_m=d["run_std"], run_anchor_offset_std_m=d["run_anchor_std"],
                sampling_var_m2=d["sampling_var"], sampling_var_per_cell_m2=d["sampling_var_per_cell"],
                removed_offsets_m=d["removed"], blup_offsets_m=d["blup"],
                reml_lr_vs_no_spread=d["reml_lr_vs_no_spread"], significant=d["significant"],
                method=("two-way random effects (run, run x anchor) on the per-run mean LOS residuals, "
                        "REML with each cell's sampling variance (block means in time) known; removed "
                        "offsets = each run's own (anchor mean removed) when the spreads are significant, else 0"))
    return offsets, diag


def run_slope_table(trs: Sequence[Trace], labels: Sequence[str], chan: Channels,
                    law: str) -> tuple[RunSlopes, dict[str, Any]]:
    """Per-run tilts of every anchor's LOS range law and their run-to-run spreads (random effects).

    For run r and anchor a, b_ra is the least-squares slope of the LOS residuals (as in
    :func:`run_offset_table`) on log10 range, its sampling variance by a jackknife over blocks in time
    (:func:`~physynth.calibrate.run_spread.cell_slope`); then the same two-way REML split as the
    offsets. The tilts returned for removal pivot about each cell's own mean log range, so removing
    them leaves the cell's mean (its offset) as it was. The pivot the scenario draws about
    (``uwb.run_slope_ref_range_m``) is the pooled mean log range of the cells. Only for the log law.
    """
    if law != "log":
        return {}, {"identifiable": False, "why": "the run-to-run tilt is fitted for the log range law only",
                    "run_slope_std_m": 0.0, "run_anchor_slope_std_m": 0.0}
    raw, n_los, centres = {}, {}, {}
    for lab, aid, xl, gl, _ in _los_cells(trs, labels, chan):
        got = cell_slope(xl, range_decades(gl))
        if got is not None:
            raw[(lab, aid)], n_los[(lab, aid)], centres[(lab, aid)] = (got[0], got[1]), int(xl.size), got[2]
    tilts, d = two_way_spread(raw, n_los, labels, unit="m per decade")
    diag: dict[str, Any] = {"per_run": d["per_run"], "identifiable": d["identifiable"]}
    if not d["identifiable"]:
        diag.update(why=d["why"], run_slope_std_m=0.0, run_anchor_slope_std_m=0.0)
        return {}, diag
    ref = float(10.0 ** np.average(list(centres.values()), weights=list(n_los.values())))
    diag.update(unit="m per decade of range", n_runs=d["n_runs"], n_anchors=d["n_anchors"],
                run_means=d["run_means"], run_slope_std_m=d["run_std"], run_anchor_slope_std_m=d["run_anchor_std"],
                ref_range_m=ref, sampling_var_per_cell=d["sampling_var_per_cell"], removed_slopes=d["removed"],
                blup_slopes=d["blup"], reml_lr_vs_no_spread=d["reml_lr_vs_no_spread"],
                significant=d["significant"],
                method=("least-squares slope of each (run, anchor) cell's LOS residuals on log10 range, "
                        "jackknife over blocks in time; two-way random effects by REML as the offsets"))
    return {k: (v, centres[k]) for k, v in tilts.items() if v != 0.0}, diag


def report_run_slopes(diag: dict[str, Any], report: ReportBuilder) -> dict[str, float]:
    """Report the run-to-run tilts of the range law as the scenario gets them (0 unless applied; the
    fitted values in the notes); the RangingFit fields (none when not applied)."""
    if not diag["identifiable"]:
        report.not_identifiable.append(f"uwb.run_slope_std_m, uwb.run_anchor_slope_std_m ({diag['why']}; 0 kept)")
        return {}
    applied = diag["applied"]
    status = ("generated" if applied else "not generated unless run_slopes=True" if diag["significant"]
              else "not significant: 0")
    for key, n in (("run_slope_std_m", diag["n_runs"]), ("run_anchor_slope_std_m", diag["n_runs"] * diag["n_anchors"])):
        report.param(f"uwb.{key}", diag[key] if applied else 0.0, n=n, summary=True,
                     note=(f"run-to-run spread of the per-run slope of the LOS residuals on log10 range (two-way "
                           f"random effects, REML likelihood ratio {diag['reml_lr_vs_no_spread']:.1f}); fitted "
                           f"{diag[key]:.4f} m per decade: {status}"))
    if not applied:
        return {}
    report.param("uwb.run_slope_ref_range_m", diag["ref_range_m"], n=diag["n_runs"],
                 note="the pooled mean log range of the LOS rows the tilts pivot about")
    return {"run_slope_std_m": diag["run_slope_std_m"], "run_anchor_slope_std_m": diag["run_anchor_slope_std_m"],
            "run_slope_ref_range_m": diag["ref_range_m"]}
