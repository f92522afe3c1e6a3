"""The truth band an IMU model is calibrated against (docs/imu.md): the calibration widens it to where
the truth still follows the IMU (coherence at least 0.5), records it as ``imu.truth_cutoff_hz``, and a
model run along a recorded truth reads that band. Checked on a synthetic oracle whose crossing
frequency is known, and on the shared BROAD trials (a left-out trial predicted better than with the
former 10 Hz, no-lever-arm default)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physynth.calibrate import CalibrationError
from physynth.calibrate.imu_fit import compare_imu_along_truth, fit_imu
from physynth.calibrate.imu_motion_noise import COHERENCE_MIN, coherent_bandwidth_hz
from physynth.calibrate.lever_arm import fit_lever_arm
from physynth.records import Anchors, Imu, Trace, Truth, Uwb

FS = 400.0
F_CROSS = 15.0  # [Hz] where the truth's differentiation noise reaches the motion's power


def _oracle(seed: int, duration_s: float = 240.0) -> Trace:
    """Motion: white acceleration of PSD S per axis (0.3-60 Hz). Truth: its positions plus white
    position noise whose second derivative has PSD (2 pi f)^4 * q, equal to S at F_CROSS. IMU: the motion's
    acceleration exactly. The coherence is then S / (S + (2 pi f)^4 q) = 1 / (1 + (f / F_CROSS)^4)."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * FS)
    t = np.arange(n) / FS
    spec = np.fft.rfft(rng.standard_normal((n, 3)), axis=0)
    f = np.fft.rfftfreq(n, 1.0 / FS)
    spec[(f < 0.3) | (f > 60.0)] = 0.0
    w = 2 * np.pi * np.maximum(f, 1e-9)
    acc = np.fft.irfft(spec, n, axis=0)
    pos = np.fft.irfft(-spec / w[:, None] ** 2, n, axis=0)
    s_acc = 2.0 / FS  # one-sided PSD of the unit white sequence before band-limiting
    q = s_acc / (2 * np.pi * F_CROSS) ** 4  # one-sided position-noise PSD
    pos = pos + rng.standard_normal((n, 3)) * np.sqrt(q * FS / 2.0)
    truth = Truth(t_s=t, pos_enu_m=pos, vel_enu_mps=np.gradient(pos, t, axis=0))
    return Trace(truth=truth, imu=Imu(t_s=t, acc_mps2=acc),
                 uwb=Uwb(t_s=np.zeros(0), anchor=np.zeros(0, np.int16), range_m=np.zeros(0)),
                 anchors=Anchors(ids=(), names=(), pos_enu_m=np.zeros((0, 3))), meta={})


def test_bandwidth_is_where_the_coherence_crosses_its_threshold():
    # 1 / (1 + (f / F_CROSS)^4) = COHERENCE_MIN at f = F_CROSS * (1 / COHERENCE_MIN - 1) ** 0.25
    expected = F_CROSS * (1.0 / COHERENCE_MIN - 1.0) ** 0.25
    bw, diag = coherent_bandwidth_hz([_oracle(1), _oracle(2)], floor_hz=5.0, cap_hz=40.0)
    # 1-Hz frequency resolution, 2 x 240 segments per estimate: the crossing is found within 1.5 Hz
    assert abs(bw - expected) <= 1.5, (bw, expected, diag["coherence"][:20])
    assert diag["coherence"][0] > 0.9  # the curve is reported from the floor up


def test_bandwidth_stays_at_the_floor_and_the_cap():
    assert coherent_bandwidth_hz([_oracle(3)], floor_hz=25.0, cap_hz=40.0)[0] == 25.0  # incoherent already
    assert coherent_bandwidth_hz([_oracle(3)], floor_hz=2.0, cap_hz=8.0)[0] == 8.0  # coherent to the cap
    assert coherent_bandwidth_hz([_oracle(3)], floor_hz=10.0, cap_hz=10.0)[0] == 10.0


def test_lever_arm_of_a_rotation_about_one_axis_is_refused_not_a_crash():
    """A truth turning about the vertical only (a vehicle) cannot identify the lever arm's height."""
    tr = _oracle(4, duration_s=60.0)
    t = tr.truth.t_s
    yaw = 0.5 * np.sin(2 * np.pi * 0.3 * t)
    quat = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], axis=1)
    omega = np.stack([0 * t, 0 * t, np.gradient(yaw, t)], axis=1)
    one_axis = Trace(truth=Truth(t_s=t, pos_enu_m=tr.truth.pos_enu_m, vel_enu_mps=tr.truth.vel_enu_mps,
                                 quat_wxyz=quat, omega_body_radps=omega),
                     imu=tr.imu, uwb=tr.uwb, anchors=tr.anchors, meta={})
    with pytest.raises(CalibrationError, match="too few axes"):
        fit_lever_arm([one_axis], 10.0, 0.0)
    fit = fit_imu(one_axis)  # the default tries the lever arm and leaves it out
    assert fit.params.lever_arm_m == [0.0, 0.0, 0.0]


BROAD = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad-imu" / "data_mat"


@pytest.mark.skipif(not BROAD.is_dir(), reason="needs ../shared/data/broad-imu")
def test_broad_default_widens_the_band_and_predicts_a_left_out_trial_better():
    from physynth.io.importers import import_broad

    trials = {f.stem[:2]: import_broad(f)[0] for f in sorted(BROAD.glob("1*_undisturbed_*.mat"))
              + sorted(BROAD.glob("2*_undisturbed_*.mat"))}
    assert set(trials) == {"10", "15", "21"}
    train = [trials["15"], trials["21"]]
    new = fit_imu(train)
    old = fit_imu(train, cutoff_hz=10.0, lever_arm=False)
    band = new.diagnostics["truth_bandwidth"]["bandwidth_hz"]
    assert 11.0 <= band <= 16.0  # the optical truth follows the IMU to 12-14 Hz on these trials
    assert new.params.truth_cutoff_hz == pytest.approx(band, rel=1e-3)
    assert 5e-3 < new.params.lever_arm_m[2] < 15e-3  # the sensor sits ~1 cm above the optical origin
    worst = {}
    for name, fit in (("new", new), ("old", old)):
        r = compare_imu_along_truth(trials["10"], fit.params, 10.0, rng=np.random.default_rng(1))
        worst[name] = float(np.max(np.abs(r["std_synth"] / r["std_real"] - 1.0)))
    # measured: 0.44 against 0.69 (the slow trial's vertical axis); per-axis std over 30,000 samples
    # of correlated error moves by a few per cent between seeds
    assert worst["new"] < worst["old"] - 0.1, worst
