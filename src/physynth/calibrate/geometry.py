"""Calibration of the path geometry, the motion (speed profile, dwells, run-to-run spread) and the
anchor layout from ground truth; and :func:`transfer_scenario`, which moves a scenario's sensor,
channel and availability models onto the geometry and motion of real recordings.

Conventions are the generator's (:mod:`physynth.models.path`, :mod:`physynth.models.motion`):

- a polynomial path is a power series in the normalised arc length u = s / L, rows E, N, U;
- a waypoints path is a natural cubic spline through ``waypoints_enu_m``, re-parameterised by arc
  length (:func:`physynth.models.path.compile_path`);
- the speed is v(t) = v_c g(u) over normalised trip time u, g with maximum 1, so the trip lasts
  T = L / (v_c mean(g)); dwells at the stations come before and after the trip;
- per-run spreads are half-widths of uniform distributions (+-frac).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from ..models.motion import SpeedShape, compile_speed_shape
from ..models.path import compile_path
from ..records import Trace
from ..scenario import (
    AnchorSpec,
    MotionParams,
    PathParams,
    PerturbationParams,
    Scenario,
    SpeedProfileParams,
    scenario_from_dict,
)
from ._base import (
    AnchorLayoutError,
    CalibrationError,
    Fit,
    as_trace_list,
    good_truth,
    rounded,
    trace_label,
)
from .jitter_fit import fit_jitter
from .tracks import STOP_SPEED_FRAC, TrackSummary, summarize_track

PathKind = Literal["auto", "polynomial", "waypoints"]

POLY_DEGREE = 10
"""Degree of the cable-path polynomial (paper section III.C)."""
POLY_MAX_REL_RMSE = 1e-3
"""``auto`` picks the polynomial when its cross-track RMSE is below this fraction of the path length
(the paper's cable fit: 0.087 m over 710.2 m = 1.2e-4) or not worse than 1.25 x the waypoint fit."""
WAYPOINT_TOL_M = 0.1
"""Largest allowed deviation of the waypoint spline from the smoothed truth [m]."""
SPEED_POLY_DEGREE = 4
"""Degree of the accelerate-cruise-decelerate speed polynomial (paper section III.D)."""
SPEED_POLY_MIN_R2 = 0.9
"""Below this R^2 of the degree-4 fit of g(u), an ``empirical`` speed profile is used instead."""
ANCHOR_TOL_M = 0.05
"""Two datasets disagree about an anchor when its positions differ by more than this [m]."""
EMPIRICAL_CUTOFF_HZ = 0.25
"""Cut-off of the generator's smoothing of an empirical speed profile, in trip time [Hz]."""


def _dense_by_arc_length(track: TrackSummary, ds_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed trip positions resampled uniformly in travelled distance: (s (M,), pos (M, 3))."""
    sl = slice(track.i_start, track.i_end + 1)
    s, p = track.s_m[sl] - track.s_m[track.i_start], track.pos_m[sl]
    keep = np.concatenate([[True], np.diff(s) > 0])
    s, p = s[keep], p[keep]
    n = max(int(np.ceil(s[-1] / ds_m)) + 1, 3)
    sd = np.linspace(0.0, s[-1], n)
    return sd, np.stack([np.interp(sd, s, p[:, k]) for k in range(3)], axis=1)


def _raw_trip_points(trace: Trace, track: TrackSummary) -> np.ndarray:
    t, p = good_truth(trace)
    inside = (t >= track.t_s[track.i_start]) & (t <= track.t_s[track.i_end])
    return p[inside]


def _curve_points(params: PathParams, spacing_m: float) -> np.ndarray:
    geom = compile_path(params)
    n = max(int(np.ceil(geom.length_m / spacing_m)) + 1, 2)
    return geom.evaluate(np.linspace(0.0, geom.length_m, n))[0]


def cross_track_distance(points_m: np.ndarray, params: PathParams, spacing_m: float | None = None) -> np.ndarray:
    """Distance [m] of each point (N, 3) to the nearest point of a path (dense sampling)."""
    geom = compile_path(params)
    spacing = spacing_m if spacing_m is not None else float(np.clip(geom.length_m / 20000.0, 0.005, 0.05))
    tree = cKDTree(_curve_points(params, spacing))
    return tree.query(points_m)[0]


# --------------------------------------------------------------------------------------------------
# Path
# --------------------------------------------------------------------------------------------------


def _fit_polynomial(sd: np.ndarray, pd: np.ndarray, degree: int) -> PathParams:
    u = sd / sd[-1]
    coeffs = []
    for k in range(3):
        poly = np.polynomial.Polynomial.fit(u, pd[:, k], degree, domain=[0.0, 1.0])
        c = poly.convert(domain=[0.0, 1.0], window=[0.0, 1.0]).coef
        coeffs.append([float(x) for x in np.pad(c, (0, degree + 1 - c.size))])
    return PathParams(kind="polynomial", length_m=float(sd[-1]), coeffs_enu_m=coeffs)


def _fit_waypoints(sd: np.ndarray, pd: np.ndarray, tol_m: float, max_spacing_m: float,
                   max_waypoints: int) -> tuple[PathParams, int]:
    """Waypoints downsampled from the dense smoothed track until the spline deviates < ``tol_m``.

    Start with one waypoint every ``max_spacing_m``; then repeatedly split every span (between two
    consecutive waypoints) where the generator's spline strays more than ``tol_m`` from the dense
    track, so waypoints concentrate where the path curves. Returns the path and the iterations used.
    """
    m = sd.size
    n0 = max(int(np.ceil(sd[-1] / max_spacing_m)), 1)
    idx = np.unique(np.round(np.linspace(0, m - 1, n0 + 1)).astype(int))
    iterations = 0
    params = PathParams(kind="waypoints", waypoints_enu_m=pd[idx].tolist())
    for iterations in range(1, 40):  # noqa: B007 - a handful of refinement rounds, each vectorised
        dev = cross_track_distance(pd, params)
        seg = np.searchsorted(idx, np.arange(m), side="right") - 1  # span of each dense point
        seg = np.clip(seg, 0, idx.size - 2)
        worst = np.zeros(idx.size - 1)
        np.maximum.at(worst, seg, dev)
        bad = np.flatnonzero((worst > tol_m) & (np.diff(idx) > 1))
        if bad.size == 0 or idx.size >= max_waypoints:
            break
        new = (idx[bad] + idx[bad + 1]) // 2
        idx = np.unique(np.concatenate([idx, new]))
        if idx.size > max_waypoints:
            break
        params = PathParams(kind="waypoints", waypoints_enu_m=pd[idx].tolist())
    return params, iterations


def _path_diagnostics(params: PathParams, points: np.ndarray) -> dict[str, Any]:
    d = cross_track_distance(points, params)
    length = compile_path(params).length_m
    rmse = float(np.sqrt(np.mean(d**2)))
    return {"rmse_m": rmse, "max_error_m": float(d.max()), "p95_error_m": float(np.percentile(d, 95)),
            "length_m": float(length), "relative_rmse": rmse / float(length), "n_points": int(points.shape[0])}


def fit_path(traces: Trace | Sequence[Trace], kind: PathKind = "auto", *, degree: int = POLY_DEGREE,
             waypoint_tol_m: float = WAYPOINT_TOL_M, max_waypoints: int = 400,
             tracks: Sequence[TrackSummary] | None = None) -> Fit[PathParams]:
    """Fit the path geometry p(s) to the ground truth over arc length.

    The geometry comes from the first (reference) trace: its trip (start to end of motion, see
    :func:`summarize_track`) is smoothed, resampled uniformly in travelled distance and fitted either
    with the paper's degree-``degree`` polynomial in u = s / L (a cable path) or with a waypoint
    spline (a general walk). ``kind="auto"`` keeps the polynomial when its cross-track RMSE is below
    ``POLY_MAX_REL_RMSE`` x L or within 1.25 x the waypoint RMSE, else the waypoints. Every trace is
    compared with the fitted path (cross-track RMSE per run in the diagnostics).

    Parameters
    ----------
    traces
        One or several traces with ground truth (``truth.pos_enu_m`` ENU [m]).
    kind
        ``"auto"``, ``"polynomial"`` or ``"waypoints"``.

    Returns
    -------
    Fit[PathParams]
        ``params`` with the default perturbation (run-to-run variability is not identifiable from the
        geometry fit; :func:`fit_path_perturbation` estimates it from several runs). Diagnostics:
        RMSE of each candidate, the choice and why, per-run RMSE and length.
    """
    trs = as_trace_list(traces)
    if kind not in ("auto", "polynomial", "waypoints"):
        raise CalibrationError(f"unknown path kind {kind!r} (use auto, polynomial or waypoints)")
    labels = [trace_label(t, i) for i, t in enumerate(trs)]
    if tracks is None:
        tracks = [summarize_track(t, lab) for t, lab in zip(trs, labels, strict=True)]
    ref, ref_trace = tracks[0], trs[0]
    if ref.trip_length_m <= 0:
        raise CalibrationError(f"{ref.label}: the ground truth does not move; no path to fit")
    sd, pd = _dense_by_arc_length(ref, ds_m=float(np.clip(ref.trip_length_m / 4000.0, 0.05, 0.5)))
    raw = _raw_trip_points(ref_trace, ref)
    candidates: dict[str, PathParams] = {}
    diag: dict[str, Any] = {"reference": ref.label, "candidates": {}}
    if kind in ("auto", "polynomial"):
        candidates["polynomial"] = _fit_polynomial(sd, pd, degree)
    if kind in ("auto", "waypoints"):
        wp, iters = _fit_waypoints(sd, pd, waypoint_tol_m, max_spacing_m=max(ref.trip_length_m / 8.0, 1.0),
                                   max_waypoints=max_waypoints)
        candidates["waypoints"] = wp
        diag["waypoint_refinement_rounds"] = iters
    for name, params in candidates.items():
        diag["candidates"][name] = _path_diagnostics(params, raw)
    if kind == "auto":
        poly, way = diag["candidates"]["polynomial"], diag["candidates"]["waypoints"]
        small = poly["relative_rmse"] <= POLY_MAX_REL_RMSE
        close = poly["rmse_m"] <= 1.25 * way["rmse_m"]
        chosen = "polynomial" if (small or close) else "waypoints"
        diag["choice_reason"] = (
            f"polynomial RMSE {poly['rmse_m']:.3g} m = {poly['relative_rmse']:.2e} x L "
            f"({'<=' if small else '>'} {POLY_MAX_REL_RMSE:g} x L), waypoint RMSE {way['rmse_m']:.3g} m: "
            f"{chosen}")
    else:
        chosen = kind
        diag["choice_reason"] = f"requested {kind}"
    params = candidates[chosen]
    if chosen == "polynomial":
        params = params.model_copy(update={"coeffs_enu_m": [[rounded(c, 10) for c in row]
                                                            for row in params.coeffs_enu_m],
                                           "length_m": rounded(params.length_m, 8)})
        diag["degree"] = degree
    else:
        params = params.model_copy(update={"waypoints_enu_m": [[round(c, 4) for c in w]
                                                               for w in params.waypoints_enu_m]})
        diag["n_waypoints"] = len(params.waypoints_enu_m)
    diag["kind"] = chosen
    best = diag["candidates"][chosen]
    diag["rmse_m"], diag["length_m"] = best["rmse_m"], best["length_m"]
    per_run = {}
    for tr, track in zip(trs, tracks, strict=True):
        pts = _raw_trip_points(tr, track)
        d = cross_track_distance(pts, params)
        per_run[track.label] = {"rmse_m": float(np.sqrt(np.mean(d**2))), "trip_length_m": track.trip_length_m,
                                "n_points": int(pts.shape[0])}
    diag["per_run"] = per_run
    return Fit(params=params, n_samples=int(raw.shape[0]), diagnostics=diag)


# --------------------------------------------------------------------------------------------------
# Motion
# --------------------------------------------------------------------------------------------------


def _profile_samples(track: TrackSummary, n: int) -> tuple[np.ndarray, np.ndarray]:
    """g(u) = speed / peak at ``n`` equally spaced normalised trip times u in [0, 1]."""
    u = np.linspace(0.0, 1.0, n)
    t = track.t_s[track.i_start] + u * track.trip_s
    v = np.interp(t, track.t_s, track.speed_mps)
    return u, v / track.peak_speed_mps


def _uniform_half_width(x: np.ndarray) -> float:
    """Half-width (fraction of the mean) of a uniform law with the sample's standard deviation."""
    return float(np.sqrt(3.0) * np.std(x, ddof=1) / np.mean(x))


def fit_motion(traces: Trace | Sequence[Trace], *, profile: Literal["auto", "polynomial", "empirical"] = "auto",
               path_length_m: float | None = None, stop_speed_frac: float = STOP_SPEED_FRAC,
               min_r2: float = SPEED_POLY_MIN_R2, empirical_step_s: float = 0.2,
               defaults: MotionParams | None = None,
               tracks: Sequence[TrackSummary] | None = None) -> Fit[MotionParams]:
    """Fit the motion model: speed-profile shape, cruise speed, dwells and run-to-run spread.

    Per run, the trip runs from the start to the end of motion (:func:`summarize_track`); the dwells
    are the rests before and after it. The shape g(u) = v / v_peak over normalised trip time is fitted
    with the paper's degree-4 polynomial on all runs pooled; when its R^2 is below ``min_r2`` (a walk
    with stops) an ``empirical`` profile of samples of the first run every ``empirical_step_s`` of
    trip time is used instead. The cruise speed of run i is chosen so that the generator's trip time
    L_i / (v_c mean g) equals the real one (L_i the travelled distance, g as the generator tabulates
    it). With several runs the spreads are uniform half-widths sqrt(3) std / mean of the per-run cruise
    speeds and lengths; with one run they are not identifiable and keep ``defaults`` (MotionParams
    defaults unless given).

    ``path_length_m`` (the fitted path length) replaces the reference run's travelled distance in the
    cruise speed, so that the nominal trip time of the scenario equals the reference run's.
    """
    trs = as_trace_list(traces)
    labels = [trace_label(t, i) for i, t in enumerate(trs)]
    if tracks is None:
        tracks = [summarize_track(t, lab, stop_speed_frac=stop_speed_frac) for t, lab in zip(trs, labels, strict=True)]
    for tr in tracks:
        if tr.trip_s <= 0 or tr.trip_length_m <= 0:
            raise CalibrationError(f"{tr.label}: no motion found in the ground truth")
    base = defaults or MotionParams(cruise_speed_mps=1.0)
    us, gs, coeffs, r2, poly_rms, per_run_r2 = _fit_speed_poly(tracks)
    kind = ("polynomial" if r2 >= min_r2 else "empirical") if profile == "auto" else profile
    prof = _speed_profile(kind, profile, coeffs, tracks[0], empirical_step_s)
    shape = compile_speed_shape(prof)
    profile_rms = _profile_rms_error(kind, prof, shape, us[0], gs[0])
    lengths = np.array([tr.trip_length_m for tr in tracks])
    trips = np.array([tr.trip_s for tr in tracks])
    v_runs = lengths / (trips * shape.mean)
    ref_len = float(path_length_m) if path_length_m is not None else float(lengths[0])
    if len(tracks) == 1:
        cruise = ref_len / (trips[0] * shape.mean)
    else:
        cruise = float(np.mean(v_runs)) * ref_len / float(np.mean(lengths))
    diag: dict[str, Any] = {
        "profile_kind": kind,
        "speed_poly_coeffs": [float(c) for c in coeffs],
        "speed_poly_r2": r2,
        "speed_poly_r2_per_run": dict(zip(labels, per_run_r2, strict=True)),
        "speed_poly_min_r2": min_r2,
        "profile_choice_reason": (f"degree-{SPEED_POLY_DEGREE} polynomial R^2 = {r2:.3f} "
                                  f"({'>=' if r2 >= min_r2 else '<'} {min_r2}): {kind}"
                                  + ("" if profile == "auto" else " (requested)")),
        "shape_mean_g": shape.mean,
        "profile_rms_error": profile_rms,
        "empirical_rms_improvement": (f"empirical profile RMS error {profile_rms:.3f} against the "
                                      f"polynomial's {poly_rms:.3f} (in units of peak speed)"
                                      if kind == "empirical" else None),
        "per_run": _per_run_motion(tracks, v_runs),
        "n_runs": len(tracks),
    }
    speed_spread, length_spread = _run_to_run_spreads(tracks, v_runs, lengths, base, diag)
    dwell_start = float(np.mean([tr.dwell_start_s for tr in tracks]))
    dwell_end = float(np.mean([tr.dwell_end_s for tr in tracks]))
    q_acc = trip_acceleration_quantile(tracks, MAX_ACC_QUANTILE)
    max_acc = None if q_acc is None else MAX_ACC_FACTOR * q_acc
    diag["max_acc"] = {"value_mps2": max_acc, "quantile": MAX_ACC_QUANTILE, "factor": MAX_ACC_FACTOR,
                       "quantile_mps2": q_acc,
                       "method": "factor x quantile of |d2p/dt2| of the smoothed tracks over their trips, runs pooled"}
    params = MotionParams(cruise_speed_mps=rounded(cruise, 6), profile=prof,
                          cruise_speed_spread_frac=rounded(speed_spread, 4),
                          length_spread_frac=rounded(length_spread, 4),
                          dwell_start_s=round(dwell_start, 3), dwell_end_s=round(dwell_end, 3),
                          max_acc_mps2=None if max_acc is None else rounded(max_acc, 4))
    diag["cruise_speed_mps"] = params.cruise_speed_mps
    n = int(sum(tr.i_end - tr.i_start + 1 for tr in tracks))
    return Fit(params=params, n_samples=n, diagnostics=diag)


MAX_ACC_QUANTILE = 0.999
MAX_ACC_FACTOR = 2.0
"""``motion.max_acc_mps2`` is MAX_ACC_FACTOR x the MAX_ACC_QUANTILE quantile of the real acceleration
magnitude over the trips. The limit is there to remove what no mover does (the 30-170 m/s^2 of a
fitted path's hooks and reversals), not to reshape the turns the recording shows: a fitted spline bends
more sharply than the smoothed track it follows (curvature 99 % quantile 3.05 against 2.52 1/m on Hanyang
LOS Case_1), and at the quantile itself (factor 1) the limit slowed the walker at ordinary turns and moved
the left-out NLOS Case_2 fidelity (``tools/loo_hanyang.py --n 50 --seed 1``: KS 0.060 without a limit,
0.088 at factor 1, 0.066 at factor 2)."""


def trip_acceleration_quantile(tracks: Sequence[TrackSummary], q: float) -> float | None:
    """Quantile ``q`` of |a| [m s^-2] over the trips of the smoothed tracks (the path is fitted to the
    same smoothing, so its curvature and this limit see the same detail); None without 10 trip samples."""
    parts = []
    for tr in tracks:  # a handful of runs, each vectorised
        if tr.t_s.size < 3:
            continue
        acc = np.gradient(np.gradient(tr.pos_m, tr.t_s, axis=0), tr.t_s, axis=0)[tr.i_start:tr.i_end + 1]
        parts.append(np.linalg.norm(acc, axis=1))
    a = np.concatenate(parts) if parts else np.zeros(0)
    a = a[np.isfinite(a)]
    return float(np.quantile(a, q)) if a.size >= 10 and np.quantile(a, q) > 0 else None


def _fit_speed_poly(tracks: Sequence[TrackSummary]
                    ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], np.ndarray, float, float, list[float]]:
    """Degree-4 polynomial g(u) on the pooled runs.

    Returns ``(us, gs, coeffs, r2, poly_rms, per_run_r2)``: the samples of each run, the power-series
    coefficients in u, the pooled R^2, the pooled RMS error and the R^2 of each run.
    """
    us, gs = zip(*(_profile_samples(tr, 401) for tr in tracks), strict=True)
    u_all, g_all = np.concatenate(us), np.concatenate(gs)
    coeffs = np.polynomial.Polynomial.fit(u_all, g_all, SPEED_POLY_DEGREE, domain=[0.0, 1.0]).convert(
        domain=[0.0, 1.0], window=[0.0, 1.0]).coef
    fit_g = np.polynomial.polynomial.polyval(u_all, coeffs)
    ss_res = float(np.sum((g_all - fit_g) ** 2))
    ss_tot = float(np.sum((g_all - g_all.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    per_run_r2 = []
    for u, g in zip(us, gs, strict=True):
        res = g - np.polynomial.polynomial.polyval(u, coeffs)
        tot = np.sum((g - g.mean()) ** 2)
        per_run_r2.append(float(1.0 - np.sum(res**2) / tot) if tot > 0 else 1.0)
    return us, gs, coeffs, r2, np.sqrt(ss_res / g_all.size), per_run_r2


def _speed_profile(kind: str, profile: str, coeffs: np.ndarray, ref: TrackSummary,
                   empirical_step_s: float) -> SpeedProfileParams:
    """The ``polynomial`` profile from ``coeffs`` or the ``empirical`` one sampled from ``ref``."""
    if kind == "polynomial":
        return SpeedProfileParams(kind="polynomial", coeffs=[rounded(c, 8) for c in coeffs])
    if kind == "empirical":
        n = int(np.clip(round(ref.trip_s / empirical_step_s) + 1, 50, 4000))
        _, g = _profile_samples(ref, n)
        # smoothing spline penalty for a half-power cut-off near EMPIRICAL_CUTOFF_HZ of trip time:
        # lam * omega_c^4 = du, omega_c = 2 pi f_c T in radians per unit of u
        lam = (1.0 / (n - 1)) / (2.0 * np.pi * EMPIRICAL_CUTOFF_HZ * ref.trip_s) ** 4
        return SpeedProfileParams(kind="empirical", samples=[round(float(x), 4) for x in np.clip(g, 0.0, None)],
                                  smoothing=rounded(max(lam, 1e-300), 4))
    raise CalibrationError(f"unknown speed profile kind {profile!r} (use auto, polynomial or empirical)")


def _profile_rms_error(kind: str, prof: SpeedProfileParams, shape: SpeedShape, u_ref: np.ndarray,
                       g_ref: np.ndarray) -> float:
    """RMS error of the generator's tabulated shape against the empirical samples, or against the
    reference run's g(u) for a polynomial profile (units of peak speed)."""
    if kind == "empirical":
        u_s = np.linspace(0.0, 1.0, len(prof.samples))
        tab = np.interp(u_s, shape.u, shape.g) * float(np.max(prof.samples))
        return float(np.sqrt(np.mean((tab - np.asarray(prof.samples)) ** 2)))
    return float(np.sqrt(np.mean((np.interp(u_ref, shape.u, shape.g) - g_ref) ** 2)))


def _per_run_motion(tracks: Sequence[TrackSummary], v_runs: np.ndarray) -> dict[str, dict[str, Any]]:
    """Trip time, length, speeds and dwells of each run, keyed by label."""
    return {tr.label: {"trip_s": tr.trip_s, "trip_length_m": tr.trip_length_m,
                       "cruise_speed_mps": float(v), "peak_speed_mps": tr.peak_speed_mps,
                       "mean_speed_mps": tr.trip_length_m / tr.trip_s,
                       "dwell_start_s": tr.dwell_start_s, "dwell_end_s": tr.dwell_end_s,
                       "stop_speed_mps": tr.stop_speed_mps}
            for tr, v in zip(tracks, v_runs, strict=True)}


MAX_RUN_SPREAD_FRAC = 0.9
"""Largest run-to-run speed or length spread (uniform half-width / mean) a scenario accepts
(``physynth.bounds``: a run at 1 - spread of the mean speed must still move); wider fitted spreads are
clipped to it and the report says so (``motion.spread_clipped``)."""


PATH_MISS_WARN_M = 0.5
"""Cross-track RMSE [m] of the fitted path to the recorded track above which calibration warns: such a
path takes another route than the recording (its ranges are good to centimetres, a waypoint path follows
the track to about :data:`WAYPOINT_TOL_M`)."""


def path_miss_warnings(diag: dict[str, Any]) -> list[str]:
    """A report warning when the fitted path misses the track by more than :data:`PATH_MISS_WARN_M` (RMS)."""
    rmse = diag["rmse_m"]
    if rmse <= PATH_MISS_WARN_M:
        return []
    hint = (f"; path_kind='waypoints' follows it (to about {WAYPOINT_TOL_M:g} m)" if diag["kind"] == "polynomial"
            else "")
    return [f"the fitted {diag['kind']} path misses the recorded track by {rmse:.2f} m RMS (more than "
            f"{PATH_MISS_WARN_M:g} m){hint}"]


def spread_clip_warnings(diag: dict[str, Any]) -> list[str]:
    """Report warnings for run-to-run spreads clipped to :data:`MAX_RUN_SPREAD_FRAC` (none if not clipped)."""
    clip = diag.get("spread_clipped")
    if not clip:
        return []
    return [f"motion.{name}: the runs differ by more than a scenario can draw (fitted {raw:.3g}); clipped to "
            f"{clip['max']} (runs of very different speed or length pooled)"
            for name, raw in zip(("cruise_speed_spread_frac", "length_spread_frac"), clip["raw"], strict=True)
            if name in clip["fields"]]


def _run_to_run_spreads(tracks: Sequence[TrackSummary], v_runs: np.ndarray, lengths: np.ndarray,
                        base: MotionParams, diag: dict[str, Any]) -> tuple[float, float]:
    """Cruise-speed and length spreads (uniform half-widths) over the runs, or ``base``'s with one run;
    records the method (and what is not identifiable) in ``diag``."""
    if len(tracks) >= 2:
        raw = (_uniform_half_width(v_runs), _uniform_half_width(lengths))
        speed_spread, length_spread = (min(x, MAX_RUN_SPREAD_FRAC) for x in raw)
        diag["spread_method"] = "uniform half-width sqrt(3) * std(ddof=1) / mean over runs"
        clipped = [name for name, x in zip(("cruise_speed_spread_frac", "length_spread_frac"), raw, strict=True)
                   if x > MAX_RUN_SPREAD_FRAC]
        if clipped:  # runs of very different speed or length (e.g. slow and fast lab trials pooled)
            diag["spread_clipped"] = {"fields": clipped, "raw": [float(x) for x in raw], "max": MAX_RUN_SPREAD_FRAC}
        diag["cruise_speed_mps_std_error"] = float(np.std(v_runs, ddof=1) / np.sqrt(len(tracks)))
    else:
        speed_spread, length_spread = base.cruise_speed_spread_frac, base.length_spread_frac
        diag["not_identifiable"] = ["cruise_speed_spread_frac", "length_spread_frac"]
        diag["spread_method"] = (f"one run: run-to-run spread not identifiable, defaults kept "
                                 f"(cruise {speed_spread}, length {length_spread})")
    return speed_spread, length_spread


@dataclass(frozen=True)
class PathDeformation:
    """The path with its run-to-run deformation (:func:`path_with_deformation`)."""

    path: PathParams
    section: dict[str, Any]  # the report's ``path_perturbation`` section
    note: str  # how the two stds came about, for the report's parameter rows
    not_identifiable: str | None  # a line for the report's not-identifiable list, or None


def path_with_deformation(traces: Sequence[Trace], path: PathParams, *,
                          tracks: Sequence[TrackSummary] | None = None) -> PathDeformation:
    """``path`` with ``perturbation`` fitted over several runs (:func:`fit_path_perturbation`), or none with
    one run: one run shows no deformation, and a cable's prior (paper III.C: 2 m lateral, 1 m sag) is not
    claimed for a recording that never showed one."""
    trs = as_trace_list(traces)
    if len(trs) >= 2:
        pert = fit_path_perturbation(trs, path, tracks=tracks)
        params = PerturbationParams(lateral_std_m=rounded(pert["lateral_std_m"], 4),
                                    sag_std_m=rounded(pert["sag_std_m"], 4))
        return PathDeformation(path.model_copy(update={"perturbation": params}), pert,
                               "std over runs of the half-sine amplitudes", None)
    none = PerturbationParams(lateral_std_m=0.0, sag_std_m=0.0)
    section = {"note": "one run: run-to-run deformation not identifiable; none claimed (set path.perturbation to "
                       "add some; the paper's cable: 2 m lateral, 1 m sag)"}
    return PathDeformation(path.model_copy(update={"perturbation": none}), section, "0 (one run)",
                           "path.perturbation (one run; set to 0)")


def fit_path_perturbation(traces: Sequence[Trace], path: PathParams, *,
                          tracks: Sequence[TrackSummary] | None = None) -> dict[str, Any]:
    """Run-to-run lateral and vertical deformation of several runs around the fitted path.

    Each run's trip, resampled over its own normalised arc length u, is compared with the path at u;
    the lateral (horizontal, normal to the chord) and vertical offsets are projected on the generator's
    half-sine shape sin(pi u) by least squares. Returns per-run amplitudes and their standard
    deviations over runs (``None`` with one run: not identifiable).
    """
    trs = as_trace_list(traces)
    geom = compile_path(path)
    lateral = geom.lateral_direction()
    out: dict[str, Any] = {"per_run": {}}
    lat_amp, sag_amp = [], []
    if tracks is None:
        tracks = [summarize_track(tr, trace_label(tr, i)) for i, tr in enumerate(trs)]
    for track in tracks:
        sd, pd = _dense_by_arc_length(track, ds_m=float(np.clip(track.trip_length_m / 2000.0, 0.05, 0.5)))
        u = sd / sd[-1]
        ref = geom.evaluate(u * geom.length_m)[0]
        diff = pd - ref
        shape = np.sin(np.pi * u)
        norm = float(np.sum(shape**2))
        a_lat = float(np.sum(diff @ lateral * shape) / norm)
        a_sag = float(np.sum(diff[:, 2] * shape) / norm)
        lat_amp.append(a_lat)
        sag_amp.append(a_sag)
        out["per_run"][track.label] = {"lateral_m": a_lat, "sag_m": a_sag}
    if len(trs) >= 2:
        out["lateral_std_m"] = float(np.std(lat_amp, ddof=1))
        out["sag_std_m"] = float(np.std(sag_amp, ddof=1))
    else:
        out["lateral_std_m"] = out["sag_std_m"] = None
    return out


# --------------------------------------------------------------------------------------------------
# Anchors and transfer
# --------------------------------------------------------------------------------------------------


AnchorPolicy = Literal["per-run", "strict", "first"]


def _recording_index(name: str, labels: Sequence[str]) -> int:
    """The recording ``name`` names: its whole label, or the end of one after a ``/`` (``r1`` for
    ``lay/r1``, ``Case_2`` for ``all4/LOS/Trajectory_A/Case_2``) when only one label ends so."""
    if name in labels:
        return list(labels).index(name)
    ends = [i for i, lab in enumerate(labels) if lab.endswith("/" + name)]
    if len(ends) == 1:
        return ends[0]
    why = "names no recording" if not ends else f"names {len(ends)} recordings"
    raise CalibrationError(f"layout_from={name!r} {why}; the recordings are {', '.join(labels)}")


def anchor_layout(traces: Sequence[Trace], *, policy: AnchorPolicy = "strict",
                  tol_m: float = ANCHOR_TOL_M, labels: Sequence[str] | None = None,
                  layout_from: int | str | None = None) -> tuple[list[AnchorSpec], dict[str, Any]]:
    """The anchors a scenario generates with (ids in order of first appearance) and a diagnostics dict.

    Two traces that place the same anchor id more than ``tol_m`` apart conflict. ``policy``:

    - ``"per-run"``: anchors re-placed between runs are expected (one physical device per id, moved
      for each run, as in the Hanyang campaign); the layout of run ``layout_from`` (index or label,
      default the first run) is written, anchors it lacks take their first position elsewhere, and
      every run's own layout is recorded in the diagnostics (``layouts``);
    - ``"strict"``: a conflict is an error naming the anchor and both positions;
    - ``"first"``: the first position of each id is kept and the conflicts are listed.

    The channel and availability statistics are computed with each run's own positions under every
    policy: the policy only decides which layout the scenario generates with.
    """
    trs = list(traces)
    names = list(labels) if labels is not None else [trace_label(t, i) for i, t in enumerate(trs)]
    if policy not in ("per-run", "strict", "first"):
        raise CalibrationError(f"unknown anchor layout policy {policy!r} (use per-run, strict or first)")
    if layout_from is None:
        ref = 0
    elif isinstance(layout_from, int) and not isinstance(layout_from, bool):
        if not 0 <= layout_from < len(trs):
            raise CalibrationError(f"layout_from={layout_from}: there are {len(trs)} recordings (0 .. {len(trs) - 1})")
        ref = layout_from
    else:
        ref = _recording_index(str(layout_from), names)
    if ref != 0 and policy != "per-run":
        raise CalibrationError("layout_from chooses a recording's layout only under the per-run anchor policy")
    order = [ref] + [i for i in range(len(trs)) if i != ref]
    pos: dict[str, np.ndarray] = {}
    display: dict[str, str] = {}
    where: dict[str, str] = {}
    conflicts = []
    for k in order:
        tr, lab = trs[k], names[k]
        for j, aid in enumerate(tr.anchors.ids):
            p = tr.anchors.pos_enu_m[j]
            if aid not in pos:
                pos[aid], where[aid], display[aid] = p, lab, tr.anchors.names[j]
                continue
            dist = float(np.linalg.norm(p - pos[aid]))
            if dist > tol_m:
                msg = (f"anchor {aid} is at {np.round(pos[aid], 3).tolist()} in {where[aid]} but at "
                       f"{np.round(p, 3).tolist()} in {lab} ({dist:.2f} m apart)")
                if policy == "strict":
                    raise AnchorLayoutError(msg, "calibrate them separately, or use the anchor layout policy "
                                                 "'per-run' (each run against its own layout)")
                conflicts.append(msg)
    if not pos:
        raise CalibrationError("the recordings have no anchors (no UWB anchor layout to calibrate)")
    first_seen = [a for t in trs for a in t.anchors.ids]
    ids = sorted(pos, key=first_seen.index)
    specs = [AnchorSpec(id=a, pos_enu_m=[round(float(x), 4) for x in pos[a]],
                        name=display[a] if display[a] != a else None) for a in ids]
    layouts = {lab: {a: [round(float(x), 4) for x in t.anchors.pos_enu_m[j]] for j, a in enumerate(t.anchors.ids)}
               for t, lab in zip(trs, names, strict=True)}
    return specs, {"policy": policy, "tolerance_m": tol_m, "conflicts": conflicts,
                   "layout_from": {a: where[a] for a in ids}, "generation_layout": names[ref],
                   "layouts": layouts}


def transfer_scenario(scn: Scenario, real_traces: Trace | Sequence[Trace], *, path_kind: PathKind = "auto",
                      anchor_policy: Literal["strict", "first"] = "strict", name: str | None = None) -> Scenario:
    """``scn`` moved onto the path, motion and anchor layout of real recordings.

    Path geometry (:func:`fit_path`), speed profile, cruise speed and dwells (:func:`fit_motion`) and
    the anchors (ids and positions, :func:`anchor_layout`) come from ``real_traces``; every sensor,
    UWB acquisition, channel and availability parameter stays as in ``scn`` (but a ``variation`` section,
    dropped: the result is the real run's one site), and so do the run-to-run
    variability of the installation (``path.perturbation``, ``motion.cruise_speed_spread_frac`` and
    ``motion.length_spread_frac``). The burst clock's phase (``uwb.burst_phase_s``, the run's alignment
    with its own time base) is taken from the real run too. Anchors of the real data without a channel or availability
    override in ``scn`` use its defaults; overrides for anchors the real data lacks are dropped.
    """
    trs = as_trace_list(real_traces)
    anchors, layout = anchor_layout(trs, policy=anchor_policy)  # first: conflicting layouts stop it at once
    tracks = [summarize_track(t, trace_label(t, i)) for i, t in enumerate(trs)]
    path_fit = fit_path(trs, path_kind, tracks=tracks)
    motion_fit = fit_motion(trs, path_length_m=path_fit.diagnostics["length_m"], defaults=scn.motion, tracks=tracks)
    jitter, _ = fit_jitter(trs, tracks, path_fit.params, motion_fit.params, scn.truth_rate_hz)
    ids = [a.id for a in anchors]
    data = scn.model_dump(mode="json")
    data["name"] = name or f"{scn.name}-transfer"
    data["path"] = {**path_fit.params.model_dump(mode="json"), "reverse": False,
                    "perturbation": scn.path.perturbation.model_dump(mode="json")}
    motion = motion_fit.params.model_dump(mode="json")
    motion["cruise_speed_spread_frac"] = scn.motion.cruise_speed_spread_frac
    motion["length_spread_frac"] = scn.motion.length_spread_frac
    motion["jitter"] = jitter.model_dump(mode="json")  # the real run's shaking, like its path
    data["motion"] = motion
    data["anchors"] = [a.model_dump(mode="json", exclude_none=True) for a in anchors]
    # the burst clock's alignment with the recording is a property of the run, like its geometry (it
    # decides how often bursts straddle grid bins); the acquisition parameters themselves stay
    from .uwb_fit import fit_burst_schedule

    phase = fit_burst_schedule(trs).params["burst_phase_s"] if any(len(t.uwb) for t in trs) else None
    data["uwb"]["burst_phase_s"] = None if phase is None else round(float(phase), 5)
    data["channel_per_anchor"] = {a: v for a, v in data["channel_per_anchor"].items() if a in ids}
    data["availability_per_anchor"] = {a: v for a, v in data["availability_per_anchor"].items() if a in ids}
    data["variation"] = None  # the real run's one site, not a varied one
    data["provenance"] = {
        **scn.provenance,
        "transfer": {
            "from_scenario": scn.name,
            "recordings": [trace_label(t, i) for i, t in enumerate(trs)],
            "path_kind": path_fit.params.kind,
            "path_rmse_m": path_fit.diagnostics["rmse_m"],
            "speed_profile": motion_fit.params.profile.kind,
            "anchor_conflicts": layout["conflicts"],
            "burst_phase_s": data["uwb"]["burst_phase_s"],
        },
    }
    return scenario_from_dict(data, source=f"transfer of {scn.name}")
