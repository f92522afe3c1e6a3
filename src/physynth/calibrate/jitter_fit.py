"""Calibration of the motion jitter (``motion.jitter``, :mod:`physynth.models.jitter`).

The jitter is what the real motion has and the fitted path and speed profile do not: per band and ENU
axis, the acceleration power of the real truth over its trips minus that of the scenario's own nominal
run (the fitted path driven by the fitted profile, no run-to-run draws), clipped at 0. Both are Welch
spectra of the acceleration (the truth low-passed at :data:`JITTER_CUTOFF_HZ` and differentiated
twice, as for the IMU), pooled over the runs; a band's power is its spectrum summed over the band.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.signal import welch

from ..models.jitter import JitterParams
from ..models.motion import MotionParams, RunDraw, SpeedProfileParams, compile_speed_shape, kinematics
from ..models.path import PathParams, PathPerturbation, PerturbationParams, compile_path
from ..records import Trace
from ._base import CalibrationError, rounded, segments
from .imu_truth import truth_acceleration
from .tracks import TrackSummary

JITTER_CUTOFF_HZ = 10.0
"""The truth is low-passed here before it is differentiated (above the top band edge, 8 Hz)."""
WELCH_SEGMENT_S = 16.0
"""Welch segment length [s]: 1/16 Hz resolution, four bins in the lowest (0.25-0.5 Hz) band."""


def _band_power(t_s: np.ndarray, acc: np.ndarray, ok: np.ndarray, edges: np.ndarray
                ) -> tuple[np.ndarray, float]:
    """Acceleration power (K, 3) [m^2 s^-4] per band and axis over the samples ``ok`` (contiguous
    spans of at least one Welch segment, their spectra averaged by length), and the seconds used."""
    dt = float(np.median(np.diff(t_s)))
    nper = int(round(WELCH_SEGMENT_S / dt))
    psd_sum, used = None, 0.0
    for a, b in segments(t_s, ok, max_gap_s=1.5 * dt):  # a few spans per run, each vectorised
        if b - a < nper:
            continue
        f, p = welch(acc[a:b], fs=1.0 / dt, nperseg=nper, axis=0, detrend="constant")
        w = (b - a) * dt
        psd_sum = p * w if psd_sum is None else psd_sum + p * w
        used += w
    if psd_sum is None:
        return np.zeros((edges.size - 1, 3)), 0.0
    psd = psd_sum / used
    df = f[1] - f[0]
    band = np.searchsorted(edges, f, side="right") - 1
    power = np.zeros((edges.size - 1, 3))
    for k in range(edges.size - 1):  # a handful of bands
        power[k] = psd[band == k].sum(axis=0) * df
    return power, used


def nominal_run_acceleration(path: PathParams, motion: MotionParams, rate_hz: float
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scenario's nominal run (no perturbation, no run-to-run draws, no jitter): times, ENU
    acceleration (T, 3) and the moving mask."""
    geometry = compile_path(path)
    kin = kinematics(geometry, PathPerturbation(lateral_m=0.0, sag_m=0.0),
                     motion.model_copy(update={"jitter": JitterParams()}), compile_speed_shape(motion.profile),
                     RunDraw(speed_factor=1.0, length_factor=1.0), rate_hz=rate_hz,
                     lateral_dir=geometry.lateral_direction())
    return kin.t_s, kin.acc_enu_mps2, np.linalg.norm(kin.vel_enu_mps, axis=1) > 0


def fit_jitter(traces: Sequence[Trace], tracks: Sequence[TrackSummary], path: PathParams, motion: MotionParams,
               rate_hz: float, *, bands_hz: Sequence[float] | None = None) -> tuple[JitterParams, dict[str, Any]]:
    """The jitter that makes the scenario's motion as strong as the real one in every band.

    Returns the parameters (off when no band has more real than nominal power) and diagnostics: the
    real and nominal RMS acceleration per band and axis, and the fitted one.
    """
    edges = np.asarray(bands_hz if bands_hz is not None else JitterParams().bands_hz, dtype=float)
    per_run = []  # (band power (K, 3), seconds) of each run with a usable span
    for tr, track in zip(traces, tracks, strict=True):
        try:
            tg, acc, valid = truth_acceleration(tr.truth.t_s, tr.truth.pos_enu_m, cutoff_hz=JITTER_CUTOFF_HZ)
        except CalibrationError:
            continue
        trip = (tg >= track.t_s[track.i_start]) & (tg <= track.t_s[track.i_end])
        p, used = _band_power(tg, acc, valid & trip, edges)
        if used > 0:
            per_run.append((p, used))
    seconds = float(sum(u for _, u in per_run))
    real = sum(p * u for p, u in per_run) if per_run else np.zeros((edges.size - 1, 3))
    diag: dict[str, Any] = {"bands_hz": edges.tolist(), "cutoff_hz": JITTER_CUTOFF_HZ,
                            "method": "real minus nominal-run acceleration power per band and axis (Welch), >= 0"}
    if seconds <= 0:
        diag["note"] = f"no trip span of {WELCH_SEGMENT_S:g} s with a differentiable truth: no jitter"
        return JitterParams(bands_hz=edges.tolist()), diag
    real /= seconds
    t, acc, moving = nominal_run_acceleration(path, motion, rate_hz)
    nominal, _ = _band_power(t, acc, moving, edges)
    rms = np.sqrt(np.maximum(real - nominal, 0.0))
    run_rms = [float(np.sqrt(np.maximum(p - nominal, 0.0).sum())) for p, _ in per_run]
    sigma, typical = _intensity_spread(run_rms)
    if typical is not None and rms.any():  # the typical run's level, the pooled spectrum's shape
        rms *= typical / float(np.sqrt(np.sum(rms**2)))
    diag.update(real_rms_mps2=np.sqrt(real).tolist(), nominal_rms_mps2=np.sqrt(nominal).tolist(),
                jitter_rms_mps2=rms.tolist(), seconds=seconds, intensity_log_std=sigma, runs_jitter_rms_mps2=run_rms,
                level=("geometric mean of the runs' jitter RMS, shaped by the pooled spectrum" if typical is not None
                       else "pooled over the runs"))
    rows = [[rounded(float(x), 4) for x in row] for row in rms]
    if not any(any(r) for r in rows):
        return JitterParams(bands_hz=edges.tolist()), diag
    return JitterParams(bands_hz=edges.tolist(), acc_rms_mps2=rows, intensity_log_std=rounded(sigma, 4)), diag


def _intensity_spread(run_rms: Sequence[float]) -> tuple[float, float | None]:
    """(sigma, typical RMS) of a log-normal fitted to the runs' jitter RMS: the std (ddof 1, capped at
    the bound 3) and the exponential of the mean of their logs; (0, None) with fewer than two runs
    that have any jitter."""
    logs = np.log([r for r in run_rms if r > 0])
    if logs.size < 2:
        return 0.0, None
    return float(min(np.std(logs, ddof=1), 3.0)), float(np.exp(np.mean(logs)))


IN_PLACE_RATIO = 5.0
"""A recording moves in place when its trips travel more than this many times the size of the space
they stay in (the diagonal of their bounding box): a hand-held device shaken on a lab bench."""
IN_PLACE_BANDS_HZ = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
"""Jitter bands of an in-place motion: all of it is jitter, down to the slow wander."""
IN_PLACE_PATH_M = 1e-3
"""Length [m] of the path of an in-place motion (a path must have one): a millimetre, crossed once."""


def in_place_motion(tracks: Sequence[TrackSummary], motion: MotionParams
                    ) -> tuple[PathParams, MotionParams, dict[str, Any]] | None:
    """Path and motion of a mover that stays in place (see :data:`IN_PLACE_RATIO`), or None.

    A folded path and a speed profile replay one run's strokes with the spikes of their reversals; a
    mover in place is instead a point (the centroid of the trips) that the jitter moves around. The
    point is a path of :data:`IN_PLACE_PATH_M` crossed at constant speed over the mean trip time;
    the trip time spreads as the runs' do (uniform half-width sqrt(3) std / mean), and the dwells are
    those of ``motion``.
    """
    sizes = [float(np.linalg.norm(np.ptp(tr.pos_m[tr.i_start:tr.i_end + 1], axis=0))) for tr in tracks]
    travelled = [tr.trip_length_m for tr in tracks]
    ratio = float(sum(travelled) / max(sum(sizes), 1e-9))
    if ratio < IN_PLACE_RATIO:
        return None
    centre = np.mean(np.concatenate([tr.pos_m[tr.i_start:tr.i_end + 1] for tr in tracks]), axis=0)
    trips = np.array([tr.trip_s for tr in tracks])
    spread = float(np.sqrt(3.0) * np.std(trips, ddof=1) / np.mean(trips)) if trips.size > 1 else 0.0
    path = PathParams(kind="waypoints", waypoints_enu_m=[[rounded(float(x), 7) for x in centre],
                                                         [rounded(float(centre[0]) + IN_PLACE_PATH_M, 7),
                                                          rounded(float(centre[1]), 7), rounded(float(centre[2]), 7)]],
                      perturbation=PerturbationParams(lateral_std_m=0.0, sag_std_m=0.0))
    params = MotionParams(cruise_speed_mps=rounded(IN_PLACE_PATH_M / float(np.mean(trips)), 6),
                          profile=SpeedProfileParams(kind="trapezoid", accel_frac=0.0, decel_frac=0.0),
                          cruise_speed_spread_frac=rounded(min(spread, 0.9), 4), length_spread_frac=0.0,
                          dwell_start_s=motion.dwell_start_s, dwell_end_s=motion.dwell_end_s)
    diag = {"in_place": True, "travelled_over_size": ratio, "size_m": sizes, "travelled_m": travelled,
            "centre_enu_m": centre.tolist(), "trip_s": trips.tolist(),
            "note": (f"the trips travel {ratio:.0f} x the size of the space they stay in (>= {IN_PLACE_RATIO:g}): "
                     "a motion in place, modelled as jitter around the centroid, not as a path")}
    return path, params, diag
