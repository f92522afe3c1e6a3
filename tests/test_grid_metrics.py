"""The 100 Hz grid, AoI and the section-5 metrics on hand-built traces with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from physynth.evaluate.grid import make_grid
from physynth.evaluate.metrics import (
    compute_metrics,
    fidelity_score,
    ks_statistic,
    relative_deviation_pct,
    residuals,
)
from physynth.records import Anchors, Imu, Trace, Truth, Uwb


def _trace(uwb_t, uwb_anchor, uwb_range, duration=2.0, imu=None):
    t = np.arange(0, duration + 1e-9, 0.01)
    pos = np.stack([t, np.zeros_like(t), np.zeros_like(t)], axis=1)  # 1 m/s along east
    vel = np.tile([1.0, 0.0, 0.0], (t.size, 1))
    return Trace(truth=Truth(t_s=t, pos_enu_m=pos, vel_enu_mps=vel),
                 uwb=Uwb(t_s=np.asarray(uwb_t, float), anchor=np.asarray(uwb_anchor),
                         range_m=np.asarray(uwb_range, float)),
                 anchors=Anchors(ids=("A", "B"), pos_enu_m=[[0, 10, 0], [0, -10, 0]]), imu=imu)


def test_aoi_resets_to_zero_at_a_fresh_measurement_and_grows_with_slope_one():
    tr = _trace([0.50, 1.20], [0, 0], [10.0, 10.0])
    g = make_grid(tr)
    k050, k120 = 50, 120
    assert g.t_s[k050] == pytest.approx(0.5)
    assert g.aoi_s[k050, 0] == pytest.approx(0.0, abs=1e-9)
    assert g.aoi_s[k120, 0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(np.diff(g.aoi_s[k050:k120, 0]), 0.01, atol=1e-9)
    # before the first measurement AoI counts from the trace start; anchor B never heard
    np.testing.assert_allclose(g.aoi_s[:k050, 0], g.t_s[:k050], atol=1e-9)
    np.testing.assert_allclose(g.aoi_s[:, 1], g.t_s, atol=1e-9)


def test_fresh_bins_are_half_open_on_the_left():
    # 0.505 lies in bin (0.50, 0.51] -> k = 51; 0.51 exactly also in k = 51; 0.5 exactly in k = 50
    tr = _trace([0.5, 0.505, 0.51], [0, 1, 1], [10.0, 10.0, 10.0])
    g = make_grid(tr)
    assert g.fresh[50, 0] and not g.fresh[51, 0]
    assert g.fresh[51, 1] and not g.fresh[50, 1]


def test_availability_fractions_and_nan_ranges():
    # anchor A at 0.10 and 0.20, B at 0.10 (same bin) and 0.30; a NaN range does not count
    tr = _trace([0.10, 0.10, 0.20, 0.30, 0.40], [0, 1, 0, 1, 0], [10, 10, 10, 10, np.nan], duration=1.0)
    m = compute_metrics([tr])
    n_bins = 101
    assert m.uwb_ge1_frac == pytest.approx(3 / n_bins)
    assert m.uwb_ge2_frac == pytest.approx(1 / n_bins)
    assert m.per_anchor["A"]["n_ranges"] == 2


def test_residuals_use_truth_interpolated_at_measurement_time():
    # tag at (t, 0, 0); anchor A at (0, 10, 0): |p - a| = sqrt(t^2 + 100)
    t = np.array([0.123, 0.777, 1.5])
    true = np.sqrt(t**2 + 100)
    tr = _trace(t, [0, 0, 0], true + np.array([0.1, -0.2, 0.3]))
    r, idx, _ = residuals(tr)
    np.testing.assert_allclose(r, [0.1, -0.2, 0.3], atol=1e-9)
    m = compute_metrics([tr])
    assert m.residual_median_m == pytest.approx(0.1)
    assert m.residual_std_m == pytest.approx(np.std([0.1, -0.2, 0.3]))
    assert m.abs_residual_p95_m == pytest.approx(np.percentile([0.1, 0.2, 0.3], 95))


def test_mean_aoi_pools_anchors_and_steps():
    tr = _trace([], [], [], duration=1.0)
    m = compute_metrics([tr])
    assert m.mean_aoi_s == pytest.approx(0.5)  # t - t0 averaged over 0..1 s, both anchors never heard


def test_imu_std_is_taken_on_the_grid_bin_means():
    rng = np.random.default_rng(0)
    t = np.arange(0, 100.0, 1 / 400)
    acc = rng.standard_normal((t.size, 3)) * [3.22, 1.72, 2.12]
    tr = _trace([], [], [], duration=100.0, imu=Imu(t_s=t, acc_mps2=acc))
    m = compute_metrics([tr])
    # bins (t_k - 10 ms, t_k]: 4 samples each -> std / 2
    np.testing.assert_allclose(m.imu_std_mps2, [1.61, 0.86, 1.06], rtol=0.02)


def test_ks_deviation_and_fidelity_helpers():
    a = np.random.default_rng(1).normal(0, 1, 500)
    b = np.random.default_rng(2).normal(0.5, 1, 500)
    assert ks_statistic(a, a) == 0.0
    assert ks_statistic(a, b) == pytest.approx(stats.ks_2samp(a, b).statistic)
    assert relative_deviation_pct(2.0, 3.0) == pytest.approx(50.0)
    tr = _trace([0.1], [0], [10.5])
    m = compute_metrics([tr])
    assert fidelity_score(m, m) == 0.0
