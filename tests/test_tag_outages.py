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

from physynth.calibrate import tag_outages as tag_fit
from physynth.calibrate.attempts import AttemptTable
from physynth.calibrate.availability_fit import fit_outages
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


def _one_dark_run(heard_until: int, b_back: int, n: int = 600) -> tuple:
    """Two anchors on a burst grid, both heard up to ``heard_until`` - 1; anchor A0 then stays silent
    to the end, anchor A1 is heard again from ``b_back`` on: one dark run [heard_until, b_back)."""
    heard = np.zeros((n, 2), dtype=bool)
    heard[:heard_until] = True
    heard[b_back:, 1] = True
    tab = AttemptTable(t_s=np.arange(n) / RATE_HZ, attempted=np.ones_like(heard), heard=heard, recorded=True,
                       burst_rate_hz=RATE_HZ)
    ok = np.ones_like(heard)
    dark = [tag_fit.dark_runs(tab, ok)]
    seqs = tag_fit.anchor_sequences([["A0", "A1"]], [tab], [ok])
    cand = [(dark[0][1] - dark[0][0]) >= RATE_HZ - 1e-9]
    pos = [tag_fit.boundary_positions(dark[0][0][cand[0]], dark[0][1][cand[0]], int(np.ceil(RATE_HZ - 1e-9)))]
    return [tab], dark, cand, pos, seqs, [np.zeros(n, dtype=bool)]


def _tag_length(chain: tuple[float, float, float], heard_until: int = 100, b_back: int = 400) -> tuple[float, float]:
    tabs, dark, cand, pos, seqs, masks = _one_dark_run(heard_until, b_back)
    tag_chain = tag_fit.from_rates(TRUE["tag_outage_onset_prob"] * RATE_HZ, TRUE["tag_outage_mean_s"], 1 / RATE_HZ)
    odds, lengths = tag_fit.tag_e_step(tabs, dark, cand, pos, seqs, masks, {"A0": chain, "A1": chain}, tag_chain)
    return float(odds[0][0]), float(lengths[0][0])


def test_tag_outage_may_end_inside_the_dark_run():
    # a 300-burst dark run: with anchors that never fail on their own (dropouts of 1e-6 only), the tag
    # outage must cover the whole run; with anchors that are often out for long, part of the run is
    # likely the anchors' own outages, and the expected tag length is shorter than the run
    sturdy = (0.0, 1.0, 1e-6)
    _, length_sturdy = _tag_length(sturdy)
    assert length_sturdy == pytest.approx(300.0, abs=0.01)
    alpha, beta = tag_fit.from_rates(TRUE["outage_onset_prob"] * RATE_HZ, TRUE["outage_mean_s"], 1 / RATE_HZ)
    _, length_frail = _tag_length((alpha, beta, TRUE["dropout_prob"]))
    assert 23 <= length_frail < 290  # at least the minimum length (1 s), clearly shorter than the run


def test_tag_posterior_sums_over_every_placement():
    # the log-odds are a log-sum over placements: a run exactly as long as the minimum has one
    # placement, and a longer run's log-odds exceed those of its single whole-run placement
    alpha, beta = tag_fit.from_rates(TRUE["outage_onset_prob"] * RATE_HZ, TRUE["outage_mean_s"], 1 / RATE_HZ)
    chain = (alpha, beta, TRUE["dropout_prob"])
    tag_chain = tag_fit.from_rates(TRUE["tag_outage_onset_prob"] * RATE_HZ, TRUE["tag_outage_mean_s"], 1 / RATE_HZ)
    tabs, dark, cand, pos, seqs, masks = _one_dark_run(100, 400)
    s, e = dark[0][0][cand[0]], dark[0][1][cand[0]]
    whole_only = tag_fit.boundary_positions(s, e, int(e[0] - s[0]))  # the single placement [s, e)
    odds_whole, len_whole = tag_fit.tag_e_step(tabs, dark, cand, [whole_only], seqs, masks,
                                               {"A0": chain, "A1": chain}, tag_chain)
    odds_all, _ = tag_fit.tag_e_step(tabs, dark, cand, pos, seqs, masks, {"A0": chain, "A1": chain}, tag_chain)
    assert len_whole[0][0] == pytest.approx(300.0)
    assert odds_all[0][0] > odds_whole[0][0] + 1e-3
    # the single placement is the old whole-run formula: tag chain plus each anchor's split run
    nb = [tag_fit.run_neighbours(sq, s, e, masks[0]) for sq in seqs]
    ll1 = sum(tag_fit.split_logp(chain, x["left_heard"], x["ps"] - x["prev"] - 1, "left")
              + tag_fit.split_logp(chain, x["right_heard"], x["nxt"] - x["pe"], "right") for x in nb)
    ll0 = sum(tag_fit.whole_logp(chain, x["left_heard"], x["right_heard"], x["nxt"] - x["prev"] - 1) for x in nb)
    expect = tag_fit.tag_log_odds(s, e, 600, *tag_chain) + ll1 - ll0
    assert odds_whole[0][0] == pytest.approx(float(expect[0]), rel=1e-9)


def test_tag_m_step_counts_an_outage_under_way_at_the_start_as_ended_not_begun():
    # pure tag outages on many short traces (100 s each, the tag out at the start with its stationary
    # probability, ~22 %): every stretch counts as exposure, every end seen inside a trace as an event,
    # every start seen inside a trace as an onset. Taking the outages under way at the start as never
    # ending overestimated the mean by about 30 % at this trace length
    from physynth.models.availability import outage_mask

    rng = np.random.default_rng(11)
    n_traces, nb = 2000, int(100.0 * RATE_HZ)
    t = np.arange(nb) / RATE_HZ
    tabs, dark, w = [], [], []
    empty = np.zeros((nb, 1), dtype=bool)
    for _ in range(n_traces):
        out = outage_mask(t, TRUE["tag_outage_onset_prob"], RATE_HZ, TRUE["tag_outage_mean_s"],
                          start_stationary=True, rng=rng)
        x = np.diff(np.concatenate([[0], out.astype(np.int8), [0]]))
        s, e = np.flatnonzero(x == 1), np.flatnonzero(x == -1)
        keep = (e - s) >= RATE_HZ  # the candidates: at least 1 s
        s, e = s[keep], e[keep]
        tabs.append(AttemptTable(t_s=t, attempted=empty, heard=empty, recorded=True, burst_rate_hz=RATE_HZ))
        dark.append((s, e, (s == 0) | (e == nb)))
        w.append(np.ones(s.size))
    tag = tag_fit.tag_m_step(tabs, dark, w, 1.0 / RATE_HZ)
    n_end = sum(int(np.sum(e < nb)) for _, e, _ in dark)
    assert n_end > 1000
    # relative standard errors 1 / sqrt(events); K of them
    assert tag["mean_s"] == pytest.approx(TRUE["tag_outage_mean_s"], rel=K / np.sqrt(n_end))
    assert tag["onset_prob"] == pytest.approx(TRUE["tag_outage_onset_prob"], rel=K / np.sqrt(tag["events"]))
