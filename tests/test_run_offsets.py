"""Run-to-run ranging offsets: REML of the two spreads with known, unequal sampling variances.

Tables of per-run mean LOS residuals d_ra = mu_a + u_r + e_ra + eps_ra are drawn with known spreads
and per-cell sampling variances that differ by a factor 30 between anchors (an anchor with few rows
or many misclassified NLOS rows); the REML estimates must recover the spreads within the standard
errors their degrees of freedom give, and find no spread (likelihood ratio below the threshold) when
there is none.
"""

from __future__ import annotations

import numpy as np
import pytest

from physynth.calibrate.run_spread import RUN_OFFSET_LR_MIN, reml_two_way

N_RUNS, N_ANCHORS = 20, 6
V_ANCHOR = np.array([30.0, 1.0, 1.0, 1.0, 1.0, 1.0]) * 1e-4  # sampling variance of a cell [m^2], per anchor


def table(seed: int, s_run: float, s_anchor: float) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    run = np.repeat(np.arange(N_RUNS), N_ANCHORS)
    anchor = np.tile(np.arange(N_ANCHORS), N_RUNS)
    v = V_ANCHOR[anchor]
    mu = rng.normal(0.0, 0.1, N_ANCHORS)
    y = (mu[anchor] + rng.normal(0.0, s_run, N_RUNS)[run] + rng.normal(0.0, s_anchor, run.size)
         + rng.normal(0.0, np.sqrt(v)))
    return y, anchor, run, v


def test_spreads_are_recovered():
    s_run, s_anchor = 0.03, 0.02
    y, anchor, run, v = table(1, s_run, s_anchor)
    var_r, var_e, blup, prof = reml_two_way(y, anchor, run, v)
    # s.e. of a variance from k degrees of freedom: sqrt(2 / k) x (variance + the noise it is seen through)
    se_r = np.sqrt(2.0 / (N_RUNS - 1)) * (s_run**2 + (s_anchor**2 + np.mean(v)) / N_ANCHORS)
    se_e = np.sqrt(2.0 / ((N_RUNS - 1) * (N_ANCHORS - 1))) * (s_anchor**2 + np.mean(v))
    assert var_r == pytest.approx(s_run**2, abs=3.0 * se_r)
    assert var_e == pytest.approx(s_anchor**2, abs=3.0 * se_e)
    assert 2.0 * (prof[0] - prof[3]) > RUN_OFFSET_LR_MIN
    assert blup.shape == y.shape


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_no_spread_found_where_there_is_none(seed):
    y, anchor, run, v = table(seed, 0.0, 0.0)
    var_r, var_e, _, prof = reml_two_way(y, anchor, run, v)
    assert 2.0 * (prof[0] - prof[3]) < RUN_OFFSET_LR_MIN
    assert np.sqrt(var_e) < 0.01 and np.sqrt(var_r) < 0.01
