"""The whole calibration: traces (or dataset directories) -> a Scenario and a JSON fit report.

Steps (each a separate fit, see the sibling modules): input checks and anchor layout, path geometry,
motion, UWB time offset, burst schedule, per-anchor LOS/NLOS errors, availability (link range,
dropout, outages, tag outages), IMU noise when IMU data is present. The scenario is written in the
generator's own format, so it feeds ``physynth generate`` directly; the report gives every parameter
with its standard error or the number of samples behind it, the diagnostics that support it and the
list of what could not be identified.
"""

from __future__ import annotations

import datetime as _dt
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .. import __version__
from ..records import Trace
from ..scenario import (
    AvailabilityParams,
    ChannelParams,
    ImuParams,
    MotionParams,
    NlosMode,
    PerturbationParams,
    Scenario,
    UwbParams,
    scenario_from_dict,
)
from ._base import CalibrationError, as_trace_list, jsonable, require_truth, rounded, trace_label
from .availability_fit import fit_availability
from .geometry import PathKind, anchor_layout, fit_motion, fit_path, fit_path_perturbation
from .uwb_fit import (
    MIN_ANCHOR_ROWS,
    MixtureFit,
    corrected_residuals,
    fit_burst_schedule,
    fit_time_offset,
    select_mixture,
)

ProgressFn = Callable[[str], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class CalibrationResult:
    """A calibrated scenario and its fit report (JSON-able dict)."""

    scenario: Scenario
    report: dict[str, Any]

    def summary_rows(self) -> list[tuple[str, str, str]]:
        """(parameter, value, uncertainty or samples) rows for a short terminal table."""
        rows = []
        for key, item in self.report["parameters"].items():
            if not item.get("summary"):
                continue
            v = item["value"]
            value = (" / ".join(_fmt(x) for x in v) if isinstance(v, list) else _fmt(v))
            if item.get("std_error") is not None:
                se = item["std_error"]
                unc = "+- " + (" / ".join(_fmt(x) for x in se) if isinstance(se, list) else _fmt(se))
            elif item.get("n_samples") is not None:
                unc = f"n = {item['n_samples']}"
            else:
                unc = item.get("note", "")
            rows.append((key, value, unc))
        return rows


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def _param(report: dict[str, Any], key: str, value: Any, *, se: Any = None, n: int | None = None,
           note: str | None = None, summary: bool = False) -> None:
    item: dict[str, Any] = {"value": value}
    if se is not None:
        item["std_error"] = se
    if n is not None:
        item["n_samples"] = int(n)
    if note:
        item["note"] = note
    if summary:
        item["summary"] = True
    report["parameters"][key] = item


def _nlos_runs(flags: list[np.ndarray]) -> np.ndarray:
    lengths = []
    for f in flags:
        x = np.concatenate([[0], f.astype(np.int8), [0]])
        d = np.diff(x)
        lengths.append(np.flatnonzero(d == -1) - np.flatnonzero(d == 1))
    return np.concatenate(lengths) if lengths else np.zeros(0, np.int64)


MIN_MODE_EPISODES = 2
"""A mixture mode gets its own NLOS episode length from at least this many episodes (else uwb.nlos_dwell_s)."""


def _mode_runs(residual_m: np.ndarray, flags: list[np.ndarray], modes: Sequence[tuple[float, float, float]]
               ) -> list[np.ndarray]:
    """Run lengths of consecutive NLOS rows in the same mixture mode (most likely mode per row), per mode."""
    if not modes or not flags:
        return [np.zeros(0, np.int64) for _ in modes]
    w, m, sd = (np.array(x) for x in zip(*modes, strict=True))
    r = np.asarray(residual_m)
    best = np.argmax(np.log(w)[None, :] - np.log(sd)[None, :] - 0.5 * ((r[:, None] - m) / sd) ** 2, axis=1)
    out: list[list[np.ndarray]] = [[] for _ in modes]
    start = 0
    for f in flags:  # one pass per trace, vectorised over its rows
        lab = np.where(f, best[start:start + f.size], -1)
        start += f.size
        edges = np.flatnonzero(np.diff(lab)) + 1
        seg_start = np.concatenate([[0], edges])
        seg_len = np.diff(np.concatenate([seg_start, [lab.size]]))
        seg_lab = lab[seg_start] if lab.size else lab
        for j in range(len(modes)):
            out[j].append(seg_len[seg_lab == j])
    return [np.concatenate(x) if x else np.zeros(0, np.int64) for x in out]


def _dwell_from_runs(lengths: np.ndarray, period_s: float) -> float | None:
    """Mean NLOS episode [s] from run lengths n >= 1 of samples every ``period_s`` (geometric MLE)."""
    if lengths.size == 0:
        return None
    mean_n = float(lengths.mean())
    if mean_n <= 1.0 + 1e-9:
        return period_s / 10.0
    return float(-period_s / np.log(1.0 - 1.0 / mean_n))


@dataclass(slots=True)
class _Channels:
    pooled_r: np.ndarray
    pooled_fit: MixtureFit
    pooled_sel: dict[str, Any]
    mix: dict[str, MixtureFit]
    mix_diag: dict[str, Any]
    flags: dict[str, list[np.ndarray]]
    per_anchor_rows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]  # residual, range, range rate
    notes: list[str]

    def los_masks(self) -> dict[str, np.ndarray]:
        return {a: self.mix[a].nlos_resp < 0.5 for a in self.per_anchor_rows}


def _fit_channels(trs: Sequence[Trace], offset: float, ids: Sequence[str], fixed_slope: float | None,
                  labels: Sequence[str]) -> _Channels:
    """Per-anchor LOS/NLOS mixtures (and the pooled one) at a given time offset."""
    res = [corrected_residuals(t, offset) for t in trs]
    pooled_r = np.concatenate([r.residual_m for r in res])
    pooled_g = np.concatenate([r.range_m for r in res])
    if pooled_r.size < MIN_ANCHOR_ROWS:
        raise CalibrationError(f"only {pooled_r.size} UWB ranges fall inside the ground-truth time span; "
                               f"at least {MIN_ANCHOR_ROWS} are needed")
    pooled_fit, pooled_sel = select_mixture(pooled_r, pooled_g, fixed_slope=fixed_slope)
    mix: dict[str, MixtureFit] = {}
    mix_diag: dict[str, Any] = {}
    flags: dict[str, list[np.ndarray]] = {}
    rows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    notes: list[str] = []
    for aid in ids:  # one mixture per anchor, pooled over the traces
        parts = [(r.residual_m[m], r.range_m[m], r.range_rate_mps[m])
                 for t, r in zip(trs, res, strict=True) if aid in t.anchors.ids
                 for m in [r.anchor == t.anchors.index(aid)]]
        sizes = [p[0].size for p in parts]
        ra = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        ga = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
        if ra.size < MIN_ANCHOR_ROWS:
            mix[aid] = pooled_fit
            mix_diag[aid] = {"n": int(ra.size), "note": f"fewer than {MIN_ANCHOR_ROWS} ranges: pooled channel used"}
            notes.append(f"channel of {aid} (too few ranges; pooled values used)")
            flags[aid] = []
            continue
        f, sel = select_mixture(ra, ga, fixed_slope=fixed_slope)
        mix[aid] = f
        per_run = {}
        for t, r, lab in zip(trs, res, labels, strict=True):  # per-run robust summary (spread over runs)
            if aid in t.anchors.ids:
                x = r.residual_m[r.anchor == t.anchors.index(aid)]
                if x.size:
                    med = float(np.median(x))
                    per_run[lab] = {"n": int(x.size), "median_m": med,
                                    "robust_std_m": float(1.4826 * np.median(np.abs(x - med)))}
        mix_diag[aid] = {"n": int(ra.size), **sel, "converged": f.converged,
                         "range_span_m": [float(ga.min()), float(ga.max())], "per_run": per_run}
        bounds = np.cumsum([0] + sizes)
        flags[aid] = [f.nlos_resp[a:b] > 0.5 for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        rows[aid] = (ra, ga, np.concatenate([p[2] for p in parts]))
    return _Channels(pooled_r=pooled_r, pooled_fit=pooled_fit, pooled_sel=pooled_sel, mix=mix, mix_diag=mix_diag,
                     flags=flags, per_anchor_rows=rows, notes=notes)


def refine_time_offset(rows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                       los: dict[str, np.ndarray]) -> dict[str, Any] | None:
    """Least-squares correction of the time offset from the LOS rows.

    With r(offset) = range - g(t - offset), r(offset0 + d) ~ r(offset0) + g'(t) d; regressing r(offset0)
    on per-anchor intercepts and range slopes and on -g' gives d with its standard error (LOS errors
    independent and Gaussian), a far more efficient estimate than the robust grid search.
    Also returns, per anchor, the sensitivity of the LOS mean and slope to the offset.
    """
    keys = [a for a in rows if los[a].sum() > 10]
    if not keys:
        return None
    blocks_r, blocks_x, rates = [], [], []
    n_a = len(keys)
    for j, a in enumerate(keys):
        r, g, gd = (x[los[a]] for x in rows[a])
        x = np.zeros((r.size, 2 * n_a + 1))
        x[:, 2 * j] = 1.0
        x[:, 2 * j + 1] = g
        x[:, -1] = -gd
        blocks_r.append(r)
        blocks_x.append(x)
        rates.append(gd)
    y = np.concatenate(blocks_r)
    x = np.concatenate(blocks_x)
    if np.ptp(x[:, -1]) == 0:
        return None
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    s2 = float(resid @ resid / max(y.size - x.shape[1], 1))
    cov = np.linalg.pinv(x.T @ x) * s2
    sens = {}
    for a in keys:
        r, g, gd = (v[los[a]] for v in rows[a])
        b, m = np.polyfit(g, gd, 1) if np.ptp(g) > 0 else (0.0, float(np.mean(gd)))
        sens[a] = {"d_los_mean_per_s": float(m), "d_range_bias_per_s": float(b)}
    return {"correction_s": float(coef[-1]), "std_error_s": float(np.sqrt(cov[-1, -1])), "n_los_rows": int(y.size),
            "sensitivity": sens}


def calibrate(traces: Trace | Sequence[Trace], *, name: str = "calibrated", path_kind: PathKind = "auto",
              anchor_policy: Literal["strict", "first"] = "strict",
              static_sweeps: str | os.PathLike | None = None, range_bias: Literal["dynamic", "static"] = "dynamic",
              sources: Sequence[str] | None = None, progress: ProgressFn | None = None) -> CalibrationResult:
    """Calibrate a scenario on one or several recordings (real or synthetic Traces).

    Parameters
    ----------
    traces
        Recordings with ground truth and UWB rows (and optionally IMU samples), pooled.
    path_kind
        ``auto`` (polynomial for a cable-like path, else waypoints), ``polynomial`` or ``waypoints``.
    anchor_policy
        ``strict``: an anchor id placed differently by two recordings is an error; ``first``: the
        first recording's layout is written (channel statistics still use each run's own positions).
    static_sweeps
        Optional Hanyang ``Static_measurements`` folder: the range-proportional bias is also fitted on
        the static sweeps (reported), and used for every anchor when ``range_bias="static"``.
    sources
        Names of the datasets the traces came from (provenance).
    progress
        Called with a short description before each step (the CLI shows it).
    """
    say = progress or (lambda _msg: None)
    trs = as_trace_list(traces)
    labels = [trace_label(t, i) for i, t in enumerate(trs)]
    if len(set(labels)) != len(labels):
        labels = [f"{lab} [{i}]" for i, lab in enumerate(labels)]
        trs = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, imu=t.imu, meta={**t.meta, "label": lab})
               for t, lab in zip(trs, labels, strict=True)]
    say("checking the recordings")
    imu_only: list[Trace] = []  # IMU recordings without UWB (e.g. a lab trial): they inform the IMU fit only
    imu_only_labels: list[str] = []
    for t, lab in zip(trs, labels, strict=True):
        require_truth(t, lab)
        has_uwb = len(t.uwb) > 0 and bool(t.uwb.valid.any())
        has_imu = t.imu is not None and t.imu.t_s.size > 100
        if not has_uwb and has_imu:
            imu_only.append(t)
            imu_only_labels.append(lab)
            continue
        if not has_uwb:
            raise CalibrationError(f"{lab}: no UWB rows with a range and no IMU samples: nothing to calibrate on")
        if len(t.anchors) == 0:
            raise CalibrationError(f"{lab}: no anchors")
    if imu_only:
        keep = [i for i, lab in enumerate(labels) if lab not in imu_only_labels]
        trs, labels = [trs[i] for i in keep], [labels[i] for i in keep]
        if not trs:  # IMU recordings only: IMU models, path and motion from the truth, no anchors
            from .imu_only import calibrate_imu_only

            return calibrate_imu_only(imu_only, name=name, path_kind=path_kind, sources=sources, progress=progress)
    anchors, layout = anchor_layout(trs, policy=anchor_policy, labels=labels)
    windows = {}
    for t, lab in zip(trs, labels, strict=True):
        u_t = t.uwb.t_s[t.uwb.valid]
        lead, tail = float(u_t[0] - t.truth.t_s[0]), float(t.truth.t_s[-1] - u_t[-1])
        windows[lab] = {"uwb_starts_after_truth_s": lead, "truth_continues_after_uwb_s": tail}
    ids = [a.id for a in anchors]
    report: dict[str, Any] = {
        "physynth_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "recordings": labels,
        "imu_only_recordings": imu_only_labels,
        "sources": list(sources or []),
        "anchor_layout": layout,
        "recording_windows": windows,
        "parameters": {},
        "not_identifiable": [],
    }
    notes: list[str] = report["not_identifiable"]
    for lab, w in windows.items():
        if max(w["uwb_starts_after_truth_s"], w["truth_continues_after_uwb_s"]) > 2.0:
            report.setdefault("warnings", []).append(
                f"{lab}: UWB covers only part of the truth span (first range {w['uwb_starts_after_truth_s']:+.1f} s "
                f"from the truth start, last range {w['truth_continues_after_uwb_s']:.1f} s before its end); "
                "availability is fitted on the "
                "UWB span only, so metrics of the uncropped recording count the uncovered part as missing UWB "
                "(import with crop_to_uwb to drop it)")

    # ---------------------------------------------------------------- path and motion
    say("fitting the path geometry")
    pf = fit_path(trs, path_kind)
    report["path"] = pf.diagnostics
    _param(report, "path.kind", pf.params.kind, n=pf.n_samples, summary=True)
    _param(report, "path.length_m", pf.diagnostics["length_m"], n=pf.n_samples, summary=True)
    _param(report, "path.rmse_m", pf.diagnostics["rmse_m"], n=pf.n_samples,
           note="cross-track RMSE of the truth to the fitted path", summary=True)
    if len(trs) >= 2:
        pert = fit_path_perturbation(trs, pf.params)
        perturbation = PerturbationParams(lateral_std_m=rounded(pert["lateral_std_m"], 4),
                                          sag_std_m=rounded(pert["sag_std_m"], 4))
        report["path_perturbation"] = pert
        note = "std over runs of the half-sine amplitudes"
    elif pf.params.kind == "polynomial":  # a cable: the paper's deformation is the prior
        perturbation = PerturbationParams()
        report["path_perturbation"] = {"note": "one run: run-to-run deformation not identifiable, cable "
                                               "defaults kept (2 m lateral, 1 m sag; paper III.C)"}
        notes.append("path.perturbation (one run; cable defaults kept)")
        note = "default (one run)"
    else:  # a general path (a walk, a vehicle): a cable's sag has no meaning and nothing else is known
        perturbation = PerturbationParams(lateral_std_m=0.0, sag_std_m=0.0)
        report["path_perturbation"] = {"note": "one run of a general path: run-to-run deformation not "
                                               "identifiable; none claimed (set path.perturbation to add some)"}
        notes.append("path.perturbation (one run of a general path; set to 0)")
        note = "0 (one run, general path)"
    _param(report, "path.perturbation.lateral_std_m", perturbation.lateral_std_m, n=len(trs), note=note)
    _param(report, "path.perturbation.sag_std_m", perturbation.sag_std_m, n=len(trs), note=note)
    path = pf.params.model_copy(update={"perturbation": perturbation})

    say("fitting the motion")
    mf = fit_motion(trs, path_length_m=pf.diagnostics["length_m"], defaults=MotionParams(cruise_speed_mps=1.0))
    report["motion"] = mf.diagnostics
    mp = mf.params
    _param(report, "motion.cruise_speed_mps", mp.cruise_speed_mps,
           se=mf.diagnostics.get("cruise_speed_mps_std_error"), n=len(trs), summary=True)
    _param(report, "motion.profile.kind", mp.profile.kind, n=mf.n_samples,
           note=mf.diagnostics["profile_choice_reason"], summary=True)
    _param(report, "motion.speed_poly_r2", mf.diagnostics["speed_poly_r2"], n=mf.n_samples)
    for key in ("cruise_speed_spread_frac", "length_spread_frac"):
        _param(report, f"motion.{key}", getattr(mp, key), n=len(trs), note=mf.diagnostics["spread_method"])
    for key in ("dwell_start_s", "dwell_end_s"):
        vals = [r[key] for r in mf.diagnostics["per_run"].values()]
        _param(report, f"motion.{key}", getattr(mp, key),
               se=float(np.std(vals, ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else None, n=len(vals))
    notes += [f"motion.{k} (one run; default kept)" for k in mf.diagnostics.get("not_identifiable", [])]

    # ---------------------------------------------------------------- UWB timing
    say("searching the UWB time offset")
    of = fit_time_offset(trs)
    report["time_offset"] = of.diagnostics
    offset = float(of.params)
    _param(report, "uwb.time_offset_s", offset, se=of.diagnostics["std_error_s"], n=of.n_samples, summary=True)
    if not of.diagnostics["identifiable"]:
        notes.append("uwb.time_offset_s (residual spread independent of the offset)")

    say("fitting the burst schedule")
    bf = fit_burst_schedule(trs)
    report["burst_schedule"] = bf.diagnostics
    burst_rate = rounded(float(bf.params["burst_rate_hz"]), 7)
    _param(report, "uwb.burst_rate_hz", burst_rate, n=bf.n_samples, summary=True)
    _param(report, "uwb.burst_jitter_s", bf.params["burst_jitter_s"], n=bf.n_samples)
    _param(report, "uwb.slot_s", bf.params["slot_s"], n=bf.n_samples, note=bf.diagnostics["slot_method"])
    _param(report, "uwb.burst_phase_s", bf.params["burst_phase_s"], n=bf.n_samples,
           note="clock alignment of the single run" if bf.params["burst_phase_s"] is not None
           else "several runs: drawn per trace")

    # ---------------------------------------------------------------- ranging errors
    say("fitting LOS/NLOS ranging errors per anchor")
    static = None
    if static_sweeps is not None:
        from .static_bias import fit_static_range_bias

        static = fit_static_range_bias(static_sweeps)
        report["static_range_bias"] = static
    fixed_slope = static["range_bias_per_m"] if (static is not None and range_bias == "static") else None
    if range_bias == "static" and static is None:
        raise CalibrationError("range_bias='static' needs static_sweeps (the Static_measurements folder)")
    chan = _fit_channels(trs, offset, ids, fixed_slope, labels)
    ref = refine_time_offset(chan.per_anchor_rows, chan.los_masks())
    report["time_offset"]["grid_offset_s"] = offset
    report["time_offset"]["refinement"] = ref
    if of.diagnostics["identifiable"] and ref is not None:
        offset = offset + ref["correction_s"]
        chan = _fit_channels(trs, offset, ids, fixed_slope, labels)
        se_off = float(np.hypot(ref["std_error_s"], of.diagnostics["std_error_s"]
                                if len(trs) >= 2 else 0.0))
        report["time_offset"]["offset_s"] = offset
        report["time_offset"]["std_error_s"] = se_off
        _param(report, "uwb.time_offset_s", offset, se=se_off, n=of.n_samples, summary=True,
               note="grid search on the robust spread, refined by least squares on the LOS rows")
    else:
        se_off = float(of.diagnostics["std_error_s"])
    pooled_r, pooled_fit, pooled_sel = chan.pooled_r, chan.pooled_fit, chan.pooled_sel
    mix, mix_diag, flags = chan.mix, chan.mix_diag, chan.flags
    notes += chan.notes

    # ---------------------------------------------------------------- availability
    say("fitting availability (link range, dropouts, outages)")
    af = fit_availability(trs, offset, burst_rate, ids)
    av = af.params["per_anchor"]
    tag = af.params["tag"]
    report["availability"] = {"per_anchor": av, "tag_outages": tag, **af.diagnostics}

    # NLOS dwell: one value for the generator, pooled over anchors
    periods = {a: av[a]["dropout_outage"]["attempt_period_s"] for a in ids}
    runs_all, per_anchor_dwell = [], {}
    for aid in ids:
        lengths = _nlos_runs(flags[aid])
        per_anchor_dwell[aid] = _dwell_from_runs(lengths, periods[aid])
        runs_all.append(lengths)
    all_runs = np.concatenate(runs_all) if runs_all else np.zeros(0)
    dwell = _dwell_from_runs(all_runs, float(np.mean(list(periods.values()))))
    nlos_dwell_guess = dwell if dwell is not None else UwbParams().nlos_dwell_s

    # ---------------------------------------------------------------- assemble channels
    channel_diag: dict[str, Any] = {}
    per_channel: dict[str, ChannelParams] = {}
    largest_range = 0.0
    for aid in ids:
        f = mix[aid]
        a_av = av[aid]
        link = a_av["link"]
        rate = min(a_av["attempt_prob"] * burst_rate, burst_rate)
        seen = link.get("max_range_seen_m") or 0.0
        largest_range = max(largest_range, seen)
        if link.get("identifiable"):
            max_range, edge = link["max_range_m"], link["edge_width_m"]
        else:
            max_range, edge = 2.0 * seen + 10.0, 5.0
            notes.append(f"channel_per_anchor.{aid}.max_range_m ({link.get('why', 'not identifiable')}; "
                         f"set to {max_range:.0f} m, above the largest range {seen:.1f} m)")
        # each mode keeps its own episode length (an episode keeps one reflector): a long, small offset at
        # rest and short gross outliers are different processes
        mode_runs = _mode_runs(chan.per_anchor_rows[aid][0], flags[aid], f.modes) if aid in chan.per_anchor_rows \
            else [np.zeros(0)] * len(f.modes)
        mode_dwell = [_dwell_from_runs(x, periods[aid]) if x.size >= MIN_MODE_EPISODES else None for x in mode_runs]
        modes = [NlosMode(weight=rounded(w, 4), mean_m=rounded(m, 5), std_m=rounded(s, 4),
                          dwell_s=None if d is None else rounded(d, 4))
                 for (w, m, s), d in zip(f.modes, mode_dwell, strict=True)]
        mode_episodes = [int(x.size) for x in mode_runs]
        if not modes:
            modes = ChannelParams().nlos_modes
        per_channel[aid] = ChannelParams(
            rate_hz=min(rounded(rate, 6), burst_rate), los_mean_m=rounded(f.los_mean_m, 5),
            los_std_m=rounded(f.los_std_m, 5),
            range_bias_per_m=rounded(f.range_bias_per_m, 5), nlos_prob=rounded(f.nlos_prob, 5), nlos_modes=modes,
            max_range_m=rounded(max_range, 5), edge_width_m=rounded(edge, 4))
        se = dict(f.se)
        sens = ((ref or {}).get("sensitivity") or {}).get(aid)
        if sens:  # the LOS mean and slope move with the time offset: add its uncertainty
            se["los_mean_m"] = float(np.hypot(se["los_mean_m"], sens["d_los_mean_per_s"] * se_off))
            se["range_bias_per_m"] = float(np.hypot(se["range_bias_per_m"], sens["d_range_bias_per_s"] * se_off))
            se["includes_time_offset_uncertainty"] = True
        if f.nlos_prob > 0:
            # NLOS comes in episodes: Var(p) ~ 2 p (1 - p) tau_c / T_obs with tau_c = dwell (1 - p)
            t_obs = mix_diag[aid]["n"] * periods[aid]
            tau = (per_anchor_dwell[aid] or nlos_dwell_guess) * (1.0 - f.nlos_prob)
            se["nlos_prob"] = float(max(se["nlos_prob"],
                                        np.sqrt(2.0 * f.nlos_prob * (1.0 - f.nlos_prob) * tau / max(t_obs, 1e-9))))
            se["nlos_prob_method"] = "episodes: sqrt(2 p (1-p) dwell (1-p) / T_obs), at least the binomial SE"
        channel_diag[aid] = {**mix_diag[aid], "std_errors": se, "nlos_dwell_s": per_anchor_dwell[aid],
                             "nlos_mode_episodes": mode_episodes, "nlos_mode_dwell_s": mode_dwell,
                             "n_nlos_episodes": int(_nlos_runs(flags[aid]).size)}
        if not f.modes:
            notes.append(f"channel_per_anchor.{aid}.nlos_modes (no NLOS rows; nlos_prob = 0, default mode kept)")
        centre = f.los_mean_m + f.range_bias_per_m * float(np.median(chan.per_anchor_rows.get(aid, ([0.0],) * 3)[1]))
        negative = [m for _, m, _ in f.modes if m < centre]
        if negative:
            report.setdefault("warnings", []).append(
                f"{aid}: {len(negative)} NLOS mode(s) below the LOS mean (means "
                f"{', '.join(f'{m:.2f}' for m in negative)} m): ranges shorter than the truth are not radio NLOS "
                "(that lengthens ranges) but truth errors or ranging outliers; the mixture reproduces them")
        pre = f"channel_per_anchor.{aid}"
        n_a = mix_diag[aid]["n"]
        _param(report, f"{pre}.los_mean_m", f.los_mean_m, se=se["los_mean_m"], n=n_a, summary=True)
        _param(report, f"{pre}.los_std_m", f.los_std_m, se=se["los_std_m"], n=n_a, summary=True)
        _param(report, f"{pre}.range_bias_per_m", f.range_bias_per_m, se=se["range_bias_per_m"], n=n_a,
               note="fixed to the static-sweep slope" if fixed_slope is not None else None)
        _param(report, f"{pre}.nlos_prob", f.nlos_prob, se=se["nlos_prob"], n=n_a, summary=True)
        _param(report, f"{pre}.nlos_modes", [list(m) for m in f.modes], se=f.se.get("mode_mean_m"), n=n_a,
               note="(weight, mean_m, std_m); std error of the means")
        _param(report, f"{pre}.rate_hz", rate, n=a_av["attempts"],
               note="recorded attempts" if a_av["attempts_recorded"] else "one attempt per burst (inferred)")
        _param(report, f"{pre}.max_range_m", max_range, n=link.get("n_attempts"),
               note=None if link.get("identifiable") else "not identifiable")
    pooled_rate = float(np.mean([per_channel[a].rate_hz for a in ids]))
    pooled_modes = ([NlosMode(weight=rounded(w, 4), mean_m=rounded(m, 5), std_m=rounded(s, 4))
                     for w, m, s in pooled_fit.modes] or ChannelParams().nlos_modes)
    channel = ChannelParams(rate_hz=min(rounded(pooled_rate, 6), burst_rate),
                            los_mean_m=rounded(pooled_fit.los_mean_m, 5),
                            los_std_m=rounded(pooled_fit.los_std_m, 5),
                            range_bias_per_m=rounded(pooled_fit.range_bias_per_m, 5),
                            nlos_prob=rounded(pooled_fit.nlos_prob, 5), nlos_modes=pooled_modes,
                            max_range_m=rounded(max(c.max_range_m for c in per_channel.values()), 5),
                            edge_width_m=rounded(float(np.median([c.edge_width_m for c in per_channel.values()])), 4))
    report["channel"] = {"pooled": {"n": int(pooled_r.size), **pooled_sel, "std_errors": pooled_fit.se},
                         "per_anchor": channel_diag}
    if static is not None:
        _param(report, "static.range_bias_per_m", static["range_bias_per_m"], se=static["std_error"],
               n=static["n_rows"], note=f"static sweeps ({static['environment']}), {static['n_files']} files",
               summary=True)
    if dwell is None:
        nlos_dwell = UwbParams().nlos_dwell_s
        notes.append("uwb.nlos_dwell_s (no NLOS episodes; default kept)")
    else:
        nlos_dwell = dwell
    _param(report, "uwb.nlos_dwell_s", nlos_dwell, n=int(all_runs.size), note="number of NLOS episodes")

    # ---------------------------------------------------------------- availability params
    av_params: dict[str, AvailabilityParams] = {}
    for aid in ids:
        do = av[aid]["dropout_outage"]
        pre = f"availability_per_anchor.{aid}"
        if do.get("identifiable"):
            p = AvailabilityParams(dropout_prob=rounded(do["dropout_prob"], 5),
                                   outage_onset_prob=rounded(do["outage_onset_prob"], 5),
                                   outage_mean_s=rounded(do["outage_mean_s"], 5))
            _param(report, f"{pre}.outage_onset_prob", p.outage_onset_prob, se=do.get("outage_onset_prob_se"),
                   n=do["n_attempts"], summary=True)
            _param(report, f"{pre}.outage_mean_s", p.outage_mean_s, se=do.get("outage_mean_s_se"),
                   n=do["n_attempts"], summary=True)
        else:
            p = AvailabilityParams(dropout_prob=rounded(min(do.get("dropout_prob", 0.0), 1.0), 5),
                                   outage_onset_prob=0.0, outage_mean_s=AvailabilityParams().outage_mean_s)
            notes.append(f"{pre}.outage_* ({do.get('why', 'not identifiable')}; no outages)")
            _param(report, f"{pre}.outage_onset_prob", 0.0, n=do["n_attempts"], note=do.get("why"))
        _param(report, f"{pre}.dropout_prob", p.dropout_prob, se=do.get("dropout_prob_se"), n=do["n_attempts"],
               summary=True)
        av_params[aid] = p
    weights = np.array([av[a]["dropout_outage"]["n_attempts"] for a in ids], dtype=float)
    weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(ids), 1.0 / len(ids))
    means = [p.outage_mean_s for p in av_params.values() if p.outage_onset_prob > 0]
    availability = AvailabilityParams(
        dropout_prob=rounded(float(np.dot(weights, [p.dropout_prob for p in av_params.values()])), 5),
        outage_onset_prob=rounded(float(np.dot(weights, [p.outage_onset_prob for p in av_params.values()])), 5),
        outage_mean_s=rounded(float(np.median(means)) if means else AvailabilityParams().outage_mean_s, 5),
        tag_outage_onset_prob=rounded(tag.get("onset_prob", 0.0), 5),
        tag_outage_mean_s=rounded(tag["mean_s"], 5) if tag.get("mean_s") else AvailabilityParams().tag_outage_mean_s,
    )
    _param(report, "availability.tag_outage_onset_prob", availability.tag_outage_onset_prob,
           n=tag["n_outages"] + tag["n_censored"], note="number of tag outages", summary=True)
    if tag.get("mean_s"):
        _param(report, "availability.tag_outage_mean_s", availability.tag_outage_mean_s,
               n=tag["n_outages"], note="uncensored tag outages")

    # ---------------------------------------------------------------- IMU
    imu_traces = [t for t in trs if t.imu is not None and t.imu.t_s.size > 100] + imu_only
    if imu_traces:
        say("fitting IMU noise")
        from .imu_fit import fit_imu

        imf = fit_imu(imu_traces)
        imu_params = imf.params
        report["imu"] = imf.diagnostics
        _param(report, "imu.white_noise_density_mps2_per_sqrt_hz",
               list(imu_params.white_noise_density_mps2_per_sqrt_hz), n=imf.n_samples, summary=True)
        _param(report, "imu.bias_rw_mps2_per_sqrt_s", imu_params.bias_rw_mps2_per_sqrt_s, n=imf.n_samples)
        _param(report, "imu.vibration.fundamental_hz", imu_params.vibration.fundamental_hz, n=imf.n_samples,
               summary=True)
        _param(report, "imu.vibration.amplitude_mps2", imu_params.vibration.amplitude_mps2, n=imf.n_samples,
               summary=True)
    else:
        imu_params = ImuParams()
        report["imu"] = {"note": "no IMU samples in the recordings: IMU parameters are the defaults, not calibrated"}
        notes.append("imu (no IMU data; defaults kept)")

    # ---------------------------------------------------------------- scenario
    phase = bf.params["burst_phase_s"]
    uwb = UwbParams(burst_rate_hz=burst_rate, burst_jitter_s=rounded(bf.params["burst_jitter_s"], 4),
                    burst_phase_s=None if phase is None else rounded(phase, 5),
                    slot_s=rounded(bf.params["slot_s"], 5), time_offset_s=rounded(offset, 5),
                    nlos_dwell_s=rounded(nlos_dwell, 4), zones=[])
    notes.append("uwb.zones (NLOS zones along the path are not fitted)")
    provenance = {
        "calibrated_by": f"physynth {__version__}",
        "created_utc": report["created_utc"],
        "datasets": list(sources or []),
        "recordings": labels,
        "imu_only_recordings": imu_only_labels,
        "command": "physynth calibrate",
    }
    data = {
        "name": name,
        "description": f"Calibrated by physynth {__version__} on {len(trs)} recording(s): " + ", ".join(labels),
        "path": path.model_dump(mode="json"),
        "motion": mp.model_dump(mode="json"),
        "imu": imu_params.model_dump(mode="json"),
        "uwb": uwb.model_dump(mode="json"),
        "anchors": [a.model_dump(mode="json", exclude_none=True) for a in anchors],
        "channel": channel.model_dump(mode="json"),
        "channel_per_anchor": {a: c.model_dump(mode="json") for a, c in per_channel.items()},
        "availability": availability.model_dump(mode="json"),
        "availability_per_anchor": {a: {k: v for k, v in p.model_dump(mode="json").items()
                                        if k in ("dropout_prob", "outage_onset_prob", "outage_mean_s")}
                                    for a, p in av_params.items()},
        "provenance": jsonable(provenance),
    }
    scn = scenario_from_dict(data, source="calibration result")
    return CalibrationResult(scenario=scn, report=jsonable(report))
