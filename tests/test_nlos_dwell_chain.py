"""NLOS episode lengths of a mode close to the LOS peak: the LOS / NLOS-mode chain against run lengths.

Rows of one anchor every ~54 ms (18.5 Hz) with NLOS episodes drawn by the generator's own sampler
(:func:`physynth.models.uwb.nlos_episodes`: exponential episodes of mean 0.6 s, 5 % of the time) and
residuals from the cablecar-ascending channel (LOS 0.22 +- 0.30 m, NLOS mode 0.9 +- 0.3 m: 2.3 LOS
sigmas apart). Classified rows cut every episode into fragments; the chain's maximum likelihood
recovers the mean within K relative standard errors (1 / sqrt(n) for n drawn episodes).
"""

from __future__ import annotations

import numpy as np
import pytest

from physynth.calibrate.uwb_fit import MixtureFit, ModeFit, fit_mode_dwell
from physynth.models.uwb import nlos_episodes

K = 3.0
TAU_S, P_NLOS, RATE_HZ, SPAN_S = 0.6, 0.05, 18.5, 2000.0
LOS = (0.22, 0.30)
MODE = (0.9, 0.3)


def mixture() -> MixtureFit:
    return MixtureFit(los_mean_m=LOS[0], range_bias_per_m=0.0, los_std_m=LOS[1], nlos_prob=P_NLOS,
                      modes=(ModeFit(weight=1.0, mean_m=MODE[0], std_m=MODE[1]),), log_likelihood=0.0, bic=0.0,
                      n=0, nlos_resp=np.zeros(0), se={}, converged=True)


@pytest.fixture(scope="module")
def rows():
    rng = np.random.default_rng(7)
    n = int(SPAN_S * RATE_HZ)
    t = np.cumsum(rng.exponential(0.2 / RATE_HZ, n) + 0.8 / RATE_HZ)  # jittered rows, as an anchor's
    nlos, _, episode = nlos_episodes(t, P_NLOS, np.array([1.0]), np.array([TAU_S]), rng=rng)
    r = np.where(nlos, rng.normal(MODE[0], MODE[1], n), rng.normal(LOS[0], LOS[1], n))
    n_episodes = int(np.unique(episode[episode >= 0]).size)
    new_run = np.zeros(n, dtype=bool)
    new_run[0] = True
    return t, r, new_run, n_episodes


def test_chain_recovers_the_episode_length(rows):
    t, r, new_run, n_ep = rows
    assert n_ep > 100
    # run lengths of rows classified NLOS (posterior > 0.5) give a fraction of the true length
    f = mixture()
    post_n = P_NLOS * np.exp(-0.5 * ((r - MODE[0]) / MODE[1]) ** 2)
    post_l = (1 - P_NLOS) * np.exp(-0.5 * ((r - LOS[0]) / LOS[1]) ** 2)
    cls = post_n > post_l
    x = np.diff(np.concatenate([[0], cls.astype(int), [0]]))
    mean_len = float(np.mean(np.flatnonzero(x == -1) - np.flatnonzero(x == 1)))
    period = float(np.mean(np.diff(t)))
    tau_runs = -period / np.log(1.0 - 1.0 / mean_len)
    assert tau_runs < 0.5 * TAU_S
    out = fit_mode_dwell(r, np.zeros_like(r), t, new_run, f, np.array([tau_runs]), np.array([True]))
    assert out["dwell_s"][0] == pytest.approx(TAU_S, rel=K / np.sqrt(n_ep))
    assert out["log_likelihood"] > out["log_likelihood_start"]


def test_fixed_modes_are_held(rows):
    t, r, new_run, _ = rows
    out = fit_mode_dwell(r, np.zeros_like(r), t, new_run, mixture(), np.array([0.25]), np.array([False]))
    assert out["dwell_s"][0] == 0.25
