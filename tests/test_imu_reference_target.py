"""Calibrating the IMU noise for a comparison against a narrower reference band, and the white-noise
floor of the calm samples (physynth.calibrate.imu_fit.reference_noise_target, calm_white_density;
docs/imu.md). Synthetic traces with a known answer: optical position noise the IMU does not read, and
extra noise only while moving."""

from __future__ import annotations

import numpy as np

from physynth.calibrate.imu_fit import calm_white_density, imu_error, reference_noise_target
from physynth.calibrate.imu_truth import truth_acceleration
from physynth.records import Anchors, Imu, Trace, Truth, Uwb

FS, DURATION_S = 200.0, 150.0


def _motion(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times, noiseless positions and their exact acceleration: sums of sinusoids of 0.3-13 Hz (the
    band above 10 Hz is what the 14 Hz input holds and the 10 Hz reference does not), switched on
    over [20, 65] s and [85, 130] s with raised-cosine ramps, at rest otherwise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(DURATION_S * FS)) / FS
    env = np.zeros_like(t)
    for a, b in ((20.0, 65.0), (85.0, 130.0)):
        env += np.clip(np.minimum(t - a, b - t) / 2.0, 0.0, 1.0)
    env = 0.5 - 0.5 * np.cos(np.pi * env)  # smooth switch on/off over 2 s
    f = np.concatenate([rng.uniform(0.3, 2.0, 4), rng.uniform(9.0, 13.0, 3)])
    amp = np.concatenate([np.full(4, 0.1), np.full(3, 1e-4)])  # m: ~4 m/s^2 slow, ~0.5 m/s^2 at 9-13 Hz
    ph = rng.uniform(0, 2 * np.pi, (f.size, 3))
    s = (amp[:, None, None] * np.sin(2 * np.pi * f[:, None, None] * t[None, :, None] + ph[:, None, :])).sum(0)
    pos = env[:, None] * s
    acc = np.gradient(np.gradient(pos, t, axis=0), t, axis=0)
    return t, pos, acc


def _trace(t, pos_truth, acc_imu) -> Trace:
    truth = Truth(t_s=t, pos_enu_m=pos_truth, vel_enu_mps=np.gradient(pos_truth, t, axis=0))
    return Trace(truth=truth, imu=Imu(t_s=t, acc_mps2=acc_imu),
                 uwb=Uwb(t_s=np.zeros(0), anchor=np.zeros(0, np.int16), range_m=np.zeros(0)),
                 anchors=Anchors(ids=(), pos_enu_m=np.zeros((0, 3))))


def test_reference_target_makes_the_synthetic_error_match_the_real_one_against_the_reference():
    """A real IMU reads the true motion plus white noise; the optical truth carries position noise
    (0.05 mm white, 0.5-1 m/s^2 of acceleration in the 10-14 Hz band) that the IMU does not read. A
    synthetic IMU fed the 14 Hz truth plus noise of the reference target's variance has, against the
    10 Hz truth, the real error's std (within 2 %); noise of the error variance against the 14 Hz truth
    itself (the plain calibration) overshoots it, as the optical noise is then counted twice."""
    t, pos, acc = _motion(5)
    rng = np.random.default_rng(11)
    sigma = 0.15
    real = _trace(t, pos + rng.standard_normal(pos.shape) * 2e-4, acc + rng.standard_normal(acc.shape) * sigma)
    y, ok = reference_noise_target(real, 14.0, 0.0, 10.0)
    target = np.mean(y[ok], axis=0)
    e14, ok14, _ = imu_error(real, 14.0)
    plain = np.mean(e14[ok14] ** 2, axis=0)
    tg, a14, v14 = truth_acceleration(t, real.truth.pos_enu_m, cutoff_hz=14.0)
    a_in = np.stack([np.interp(t, tg, np.where(v14, a14[:, k], 0.0)) for k in range(3)], axis=1)
    e_real, ok_r, _ = imu_error(real, 10.0)
    std_real = np.std(e_real[ok_r], axis=0)
    out = {}
    for name, var in (("target", target), ("plain", plain)):
        noise = np.random.default_rng(3).standard_normal(a_in.shape) * np.sqrt(np.maximum(var, 0.0))
        e_s, ok_s, _ = imu_error(_trace(t, real.truth.pos_enu_m, a_in + noise), 10.0)
        out[name] = np.std(e_s[ok_s & ok_r], axis=0) / std_real - 1.0
    assert np.all(np.abs(out["target"]) < 0.02), out
    assert np.all(out["plain"] > 0.1), out  # measured +24 to +29 %


def test_reference_target_shifts_the_input_by_the_clock_offset():
    """An IMU reading the 14 Hz truth exactly, 3 ms late: at that offset the target vanishes sample by
    sample (the synthetic input is the IMU); at zero offset it does not (an offset of the wrong sign
    would leave a jerk x 6 ms error)."""
    t, pos, _ = _motion(6)
    tg, a14, v14 = truth_acceleration(t, pos, cutoff_hz=14.0)
    lag = 0.003
    a_late = np.stack([np.interp(t - lag, tg, np.where(v14, a14[:, k], 0.0)) for k in range(3)], axis=1)
    real = _trace(t, pos, a_late)
    y, ok = reference_noise_target(real, 14.0, lag, 10.0)
    assert ok.sum() > 0.9 * t.size and np.max(np.abs(y[ok])) < 1e-9
    y0, ok0 = reference_noise_target(real, 14.0, -lag, 10.0)
    assert np.max(np.abs(y0[ok0])) > 0.1


def test_calm_white_density_is_the_rest_noise_not_the_pooled_one():
    """White noise of 0.05 m/s^2 per sample throughout, plus 0.2 m/s^2 more while moving: the calm
    samples give the rest density within 5 %, although the moving phases hold 60 % of the samples."""
    t, pos, acc = _motion(7)
    rng = np.random.default_rng(4)
    moving = np.any(np.abs(pos) > 0.0, axis=1)
    noise = rng.standard_normal(acc.shape) * 0.05 + moving[:, None] * rng.standard_normal(acc.shape) * 0.2
    tr = _trace(t, pos, acc + noise)
    errs = [imu_error(tr, 14.0)]
    dens, n = calm_white_density([tr], errs, 14.0, 0.0, (60.0, 90.0))
    assert n > 20 * FS
    assert np.all(np.abs(dens * np.sqrt(FS) / 0.05 - 1.0) < 0.05), dens * np.sqrt(FS)
    e, ok, _ = errs[0]
    assert np.all(np.std(e[ok & moving], axis=0) > 3 * 0.05)  # the pooled floor would be far above it
