"""Component ``geometry``: the path, its run-to-run deformation, the motion and its jitter."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...progress import ProgressCallback
from ...scenario import MotionParams, PathParams, Scenario
from ..component import Component
from ..geometry import PathKind, fit_motion, fit_path, path_miss_warnings, path_with_deformation, spread_clip_warnings
from ..inputs import CalibrationInputs
from ..jitter_fit import fit_jitter
from ..report import ReportBuilder


@dataclass(frozen=True, slots=True, kw_only=True)
class GeometryFit:
    path: PathParams
    motion: MotionParams


def fit_geometry(inp: CalibrationInputs, path_kind: PathKind, report: ReportBuilder,
                 progress: ProgressCallback) -> GeometryFit:
    """Path geometry, run-to-run deformation and motion (one track summary per run, shared)."""
    trs, rep = inp.traces, report
    progress("fitting the path geometry")
    pf = fit_path(trs, path_kind, tracks=inp.tracks)
    rep.sections["path"] = pf.diagnostics
    rep.param("path.kind", pf.params.kind, n=pf.n_samples, summary=True)
    rep.param("path.length_m", pf.diagnostics["length_m"], n=pf.n_samples, summary=True)
    rep.param("path.rmse_m", pf.diagnostics["rmse_m"], n=pf.n_samples,
              note="cross-track RMSE of the truth to the fitted path", summary=True)
    rep.warnings.extend(path_miss_warnings(pf.diagnostics))
    deformed = path_with_deformation(trs, pf.params, tracks=inp.tracks)
    path = deformed.path
    rep.sections["path_perturbation"] = deformed.section
    if deformed.not_identifiable:
        rep.not_identifiable.append(deformed.not_identifiable)
    rep.param("path.perturbation.lateral_std_m", path.perturbation.lateral_std_m, n=len(trs), note=deformed.note)
    rep.param("path.perturbation.sag_std_m", path.perturbation.sag_std_m, n=len(trs), note=deformed.note)

    progress("fitting the motion")
    mf = fit_motion(trs, path_length_m=pf.diagnostics["length_m"], defaults=MotionParams(cruise_speed_mps=1.0),
                    tracks=inp.tracks)
    rep.sections["motion"] = mf.diagnostics
    mp = mf.params
    rep.param("motion.cruise_speed_mps", mp.cruise_speed_mps,
              se=mf.diagnostics.get("cruise_speed_mps_std_error"), n=len(trs), summary=True)
    rep.param("motion.profile.kind", mp.profile.kind, n=mf.n_samples,
              note=mf.diagnostics["profile_choice_reason"], summary=True)
    rep.param("motion.speed_poly_r2", mf.diagnostics["speed_poly_r2"], n=mf.n_samples)
    rep.param("motion.max_acc_mps2", mp.max_acc_mps2, n=mf.n_samples, summary=True,
              note=(f"{mf.diagnostics['max_acc']['factor']:g} x the {mf.diagnostics['max_acc']['quantile']:.1%} "
                    "quantile of the trips' acceleration"))
    for key in ("cruise_speed_spread_frac", "length_spread_frac"):
        rep.param(f"motion.{key}", getattr(mp, key), n=len(trs), note=mf.diagnostics["spread_method"])
    jitter, jdiag = fit_jitter(trs, inp.tracks, path, mp, Scenario.model_fields["truth_rate_hz"].default)
    rep.sections["motion_jitter"] = jdiag
    rep.param("motion.jitter.acc_rms_mps2", jitter.acc_rms_mps2, n=mf.n_samples, note=jdiag["method"])
    mp = mp.model_copy(update={"jitter": jitter})
    rep.warnings.extend(spread_clip_warnings(mf.diagnostics))
    for key in ("dwell_start_s", "dwell_end_s"):
        vals = [r[key] for r in mf.diagnostics["per_run"].values()]
        rep.param(f"motion.{key}", getattr(mp, key),
                  se=float(np.std(vals, ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else None, n=len(vals))
    rep.not_identifiable.extend(f"motion.{k} (one run; default kept)"
                                for k in mf.diagnostics.get("not_identifiable", []))
    return GeometryFit(path=path, motion=mp)


COMPONENT = Component(
    name="geometry", data="the ground truth of every UWB recording",
    fits="path, path.perturbation, motion (speed profile, dwells, spreads, jitter)",
    fit=lambda ctx: fit_geometry(ctx.inputs, ctx.options.path_kind, ctx.report, ctx.progress))
