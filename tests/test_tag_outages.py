"""Tag outages told apart from overlapping per-anchor outages (joint fit of the availability processes).

Attempt tables are drawn with the generator's own availability sampler on a burst grid (every anchor
attempted in every burst, all in range), with known per-anchor and tag outage processes whose
outages have similar lengths (16 s and 20 s) and where each anchor is out about half of the time:
the length of an all-anchors-silent run does not say which process made it, only the joint
likelihood does. Tolerances: K standard errors of a rate or an exponential mean estimated from n
events (relative standard error 1 / sqrt(n)), n counted in the drawn data.
"""

from __future__ import annotations

import numpy as np
import pytest

from physynth.calibrate.availability_fit import AttemptTable, fit_outages
from physynth.models.availability import AvailabilityParams, availability_arrays, simulate_availability

RATE_HZ = 23.0
N_ANCHORS = 6
N_TRACES = 12
TRACE_S = 300.0
K = 3.5
TRUE = {"dropout_prob": 0.04, "outage_onset_prob": 0.003, "outage_mean_s": 16.0,
        "tag_outage_onset_prob": 0.0006, "tag_outage_mean_s": 20.0}


def draw_tables(seed: int, **params: float) -> tuple[list[AttemptTable], int]:
    """Attempt tables of N_TRACES traces and the number of tag outages that began in them."""
    rng = np.random.default_rng(seed)
    p = AvailabilityParams(**params)
    av = availability_arrays(p, [p] * N_ANCHORS)
    nb = int(TRACE_S * RATE_HZ)
    bursts = np.arange(nb) / RATE_HZ
    t = np.repeat(bursts, N_ANCHORS)
    anchor = np.tile(np.arange(N_ANCHORS), nb)
    burst = np.repeat(np.arange(nb), N_ANCHORS)
    tabs, n_tag = [], 0
    for _ in range(N_TRACES):
        out, drop = simulate_availability(t, anchor, burst, bursts, av, RATE_HZ, rng=rng)
        out = out.reshape(nb, N_ANCHORS)
        all_out = out.all(axis=1)
        n_tag += int(np.sum(all_out[1:] & ~all_out[:-1]))  # every-anchor outage onsets (an upper bound)
        heard = ~out & ~drop.reshape(nb, N_ANCHORS)
        tabs.append(AttemptTable(t_s=bursts, attempted=np.ones_like(heard), heard=heard, recorded=True,
                                 burst_rate_hz=RATE_HZ))
    return tabs, n_tag


def fit(tabs: list[AttemptTable]):
    ids = [f"A{i}" for i in range(N_ANCHORS)]
    return fit_outages(tabs, [np.ones_like(t.heard) for t in tabs], [ids] * len(tabs), ids,
                       dict.fromkeys(ids, 1.0 / RATE_HZ), RATE_HZ)


@pytest.fixture(scope="module")
def with_tag():
    tabs, _ = draw_tables(5, **TRUE)
    return fit(tabs)


def test_tag_outages_are_recovered(with_tag):
    _, _, tag = with_tag
    n = tag["n_outages"] + tag["n_censored"]
    assert n >= 20  # ~0.0006 x 23 Hz x 2,800 s of tag up time ~ 40 expected
    rel = K / np.sqrt(n)
    assert tag["onset_prob"] == pytest.approx(TRUE["tag_outage_onset_prob"], rel=rel)
    assert tag["mean_s"] == pytest.approx(TRUE["tag_outage_mean_s"], rel=K / np.sqrt(tag["n_outages"]))
    assert tag["lr_statistic"] > 100


def test_per_anchor_outages_are_recovered_beside_the_tag(with_tag):
    _, fits, _ = with_tag
    onset = np.array([f["outage_onset_prob"] for f in fits.values()])
    mean = np.array([f["outage_mean_s"] for f in fits.values()])
    drop = np.array([f["dropout_prob"] for f in fits.values()])
    # per anchor ~ 3,600 s x 0.78 (tag up) / 30.5 s per cycle ~ 90 outages: pooled over six anchors ~ 550
    n = N_ANCHORS * N_TRACES * TRACE_S * 0.78 / (1 / (TRUE["outage_onset_prob"] * RATE_HZ) + TRUE["outage_mean_s"])
    assert onset.mean() == pytest.approx(TRUE["outage_onset_prob"], rel=K / np.sqrt(n))
    assert mean.mean() == pytest.approx(TRUE["outage_mean_s"], rel=K / np.sqrt(n))
    # dropouts: ~ 6 x 12 x 6,900 x 0.4 attempts while up
    n_up = N_ANCHORS * N_TRACES * TRACE_S * RATE_HZ * 0.4
    assert drop.mean() == pytest.approx(TRUE["dropout_prob"], abs=K * np.sqrt(0.04 * 0.96 / n_up))


def test_no_tag_outages_invented():
    # same per-anchor outages, no tag process: every anchor silent at once happens (0.5^6 of the time,
    # runs of seconds), and must be left to the per-anchor outages
    tabs, n_all = draw_tables(6, **{**TRUE, "tag_outage_onset_prob": 0.0})
    assert n_all >= 10  # the data do hold all-anchor silent runs
    _, fits, tag = fit(tabs)
    assert tag["onset_prob"] == 0.0 and tag["n_outages"] == 0
    onset = np.array([f["outage_onset_prob"] for f in fits.values()])
    n = N_ANCHORS * N_TRACES * TRACE_S / (1 / (TRUE["outage_onset_prob"] * RATE_HZ) + TRUE["outage_mean_s"])
    assert onset.mean() == pytest.approx(TRUE["outage_onset_prob"], rel=K / np.sqrt(n))
