"""Calibration on IMU recordings without UWB (a lab trial such as BROAD): the IMU models and the
path and motion of the truth.

Two IMU models are fitted:

- the paper's ENU gravity-free accelerometer (:func:`physynth.calibrate.imu_fit.fit_imu`, with the
  clock offset and the motion-scaled vibration);
- where the recordings hold the raw body-frame sensor and the truth its attitude, the strapdown
  accelerometer and gyroscope (:func:`fit_body_imu`): per sensor, the measured triad regressed on the
  truth-derived specific force f_b = R_wb^T (a_w - g_w) or body rate by least squares (a 3 x 3
  matrix: scale factor and misalignment, and a bias), then the Allan deviation of what is left over
  the calm samples (rest phases) gives the white noise (slope -1/2) and the bias random walk (slope
  +1/2, where the calm span is long enough).

The scenario generated from the result has no anchors (no UWB rows).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import butter, sosfiltfilt
from scipy.spatial.transform import Rotation

from .. import __version__
from ..constants import G0_MPS2, IMU_BODY_FRAME, IMU_FRAME
from ..evaluate.stats import allan_deviation
from ..models.imu import AccelerometerParams, BodyImuParams, GyroscopeParams
from ..records import Trace
from ..scenario import Scenario, scenario_from_dict
from ._base import CalibrationError, Fit, median_step_s, rounded, segments, trace_label
from .imu_fit import fit_imu
from .imu_motion_noise import CALM_ACC_MPS2, CALM_RATE_RADPS, motion_intensity
from .imu_truth import sensor_truth_acceleration, smoothed_body_rate

ALLAN_WHITE_TAU_S = 0.05
"""Averaging time at which the white noise is read off the Allan deviation, N = adev * sqrt(tau) [s]."""


def has_body_imu(trace: Trace) -> bool:
    im = trace.imu
    return (im is not None and im.acc_body_mps2 is not None and im.gyro_body_radps is not None
            and trace.truth.quat_wxyz is not None)


def body_truth(trace: Trace, cutoff_hz: float, offset_s: float = 0.0, *,
               lever_arm_m: Sequence[float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Truth-derived specific force and body rate (N, 3) at the IMU times read at t - offset, a
    validity mask (N,) and a calm mask (|a| < CALM_ACC_MPS2 and |w| < CALM_RATE_RADPS).

    f_b = R_wb^T (a_w - g_w): a_w the low-passed, twice-differentiated truth position, R_wb the truth
    attitude (nearest sample), g_w = (0, 0, -G0). The body rate is the truth's, low-passed. With
    ``lever_arm_m`` a_w is the sensor point's (:func:`~physynth.calibrate.imu_truth.sensor_truth_acceleration`).
    """
    return _body_truth_parts(trace, cutoff_hz, offset_s, lever_arm_m)[1:]


def _body_truth_parts(trace: Trace, cutoff_hz: float, offset_s: float, lever_arm_m: Sequence[float] | None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`body_truth` preceded by the truth acceleration a_w (N, 3) [m/s^2] it is built from."""
    ti = trace.imu.t_s - offset_s
    tg, a, valid = sensor_truth_acceleration(trace, cutoff_hz, lever_arm_m)
    a_i = np.stack([np.interp(ti, tg, np.where(valid, a[:, k], 0.0)) for k in range(3)], axis=1)
    ok = np.interp(ti, tg, valid.astype(float)) > 0.999
    q = trace.truth.quat_wxyz
    t_t = trace.truth.t_s
    k = np.clip(np.searchsorted(t_t, ti), 0, t_t.size - 1)
    qk = q[k]
    ok &= np.all(np.isfinite(qk), axis=1)
    f_b = np.full_like(a_i, np.nan)
    g = a_i[ok].copy()
    g[:, 2] += G0_MPS2
    f_b[ok] = Rotation.from_quat(qk[ok], scalar_first=True).inv().apply(g)
    w = smoothed_body_rate(trace, ti, cutoff_hz)
    if w is None:
        raise CalibrationError("the truth has no attitude rates: the gyroscope cannot be calibrated")
    ok &= np.all(np.isfinite(w), axis=1)
    calm = ok & (np.linalg.norm(a_i, axis=1) < CALM_ACC_MPS2) & (np.linalg.norm(w, axis=1) < CALM_RATE_RADPS)
    return a_i, f_b, w, ok, calm


MATRIX_PRIOR_STD = 0.01
"""Prior std of each scale-factor and misalignment entry around the identity (1 %, a MEMS IMU's
data-sheet order): an axis the motion hardly excites stays near 1 instead of fitting noise."""


def _lowpass(x: np.ndarray, fs: float, cutoff_hz: float) -> np.ndarray:
    """(N, 3) zero-phase 4th-order Butterworth low-pass (NaN gaps bridged linearly before filtering)."""
    t = np.arange(x.shape[0])
    ok = np.all(np.isfinite(x), axis=1)
    filled = np.stack([np.interp(t, t[ok], x[ok, k]) for k in range(3)], axis=1)
    return sosfiltfilt(butter(4, min(cutoff_hz, 0.45 * fs), fs=fs, output="sos"), filled, axis=0)


def _affine_fit(x: np.ndarray, y: np.ndarray, prior_std: float = MATRIX_PRIOR_STD) -> tuple[np.ndarray, np.ndarray]:
    """y = M x + b over rows by least squares with a Gaussian prior M ~ I +- prior_std: (M (3, 3), b (3,)).

    The prior's weight per output is its residual variance over prior_std^2 (a MAP estimate), so a
    well-excited axis is decided by the data and an unexcited one by the prior.
    """
    design = np.concatenate([x, np.ones((x.shape[0], 1))], axis=1)
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid_var = np.var(y - design @ coef, axis=0)
    m, b = np.zeros((3, 3)), np.zeros(3)
    gram, rhs = design.T @ design, design.T @ y
    for k in range(3):  # three outputs, each a 4 x 4 solve
        lam = resid_var[k] / prior_std**2
        reg = np.diag([lam, lam, lam, 0.0])
        target = np.zeros(4)
        target[k] = lam  # pulls row k of M towards the k-th unit vector
        sol = np.linalg.solve(gram + reg, rhs[:, k] + target)
        m[k], b[k] = sol[:3], sol[3]
    return m, b


def _noise_from_allan(resid: np.ndarray, t_s: np.ndarray, calm: np.ndarray, fs: float
                      ) -> tuple[np.ndarray, float | None, dict[str, Any]]:
    """White-noise density (3,) and bias random walk (or None) from the Allan deviation of the
    residual over the longest calm segment."""
    segs = [s for s in segments(t_s, calm, max_gap_s=1.5 / fs) if s[1] - s[0] > 20]
    if not segs:
        raise CalibrationError("no calm (resting) span to read the IMU noise from")
    a, b = max(segs, key=lambda s: s[1] - s[0])
    x = resid[a:b] - resid[a:b].mean(axis=0)
    dur = (b - a) / fs
    taus = np.geomspace(1.0 / fs, max(dur / 4.0, 2.0 / fs), 20)
    adev = allan_deviation(x, fs, taus).T  # (T, 3)
    tau_w = max(ALLAN_WHITE_TAU_S, 1.0 / fs)
    white = np.array([np.interp(np.log(tau_w), np.log(taus), adev[:, k]) for k in range(3)]) * np.sqrt(tau_w)
    # random walk: Allan variance K^2 tau / 3 above the white part at the longest tau, if it stands out
    long = taus[-1]
    excess = adev[-1] ** 2 - white**2 / long
    n_clusters = max(dur / long, 1.0)
    rw = float(np.sqrt(np.mean(np.maximum(excess, 0.0)) * 3.0 / long)) \
        if np.mean(excess) > 2.0 * np.mean(adev[-1] ** 2) / np.sqrt(n_clusters) else None
    return white, rw, {"calm_span_s": dur, "tau_s": taus.tolist(), "adev": adev.tolist(),
                       "white_tau_s": tau_w}


def _pooled_body_regressions(trs: list[Trace], fs: float, cutoff_hz: float, offset_s: float,
                             lever_arm_m: Sequence[float] | None) -> tuple:
    """Accelerometer and gyroscope matrix and bias fitted on the valid samples of all recordings pooled:
    (m_a, b_a, m_g, b_g, per-recording (trace, f_b, w, valid, calm, |a_w|), number of samples)."""
    xs_f, ys_f, xs_w, ys_w = [], [], [], []
    per = []
    for tr in trs:  # a handful of recordings, each vectorised
        a_w, f_b, w, ok, calm = _body_truth_parts(tr, cutoff_hz, offset_s, lever_arm_m)
        acc, gyr = tr.imu.acc_body_mps2, tr.imu.gyro_body_radps
        ok &= np.all(np.isfinite(acc), axis=1) & np.all(np.isfinite(gyr), axis=1)
        # the measurement low-passed like the truth: the matrix compares the same frequency band (a
        # truth attenuated near the cut-off would otherwise read as a scale factor above 1)
        xs_f.append(f_b[ok])
        ys_f.append(_lowpass(acc, fs, cutoff_hz)[ok])
        xs_w.append(w[ok])
        ys_w.append(_lowpass(gyr, fs, cutoff_hz)[ok])
        per.append((tr, f_b, w, ok, calm & ok, np.linalg.norm(a_w, axis=1)))
    m_a, b_a = _affine_fit(np.concatenate(xs_f), np.concatenate(ys_f))
    m_g, b_g = _affine_fit(np.concatenate(xs_w), np.concatenate(ys_w))
    return m_a, b_a, m_g, b_g, per, int(sum(x.shape[0] for x in xs_f))


def _body_noise_per_recording(per: list[tuple], m_a: np.ndarray, b_a: np.ndarray, m_g: np.ndarray,
                              b_g: np.ndarray, fs: float, notes: list[str]) -> tuple:
    """White noise and bias random walk of each recording's residual (Allan deviation over its calm
    span, or over the whole recording without one): (noise_a, noise_g, rw_a, rw_g, per-recording
    diagnostics, gyro residual sums for the motion-scaled power: :class:`_GyroMotionSums`). Appends to
    ``notes``."""
    noise_a, noise_g, rw_a, rw_g, diag_rec = [], [], [], [], []
    gyro_motion = _GyroMotionSums()
    for tr, f_b, w, ok, calm, a_abs in per:
        ra = np.where(ok[:, None], tr.imu.acc_body_mps2 - (f_b @ m_a.T + b_a), np.nan)
        rg = np.where(ok[:, None], tr.imu.gyro_body_radps - (w @ m_g.T + b_g), np.nan)
        gyro_motion.add(rg, np.linalg.norm(w, axis=1), a_abs, ok, calm)
        span = calm if calm.sum() >= 2.0 * fs else ok  # no rest: the residual of the whole recording
        if span is ok:
            notes.append(f"{trace_label(tr, len(diag_rec))}: no calm span of 2 s; body-frame IMU noise read "
                         "from the residual of the moving recording")
        try:
            na, ka, da = _noise_from_allan(ra, tr.imu.t_s, span, fs)
            ng, kg, dg = _noise_from_allan(rg, tr.imu.t_s, span, fs)
        except CalibrationError:
            continue
        noise_a.append(na)
        noise_g.append(ng)
        rw_a.append(ka)
        rw_g.append(kg)
        diag_rec.append({"recording": trace_label(tr, len(diag_rec)), "acc_white": na.tolist(),
                         "gyro_white": ng.tolist(),
                         "calm_span_s": da["calm_span_s"],
                         "acc_error_std_mps2": np.nanstd(ra[ok], axis=0).tolist(),
                         "gyro_error_std_radps": np.nanstd(rg[ok], axis=0).tolist()})
    return noise_a, noise_g, rw_a, rw_g, diag_rec, gyro_motion


def _median_bias_walk(vals: list[float | None], default: float, name: str, notes: list[str]) -> float:
    """The median of the identified bias random walks, else ``default`` (with a note)."""
    got = [v for v in vals if v is not None]
    if got:
        return float(np.median(got))
    notes.append(f"{name} (calm spans too short for the +1/2 Allan slope; default {default:g} kept)")
    return default


@dataclass
class _GyroMotionSums:
    """Sums over recordings of the gyro residual e (per body axis) for the laws var_k = c0_k + gain_k x,
    x = |a| (truth acceleration) or |w| (body rate): c0 from the calm samples, the gain by the pooled
    ratio of means (the residual power above c0 over the mean of x)."""

    e2: np.ndarray = field(default_factory=lambda: np.zeros(3))  # sum of e_k^2 over the valid samples
    e2_calm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    w_sum: float = 0.0
    a_sum: float = 0.0
    n: int = 0
    n_calm: int = 0

    def add(self, resid: np.ndarray, w_abs: np.ndarray, a_abs: np.ndarray, ok: np.ndarray, calm: np.ndarray) -> None:
        self.e2 += np.sum(resid[ok] ** 2, axis=0)
        self.e2_calm += np.sum(resid[calm] ** 2, axis=0)
        self.w_sum += float(np.sum(w_abs[ok]))
        self.a_sum += float(np.sum(a_abs[ok]))
        self.n += int(ok.sum())
        self.n_calm += int(calm.sum())

    @property
    def calm_variance(self) -> np.ndarray:
        return self.e2_calm / self.n_calm if self.n_calm > 0 else np.zeros(3)

    def gain(self, x_sum: float) -> np.ndarray:
        """Per-axis gain of the law in x (``x_sum``: ``a_sum`` or ``w_sum``), >= 0."""
        if x_sum <= 0:
            return np.zeros(3)
        return np.maximum((self.e2 - self.calm_variance * self.n) / x_sum, 0.0)


def _body_imu_params(fs: float, offset_s: float, base: BodyImuParams, lever_arm_m: Sequence[float] | None,
                     na: np.ndarray, ng: np.ndarray, ka: float, kg: float, m_a: np.ndarray, b_a: np.ndarray,
                     m_g: np.ndarray, b_g: np.ndarray) -> BodyImuParams:
    """The fitted values, rounded; the per-device spreads are the RMS of this device's errors."""
    off = ~np.eye(3, dtype=bool)
    return BodyImuParams(
        rate_hz=rounded(fs, 7), time_offset_s=rounded(offset_s, 4), vibration=base.vibration,
        lever_arm_m=[0.0, 0.0, 0.0] if lever_arm_m is None else [rounded(float(x), 4) for x in lever_arm_m],
        accelerometer=AccelerometerParams(
            noise_density_mps2_per_sqrt_hz=rounded(float(na.mean()), 4), bias_rw_mps2_per_sqrt_s=rounded(ka, 4),
            turn_on_bias_std_mps2=rounded(float(np.sqrt(np.mean(b_a**2))), 4),
            scale_factor_std=rounded(float(np.sqrt(np.mean((np.diag(m_a) - 1.0) ** 2))), 4),
            misalignment_std_rad=rounded(float(np.sqrt(np.mean(m_a[off] ** 2))), 4)),
        gyroscope=GyroscopeParams(
            noise_density_radps_per_sqrt_hz=rounded(float(ng.mean()), 4), bias_rw_radps_per_sqrt_s=rounded(kg, 4),
            turn_on_bias_std_radps=rounded(float(np.sqrt(np.mean(b_g**2))), 4),
            scale_factor_std=rounded(float(np.sqrt(np.mean((np.diag(m_g) - 1.0) ** 2))), 4),
            misalignment_std_rad=rounded(float(np.sqrt(np.mean(m_g[off] ** 2))), 4)),
    )


def fit_body_imu(traces: Sequence[Trace], *, cutoff_hz: float = 10.0, offset_s: float = 0.0,
                 defaults: BodyImuParams | None = None, lever_arm_m: Sequence[float] | None = None
                 ) -> Fit[BodyImuParams]:
    """Fit the body-frame accelerometer and gyroscope on recordings with raw IMU and truth attitude.

    Per sensor: M (scale factor = diag - 1, misalignment = off-diagonal) and bias by least squares
    over the valid samples of all recordings pooled, with a prior M ~ I +- ``MATRIX_PRIOR_STD``; white
    noise and bias random walk from the Allan deviation of the residual over the calm span of each
    recording (median over recordings). With one device, the per-device spreads of the scenario
    (``scale_factor_std``, ``misalignment_std_rad``, ``turn_on_bias_std_*``) are set to the RMS of the
    fitted values (one draw of the population). ``lever_arm_m`` (body frame [m], e.g. from
    :func:`~physynth.calibrate.imu_fit.fit_imu` with ``lever_arm=True``): the truth is the sensor
    point's, and the scenario keeps it.
    """
    trs = [t for t in traces if has_body_imu(t)]
    if not trs:
        raise CalibrationError("no recording with a body-frame accelerometer + gyroscope and truth attitude")
    base = defaults or BodyImuParams()
    fs = 1.0 / median_step_s(trs[0].imu.t_s)
    m_a, b_a, m_g, b_g, per, n_samples = _pooled_body_regressions(trs, fs, cutoff_hz, offset_s, lever_arm_m)
    notes: list[str] = []
    noise_a, noise_g, rw_a, rw_g, diag_rec, gyro_motion = _body_noise_per_recording(per, m_a, b_a, m_g, b_g, fs,
                                                                                    notes)
    if not noise_a:
        raise CalibrationError("no recording has a valid span: the body-frame IMU noise cannot be read")
    na, ng = np.median(noise_a, axis=0), np.median(noise_g, axis=0)
    ka = _median_bias_walk(rw_a, base.accelerometer.bias_rw_mps2_per_sqrt_s,
                           "body_imu.accelerometer.bias_rw_mps2_per_sqrt_s", notes)
    kg = _median_bias_walk(rw_g, base.gyroscope.bias_rw_radps_per_sqrt_s,
                           "body_imu.gyroscope.bias_rw_radps_per_sqrt_s", notes)
    c0_g = gyro_motion.calm_variance
    gyro_gain = float(np.mean(gyro_motion.gain(gyro_motion.w_sum)))
    acc_gain = gyro_motion.gain(gyro_motion.a_sum)
    params = _body_imu_params(fs, offset_s, base, lever_arm_m, na, ng, ka, kg, m_a, b_a, m_g, b_g)
    params = params.model_copy(update={"gyroscope": params.gyroscope.model_copy(update={
        "vibration_acc_var_gain_rad2_per_m": [rounded(float(x), 6) for x in acc_gain]})})
    notes.append(f"body_imu.gyroscope.vibration_rate_var_gain_radps (measured {gyro_gain:.3g} rad^2/s^2 per rad/s on "
                 "these recordings but not used: the gyro residual grows with the acceleration |a|, not with the "
                 "rate; fitted on BROAD translation trials a rate law overshoots a fast-rotating trial by 35-160 %)")
    diag = {"accelerometer_matrix": m_a.tolist(), "accelerometer_bias_mps2": b_a.tolist(),
            "gyroscope_matrix": m_g.tolist(), "gyroscope_bias_radps": b_g.tolist(),
            "accelerometer_white_per_axis": na.tolist(), "gyroscope_white_per_axis": ng.tolist(),
            "gyroscope_calm_variance_radps_sq": c0_g.tolist(), "gyroscope_rate_var_gain_radps": gyro_gain,
            "gyroscope_acc_var_gain_rad2_per_m": acc_gain.tolist(),
            "recordings": diag_rec, "truth_cutoff_hz": cutoff_hz, "time_offset_s": offset_s,
            "not_identifiable": notes,
            "note": "one device: per-device spreads are the RMS of this device's fitted errors"}
    return Fit(params=params, n_samples=n_samples, diagnostics=diag)


def _attitude_section(traces: Sequence[Trace], cutoff_hz: float) -> dict[str, Any]:
    """A smoothly tumbling attitude with the truth's body-rate spread and 1/e correlation lag (or tangent)."""
    rates = []
    for tr in traces:
        if tr.truth.quat_wxyz is None:
            continue
        w = smoothed_body_rate(tr, tr.truth.t_s, cutoff_hz)
        if w is not None:
            rates.append(w[np.all(np.isfinite(w), axis=1)])
    if not rates:
        return {"kind": "tangent"}
    w = np.concatenate(rates)
    std = float(np.sqrt(np.mean(w**2)))
    dt = median_step_s(traces[0].truth.t_s)
    x = w - w.mean(axis=0)
    n = min(x.shape[0] // 2, int(10.0 / dt))
    acf = np.array([np.mean(np.sum(x[: x.shape[0] - k] * x[k:], axis=1)) for k in range(0, n, max(1, n // 200))])
    lag = int(np.argmax(acf < acf[0] / np.e)) * max(1, n // 200) if np.any(acf < acf[0] / np.e) else n
    # the smooth spectrum's autocorrelation (1 + t / tau) exp(-t / tau) falls to 1/e at t = 2.146 tau
    return {"kind": "tumble", "tumble_spectrum": "smooth", "tumble_rate_std_radps": rounded(std, 4),
            "tumble_correlation_s": rounded(max(lag * dt / SMOOTH_ACF_1_OVER_E, dt), 4)}


SMOOTH_ACF_1_OVER_E = 2.1462
"""(1 + x) exp(-x) = 1/e at x = 2.1462: the 1/e lag of a smooth tumble's rate in units of its tau."""


@dataclass(frozen=True)
class _TruthMotion:
    """The path and motion an IMU-only calibration writes, with the fits they come from."""

    path_fit: Fit
    motion_fit: Fit
    tracks: list
    in_place: tuple | None  # in_place_motion's result, None for a mover along a path
    path: Any
    motion: Any
    jitter: Any
    jitter_diag: dict[str, Any]
    rate_hz: float
    deformation: Any = None  # geometry.PathDeformation of a mover along a path, None for a motion in place


def _truth_motion(trs: list[Trace], labels: list[str], path_kind: str) -> _TruthMotion:
    """Path, motion and jitter of the truth: a fitted path and speed profile, or, for a motion in place
    (:func:`~physynth.calibrate.jitter_fit.in_place_motion`), a point; the jitter fitted on top."""
    from .geometry import fit_motion, fit_path, path_with_deformation, summarize_track
    from .jitter_fit import IN_PLACE_BANDS_HZ, fit_jitter, in_place_motion

    tracks = [summarize_track(t, lab) for t, lab in zip(trs, labels, strict=True)]
    path_fit = fit_path(trs, path_kind, tracks=tracks)  # type: ignore[arg-type]
    motion_fit = fit_motion(trs, path_length_m=path_fit.diagnostics["length_m"], tracks=tracks)
    rate = 1.0 / median_step_s(trs[0].truth.t_s)
    path_p, motion_p, bands = path_fit.params, motion_fit.params, None
    place = in_place_motion(tracks, motion_p)
    deformation = None
    if place is not None:  # a device shaken on a bench: a point and its jitter, not a folded path
        path_p, motion_p, _ = place
        bands = IN_PLACE_BANDS_HZ
    else:  # a mover along a path: its run-to-run deformation from the runs, none from one
        deformation = path_with_deformation(trs, path_p, tracks=tracks)
        path_p = deformation.path
    jitter, jitter_diag = fit_jitter(trs, tracks, path_p, motion_p, rate, bands_hz=bands)
    if place is not None:
        jitter_diag["in_place"] = place[2]
    return _TruthMotion(path_fit=path_fit, motion_fit=motion_fit, tracks=tracks, in_place=place, path=path_p,
                        motion=motion_p, jitter=jitter, jitter_diag=jitter_diag, rate_hz=rate, deformation=deformation)


def _imu_only_parameters(tm: _TruthMotion, imf: Fit, body: Any, n_runs: int) -> dict[str, Any]:
    """The report's ``parameters`` of an IMU-only calibration: each fitted value with its sample count."""
    params: dict[str, Any] = {}

    def put(key: str, value: Any, n: int, summary: bool = True) -> None:
        params[key] = {"value": value, "n_samples": int(n), **({"summary": True} if summary else {})}

    n_truth = int(sum(tr.i_end - tr.i_start + 1 for tr in tm.tracks))
    put("motion.in_place", tm.in_place is not None, n_truth)
    if tm.deformation is not None:
        for key in ("lateral_std_m", "sag_std_m"):
            put(f"path.perturbation.{key}", getattr(tm.path.perturbation, key), n_runs, summary=False)
    put("motion.jitter.acc_rms_mps2", tm.jitter.acc_rms_mps2, n_truth, summary=False)  # a table: in the report
    put("motion.jitter.intensity_log_std", tm.jitter.intensity_log_std, len(tm.tracks))
    p = imf.params
    put("imu.white_noise_density_mps2_per_sqrt_hz", list(p.white_noise_density_mps2_per_sqrt_hz), imf.n_samples)
    put("imu.time_offset_s", p.time_offset_s, imf.n_samples)
    put("imu.motion_noise.acc_var_gain_mps2", list(p.motion_noise.acc_var_gain_mps2), imf.n_samples)
    put("imu.vibration.amplitude_mps2", p.vibration.amplitude_mps2, imf.n_samples)
    if body is not None:
        b = body.params
        put("body_imu.accelerometer.noise_density_mps2_per_sqrt_hz", b.accelerometer.noise_density_mps2_per_sqrt_hz,
            body.n_samples)
        put("body_imu.gyroscope.noise_density_radps_per_sqrt_hz", b.gyroscope.noise_density_radps_per_sqrt_hz,
            body.n_samples)
        put("body_imu.accelerometer.scale_factor_std", b.accelerometer.scale_factor_std, body.n_samples)
        put("body_imu.gyroscope.scale_factor_std", b.gyroscope.scale_factor_std, body.n_samples)
    return params


def calibrate_imu_only(traces: Sequence[Trace], *, name: str = "calibrated", path_kind: str = "auto",
                       sources: Sequence[str] | None = None,
                       progress: Callable[[str], None] | None = None) -> Any:
    """A scenario from IMU-only recordings: fitted IMU models, path and motion from the truth, no anchors.

    Returns a :class:`physynth.calibrate.CalibrationResult`.
    """
    from .geometry import path_miss_warnings, spread_clip_warnings
    from .report import CalibrationResult

    say = progress or (lambda _msg: None)
    trs = list(traces)
    if not trs:
        raise CalibrationError("no IMU recording to calibrate on")
    labels = [trace_label(t, i) for i, t in enumerate(trs)]
    say("fitting the path and motion of the truth")
    tm = _truth_motion(trs, labels, path_kind)
    say("fitting the IMU (ENU, gravity-free)")
    imf = fit_imu(trs)
    fc = float(imf.diagnostics["truth_cutoff_hz"])
    frames = [IMU_FRAME]
    body = None
    if any(has_body_imu(t) for t in trs):
        say("fitting the body-frame accelerometer and gyroscope")
        body = fit_body_imu(trs, cutoff_hz=fc, offset_s=imf.params.time_offset_s,
                            lever_arm_m=imf.params.lever_arm_m if any(imf.params.lever_arm_m) else None)
        frames.append(IMU_BODY_FRAME)
    imu = imf.params.model_dump(mode="json")
    data: dict[str, Any] = {
        "name": name,
        "description": f"calibrated by physynth {__version__} on IMU-only recordings {', '.join(labels)}",
        "path": {**tm.path.model_dump(mode="json"), "reverse": False},
        "motion": tm.motion.model_copy(update={"jitter": tm.jitter}).model_dump(mode="json"),
        "attitude": _attitude_section(trs, fc),
        "imu": imu,
        "imu_frames": frames,
        "anchors": [],
        "truth_rate_hz": rounded(tm.rate_hz, 7),
        "provenance": {"calibrated_on": labels, "sources": list(sources or []), "imu_only": True},
    }
    if body is not None:
        data["body_imu"] = {**body.params.model_dump(mode="json"), "rate_hz": imu["rate_hz"]}
        # the motion-driven part of the accelerometer error is the ENU fit's, one axis-mean gain (body
        # axes turn with the sensor); its comb shape is the ENU fit's too
        mot = imf.params.motion_noise
        acc_sec = data["body_imu"]["accelerometer"]
        # per axis the ENU model scales with |a_k|; the body model with |a|: match the mean variance
        a_k = np.concatenate([motion_intensity(t, fc, imf.params.time_offset_s)[0] for t in trs])
        a_k = a_k[np.all(np.isfinite(a_k), axis=1)]
        share = float(np.mean(a_k @ np.asarray(mot.acc_var_gain_mps2)) / 3.0
                      / max(float(np.mean(np.linalg.norm(a_k, axis=1))), 1e-12))
        acc_sec["vibration_acc_var_gain_mps2"] = rounded(share, 5)
        acc_sec["vibration_rate_var_gain_mps4_per_radps"] = rounded(float(np.mean(mot.rate_var_gain_mps4_per_radps)), 5)
        acc_sec["vibration_amplitude_mps2"] = rounded(float(np.sqrt(np.mean(
            (imf.params.vibration.amplitude_mps2 * np.asarray(imf.params.vibration.axis_gain)) ** 2))), 5)
        data["body_imu"]["vibration"] = {**imf.params.vibration.model_dump(mode="json"), "axis_gain": [1.0, 1.0, 1.0]}
    scn: Scenario = scenario_from_dict(data, "calibrated IMU-only")
    params = _imu_only_parameters(tm, imf, body, len(trs))
    report: dict[str, Any] = {
        "physynth_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "recordings": labels,
        "imu_only_recordings": labels,
        "sources": list(sources or []),
        "parameters": params,
        "path": tm.path_fit.diagnostics, "motion": tm.motion_fit.diagnostics, "motion_jitter": tm.jitter_diag,
        **({} if tm.deformation is None else {"path_perturbation": tm.deformation.section}),
        "imu": imf.diagnostics,
        "body_imu": None if body is None else body.diagnostics,
        "not_identifiable": ["uwb, channel, availability, anchors (IMU-only recordings: the scenario has no anchors)"]
        + ([tm.deformation.not_identifiable] if tm.deformation is not None and tm.deformation.not_identifiable else [])
        + list(imf.diagnostics.get("not_identifiable", []))
        + ([] if body is None else body.diagnostics["not_identifiable"]),
        "scenario": scn.model_dump(mode="json"),
    }
    warnings = ([*path_miss_warnings(tm.path_fit.diagnostics), *spread_clip_warnings(tm.motion_fit.diagnostics)]
                if tm.in_place is None else [])  # a path's fit and spreads; a motion in place is a point
    if warnings:
        report["warnings"] = warnings
    return CalibrationResult(scenario=scn, report=report)
