"""Calibration of the IMU error model from the IMU error = IMU minus truth-derived acceleration.

The generator's accelerometer (:mod:`physynth.models.imu`, ENU, gravity-free) adds to the true acceleration

- white noise of one-sided PSD 2 sigma_w^2 per axis (per-sample standard deviation sigma_w sqrt(fs));
- a bias random walk b(t) = sigma_b W(t) (Allan variance sigma_b^2 tau / 3, PSD sigma_b^2 / (2 pi^2 f^2));
- narrow-band vibration at f0 and its harmonics, each line a Lorentzian of -3 dB width
  ``bandwidth_hz`` holding the share w_h / sum(w) of the variance ``amplitude_mps2^2``.

The truth-derived acceleration is the truth position low-passed (zero-phase Butterworth at
``cutoff_hz``) and differentiated twice, interpolated to the IMU times; masked (NaN) truth spans and
a margin around them are left out. Above the cut-off the truth has no content, so the white-noise
density comes from the top of the error PSD; the vibration lines are fitted to the rest of the Welch
PSD (non-negative least squares over harmonic variances, grid search over the line width); the bias
random walk from the long-tau end of the Allan deviation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.signal import welch
from scipy.spatial.transform import Rotation

from ..models.imu import MotionNoiseParams, simulate_imu
from ..models.motion import Kinematics
from ..records import Imu, Trace
from ..scenario import ImuParams, VibrationParams
from ._base import CalibrationError, Fit, median_step_s, rounded, segments, trace_label
from .imu_motion_noise import (
    calm_white_density,
    coherent_bandwidth_hz,
    fit_motion_noise,
    fit_time_offset,
    level_motion_noise,
    reference_noise_target,
)
from .imu_spectrum import error_spectrum_white_floor, fit_bias_walk, fit_vibration, vibration_params
from .imu_truth import filled_truth_acceleration, has_truth_rotation, imu_error, smoothed_body_rate, truth_attitude_at
from .lever_arm import fit_lever_arm


def _imu_traces(traces: Trace | Sequence[Trace]) -> list[Trace]:
    """The traces with more than 100 IMU samples (an error when there is none)."""
    trs = [traces] if isinstance(traces, Trace) else list(traces)
    trs = [t for t in trs if t.imu is not None and t.imu.t_s.size > 100]
    if not trs:
        raise CalibrationError("no trace with IMU samples: IMU noise cannot be calibrated")
    return trs


def _fit_offset_and_lever(trs: list[Trace], fc: float, motion_dependent: bool, lever_arm: bool,
                          auto_lever: bool = False
                          ) -> tuple[float, dict[str, Any] | None, np.ndarray | None, dict[str, Any] | None]:
    """The kept IMU-to-truth time offset and lever arm with their diagnostics: (offset, offset_diag,
    lever or None, lever_diag). ``auto_lever``: a lever arm the truth's rotation cannot identify is left
    out (noted in the diagnostics) instead of raising.

    The offset is kept when it lowers the error variance by at least 0.5 % and exceeds 0.25 ms; the
    lever arm when it lowers the mean squared error by at least 0.5 %, and then the offset is fitted
    again for the sensor point (the first fit kept under ``without_lever_arm``).
    """
    offset, offset_diag = 0.0, None
    if motion_dependent:
        offset, offset_diag = fit_time_offset(trs, fc)
        if offset_diag["error_variance_reduction_frac"] < 0.005 or abs(offset) < 2.5e-4:
            offset_diag["kept"] = False
            offset = 0.0
    lever, lever_diag = None, None
    if lever_arm:
        try:
            r, lever_diag = fit_lever_arm(trs, fc, offset)
        except CalibrationError as exc:
            if not auto_lever:
                raise
            return offset, offset_diag, None, {"kept": False, "reason": str(exc)}
        lever_diag["kept"] = lever_diag["mean_square_reduction_frac"] >= 0.005
        lever = r if lever_diag["kept"] else None
        if lever is not None and motion_dependent:  # the clock offset again, now of the sensor point
            off2, od2 = fit_time_offset(trs, fc, lever_arm_m=lever)
            od2["kept"] = not (od2["error_variance_reduction_frac"] < 0.005 or abs(off2) < 2.5e-4)
            offset = off2 if od2["kept"] else 0.0
            offset_diag = {**od2, "without_lever_arm": offset_diag}
            r, lever_diag = fit_lever_arm(trs, fc, offset)
            lever_diag["kept"] = lever_diag["mean_square_reduction_frac"] >= 0.005
            lever = r if lever_diag["kept"] else None
    return offset, offset_diag, lever, lever_diag


def _imu_params(fs: float, density: np.ndarray, bias_rw: float, vibration: VibrationParams, offset: float,
                motion: dict[str, Any] | None, lever: np.ndarray | None, truth_cutoff_hz: float) -> ImuParams:
    """The fitted values, rounded, as the scenario's IMU section."""
    motion_params = MotionNoiseParams()
    if motion is not None:
        motion_params = MotionNoiseParams(
            acc_var_gain_mps2=[rounded(x, 5) for x in motion["acc_var_gain_mps2"]],
            rate_var_gain_mps4_per_radps=[rounded(x, 5) for x in motion["rate_var_gain_mps4_per_radps"]])
    return ImuParams(rate_hz=rounded(fs, 7), white_noise_density_mps2_per_sqrt_hz=[rounded(x, 5) for x in density],
                     bias_rw_mps2_per_sqrt_s=rounded(bias_rw, 4), bias_initial_std_mps2=0.0, vibration=vibration,
                     time_offset_s=rounded(offset, 4), motion_noise=motion_params,
                     lever_arm_m=[0.0, 0.0, 0.0] if lever is None else [rounded(float(x), 4) for x in lever],
                     truth_cutoff_hz=rounded(truth_cutoff_hz, 4))


def _imu_fit_diagnostics(trs: list[Trace], errs: list, fc: float, fs: float, spectrum: tuple,
                         offset_diag: dict[str, Any] | None, lever_diag: dict[str, Any] | None,
                         motion: dict[str, Any] | None, vib_diag: dict[str, Any], bias_diag: dict[str, Any],
                         notes: list[str]) -> dict[str, Any]:
    """The diagnostics dict of :func:`fit_imu` (``spectrum`` from :func:`error_spectrum_white_floor`)."""
    _, f, psd, n_total, _, lo, hi, wb, _, density = spectrum
    dec = max(1, f.size // 400)
    return {
        "truth_cutoff_hz": fc,
        "imu_rate_hz": fs,
        "white_band_hz": [float(lo), float(hi)],
        "white_noise_density_mps2_per_sqrt_hz": density.tolist(),
        "white_noise_rel_se": float(1.0 / np.sqrt(max(wb.sum() * len(errs), 1))),
        "error_std_mps2": np.sqrt(np.nanmean(np.concatenate([e[ok] for e, ok, _ in errs]) ** 2, axis=0)).tolist(),
        "time_offset": offset_diag,
        "lever_arm": lever_diag,
        "motion_noise": None if motion is None else {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                                     for k, v in motion.items()},
        "n_samples": n_total,
        "vibration": vib_diag,
        "bias_rw": {k: bias_diag[k] for k in ("value", "k2_estimate", "k2_std_error", "note")},
        "allan_deviation": bias_diag["allan_deviation"],
        "psd": {"f_hz": f[::dec].tolist(), "psd_mps2_sq_per_hz": psd[::dec].tolist()},
        "recordings": [trace_label(t, i) for i, t in enumerate(trs)],
        "not_identifiable": notes,
    }


def _truth_band(trs: list[Trace], cutoff_hz: float | None, motion_dependent: bool, truth_rate: float
                ) -> tuple[float, dict[str, Any] | None]:
    """The truth cut-off of :func:`fit_imu` and its diagnostics (None unless widened by coherence)."""
    if cutoff_hz is not None:
        return float(cutoff_hz), None
    floor = float(min(10.0, 0.2 * truth_rate))
    return coherent_bandwidth_hz(trs, floor, 0.2 * truth_rate) if motion_dependent else (floor, None)


def fit_imu(traces: Trace | Sequence[Trace], *, cutoff_hz: float | None = None, nperseg_s: float = 20.0,
            defaults: ImuParams | None = None, motion_dependent: bool = True,
            motion_rate_term: bool = False, lever_arm: bool | None = None,
            reference_cutoff_hz: float | None = None, calm_white_noise: bool = False) -> Fit[ImuParams]:
    """Fit white noise, bias random walk and vibration to the IMU error of traces with IMU and truth.

    Parameters
    ----------
    traces
        Traces with IMU samples (ENU, gravity-free) and truth positions.
    cutoff_hz
        Low-pass cut-off of the truth before double differentiation [Hz]: the band of truth the noise
        terms are fitted against, recorded as ``truth_cutoff_hz``. Default min(10 Hz, 0.2 x truth
        rate), widened with the motion-dependent model up to the highest frequency where the truth
        still follows the IMU (:func:`coherent_bandwidth_hz`, at most 0.2 x truth rate): the real motion
        in that band is then the model's input, not its noise.
    nperseg_s
        Welch segment length [s] (frequency resolution 1 / nperseg_s).
    motion_dependent
        Also fit the IMU-to-truth time offset (:func:`fit_time_offset`; kept when it lowers the error
        variance by at least 0.5 %) and the motion-scaled noise (:func:`fit_motion_noise`; an axis's
        gains kept when they carry at least 5 % of its mean error variance). The white-noise density is
        fitted as before; the vibration amplitude comes from the error variance at zero motion, and
        the vibration's power grows with the motion (:class:`~physynth.models.imu.MotionNoiseParams`).
    motion_rate_term
        Let the motion noise grow with the angular rate too (needs truth attitude rates).
    lever_arm
        Also fit the sensor's position in the body frame (:func:`fit_lever_arm`, after the time
        offset, before the motion noise; needs the truth attitude), kept when it lowers the mean
        squared error by at least 0.5 %; the noise terms are then fitted to the error with its
        lever-arm acceleration removed. Default (None): when every recording's truth has an attitude
        and a body rate.
    reference_cutoff_hz
        The cut-off of the reference truth the IMU error is judged against, when it is below
        ``cutoff_hz`` (e.g. 10 Hz against a 14 Hz input): the motion noise (c0, gains, level) is then
        fitted to what noise added to the ``cutoff_hz`` truth must carry for the error against the
        reference to come out right (:func:`reference_noise_target`), rather than to the error
        against the ``cutoff_hz`` truth itself.
    calm_white_noise
        With the motion noise, take the white-noise density from the calm samples only
        (:func:`calm_white_density`, same band): the sensor's own noise. The high-frequency error of the
        moving phases (ten times the calm level on a fast rotating trial) then belongs to the
        motion-scaled term, and at zero motion white noise, bias walk and vibration add up to c0
        instead of the pooled white level alone exceeding it.

    Returns
    -------
    Fit[ImuParams]
        Diagnostics: per-axis white-noise density and error standard deviation, the PSD (decimated),
        the vibration fit, the Allan deviation table, what was not identifiable.
    """
    trs = _imu_traces(traces)
    base = defaults or ImuParams()
    fs = 1.0 / median_step_s(trs[0].imu.t_s)
    truth_rate = 1.0 / median_step_s(trs[0].truth.t_s[np.all(np.isfinite(trs[0].truth.pos_enu_m), axis=1)])
    fc, band_diag = _truth_band(trs, cutoff_hz, motion_dependent, truth_rate)
    offset, offset_diag, lever, lever_diag = _fit_offset_and_lever(
        trs, fc, motion_dependent, all(has_truth_rotation(t) for t in trs) if lever_arm is None else lever_arm,
        auto_lever=lever_arm is None)
    motion, motion_var = None, np.zeros(3)
    if motion_dependent:
        motion = fit_motion_noise(trs, fc, offset, use_rate=motion_rate_term, lever_arm_m=lever,
                                  reference_cutoff_hz=reference_cutoff_hz)
    errs = [imu_error(t, fc, offset_s=offset, lever_arm_m=lever) for t in trs]
    if motion is not None:
        targets = None if reference_cutoff_hz is None else [
            reference_noise_target(t, fc, offset, reference_cutoff_hz, lever_arm_m=lever) for t in trs]
        motion_var = level_motion_noise(trs, errs, fc, offset, motion, targets)
    spectrum = error_spectrum_white_floor(errs, fs, fc, nperseg_s)
    nper, f, psd, n_total, n_avg, lo, hi, _, floor, density = spectrum
    calm_white = None
    if calm_white_noise and motion is not None:
        calm_white, n_calm = calm_white_density(trs, errs, fc, offset, (lo, hi))
        if calm_white is not None:
            motion["white_noise_density_pooled_mps2_per_sqrt_hz"] = density.tolist()
            motion["white_noise_from_calm_samples"] = n_calm
            density = calm_white
    err_std = np.sqrt(np.nanmean(np.concatenate([e[ok] for e, ok, _ in errs]) ** 2, axis=0))
    if motion is not None:  # the vibration must explain what is left at zero motion
        err_std = np.sqrt(np.maximum(np.minimum(err_std**2 - motion_var, motion["c0_mps2_sq"]), 1e-12))
    pooled, pooled_floor = psd.mean(axis=1), float(floor.mean())  # vibration on the pooled spectrum's excess
    vib = fit_vibration(f, pooled - pooled_floor, pooled, pooled_floor, 3 * n_avg, f_lo=max(0.3, 3.0 / (nper / fs)),
                         f_hi=min(0.45 * (fs / 2.0), lo))
    notes: list[str] = []
    bias_rw, bias_diag = fit_bias_walk(errs, fs, density, base.bias_rw_mps2_per_sqrt_s)
    if bias_diag["note"] is not None:
        notes.append("imu.bias_rw_mps2_per_sqrt_s (" + bias_diag["note"] + ")")
    # vibration: spectral shape from the comb fit, amplitude from the variance the white noise and the
    # bias walk leave unexplained (per axis), one amplitude for all axes (the generator's model)
    seg_s = float(np.mean([(b_ - a_) / fs for e_, ok_, t_ in errs for a_, b_ in segments(t_, ok_, 1.5 / fs)]))
    other_var = density**2 * fs + bias_rw**2 * seg_s / 6.0
    resid_std = np.sqrt(np.maximum(err_std**2 - other_var, 0.0))
    vibration, vib_diag = vibration_params(vib, density, fs, err_std, resid_std, other_var, motion, notes)
    params = _imu_params(fs, density, bias_rw, vibration, offset, motion, lever, fc)
    diag = _imu_fit_diagnostics(trs, errs, fc, fs, spectrum, offset_diag, lever_diag, motion, vib_diag, bias_diag,
                                notes)
    if band_diag is not None:
        diag["truth_bandwidth"] = band_diag
    return Fit(params=params, n_samples=n_total, diagnostics=diag)


def simulate_imu_on(t_s: np.ndarray, acc_enu_mps2: np.ndarray, params: ImuParams, *,
                    rng: np.random.Generator, omega_body_radps: np.ndarray | None = None,
                    attitude: Rotation | None = None) -> Imu:
    """The generator's IMU model (:func:`physynth.models.imu.simulate_imu`) applied to a given acceleration track.

    ``t_s`` (T,) uniform times [s] and ``acc_enu_mps2`` (T, 3) the true acceleration (e.g. derived
    from a real trial's truth, NaN spans filled); the IMU is sampled at ``params.rate_hz`` from t_s[0].
    ``omega_body_radps`` (T, 3) and ``attitude`` (T rotations): for the rate-scaled noise and the lever arm.
    """
    acc = np.asarray(acc_enu_mps2, dtype=float)
    kin = Kinematics(t_s=np.asarray(t_s, dtype=float), s_m=np.zeros(len(t_s)), pos_enu_m=np.zeros_like(acc),
                     vel_enu_mps=np.zeros_like(acc), acc_enu_mps2=acc)
    return simulate_imu(kin, params, rng=rng, omega_body_radps=omega_body_radps, attitude=attitude)


def imu_along_truth(real: Trace, params: ImuParams, *, rng: np.random.Generator,
                    input_cutoff_hz: float | None = None,
                    truth_input: tuple[np.ndarray, np.ndarray] | None = None) -> Imu:
    """The ENU IMU model ``params`` run along a real trace's own truth (sampled from its first truth instant).

    The model reads the truth acceleration low-passed at ``input_cutoff_hz`` (default the model's
    ``truth_cutoff_hz``, else 10 Hz), masked spans filled linearly; with a lever arm and a truth
    attitude, the sensor point's rotational acceleration along the truth's rotation (body rate
    low-passed at the same band). ``truth_input``: that band's :func:`filled_truth_acceleration`, when
    the caller has it already.
    """
    fc_in = float(input_cutoff_hz if input_cutoff_hz is not None else params.truth_cutoff_hz or 10.0)
    tg, filled = truth_input if truth_input is not None else filled_truth_acceleration(real, fc_in)
    att = truth_attitude_at(real, tg) if any(params.lever_arm_m) else None
    return simulate_imu_on(tg, filled, params, rng=rng, omega_body_radps=smoothed_body_rate(real, tg, fc_in),
                           attitude=None if att is None else att[0])


def compare_imu_along_truth(real: Trace, params: ImuParams, cutoff_hz: float, *,
                            rng: np.random.Generator, input_cutoff_hz: float | None = None) -> dict[str, np.ndarray]:
    """Apply the IMU error model ``params`` along a real trace's own truth and compare the IMU errors.

    The error of both sides is IMU minus the truth-derived acceleration low-passed at ``cutoff_hz``
    (:func:`imu_error`). The synthetic IMU reads the truth low-passed at ``input_cutoff_hz`` (default
    the model's ``truth_cutoff_hz``, else ``cutoff_hz``; :func:`imu_along_truth`): above ``cutoff_hz``
    the real IMU reads motion that the reference filters out, so a
    model calibrated on the error against a wider-band truth (``fit_imu(..., cutoff_hz=input_cutoff_hz)``)
    is compared with the same band of real motion in its input. With a truth attitude, the model's
    lever arm acts along the truth's rotation (body rate low-passed at ``input_cutoff_hz``). Returns
    per-axis error std (``std_real``, ``std_synth``), and on log10 Welch PSDs (8192-sample segments,
    0.2 Hz to 0.95 x Nyquist, masked samples zeroed) the correlation (``log_psd_corr``) and the
    log-spectral distance in dB (``lsd_db``).
    """
    fc_in = input_cutoff_hz if input_cutoff_hz is not None else params.truth_cutoff_hz or cutoff_hz
    synth = Trace(truth=real.truth, uwb=real.uwb, anchors=real.anchors,
                  imu=imu_along_truth(real, params, rng=rng, input_cutoff_hz=fc_in))
    e_r, ok_r, _ = imu_error(real, cutoff_hz)
    e_s, ok_s, _ = imu_error(synth, cutoff_hz)
    fs = params.rate_hz
    f, p_r = welch(np.where(ok_r[:, None], e_r, 0.0), fs=fs, nperseg=8192, axis=0)
    _, p_s = welch(np.where(ok_s[:, None], e_s, 0.0), fs=fs, nperseg=8192, axis=0)
    band = (f > 0.2) & (f < 0.95 * fs / 2)
    lr, ls = np.log10(p_r[band]), np.log10(p_s[band])
    return {
        "std_real": np.std(e_r[ok_r], axis=0),
        "std_synth": np.std(e_s[ok_s], axis=0),
        "log_psd_corr": np.array([np.corrcoef(lr[:, k], ls[:, k])[0, 1] for k in range(3)]),
        "lsd_db": np.sqrt(np.mean((10.0 * (lr - ls)) ** 2, axis=0)),
    }
