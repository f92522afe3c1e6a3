"""Calibration on thin data: an anchor heard over too narrow a span of ranges, and outages that outlast
the recording, give parameters inside their physical bounds (and say so in the report) instead of a
scenario that fails validation."""

from __future__ import annotations

import numpy as np

from physynth.bounds import BOUNDS
from physynth.calibrate.anchor_channels import fit_channels
from physynth.calibrate.dropout_outage import RunStats, add_runs, fit_dropout_outage
from physynth.generate import generate_traces
from physynth.io.scenario_file import load_scenario

PERIOD_S = 0.1


def test_an_outage_that_outlasts_the_recording_gets_the_recorded_span():
    stats = RunStats()
    rng = np.random.default_rng(0)  # with this seed the likelihood's outage mean is infinite
    # run 0 dark from start to end (90 s), run 1 heard throughout (5 % dropouts, 30 s): no outage ever ends
    for code in (np.zeros(900, int), (rng.random(300) > 0.05).astype(int)):
        add_runs(stats, np.arange(code.size) * PERIOD_S, code)
    fit = fit_dropout_outage(stats, PERIOD_S, 1.0 / PERIOD_S)
    span = stats.n_attempts * PERIOD_S
    assert fit["identifiable"] and fit["outage_mean_censored"]
    assert fit["outage_mean_ml_s"] > 1e6  # what the likelihood alone gives (out of bounds, here infinite)
    assert fit["outage_mean_s"] == span and "outlast" in fit["why"]
    b = BOUNDS["availability.outage_mean_s"]
    assert b.lo <= fit["outage_mean_s"] <= b.hi


def test_an_outage_that_ends_keeps_its_maximum_likelihood_length():
    stats = RunStats()
    rng = np.random.default_rng(1)
    for _ in range(4):  # 10 s outages that end, inside 90 s runs
        code = (rng.random(900) > 0.05).astype(int)
        code[300:400] = 0
        add_runs(stats, np.arange(code.size) * PERIOD_S, code)
    fit = fit_dropout_outage(stats, PERIOD_S, 1.0 / PERIOD_S)
    assert fit["identifiable"] and not fit.get("outage_mean_censored")
    assert 5.0 < fit["outage_mean_s"] < 20.0


def test_an_anchor_seen_over_a_narrow_span_gets_the_pooled_slope():
    scn = load_scenario("cablecar-descending")
    traces = list(generate_traces(scn, 2, seed=5))  # A108: dark for all of run 0, heard near one range in run 1
    ids = list(scn.anchor_ids)
    chan = fit_channels(traces, scn.uwb.time_offset_s, ids, None, ["r0", "r1"])
    b = BOUNDS["channel.range_bias_per_decade_m"]
    for aid in ids:
        assert b.lo <= chan.mix[aid].range_bias_per_decade_m <= b.hi, aid
    fallback = [a for a in ids if "slope_out_of_bounds" in chan.mix_diag[a]]
    assert fallback, "the test data no longer has an anchor with an out-of-bounds slope"
    for aid in fallback:
        assert chan.mix[aid].range_bias_per_decade_m == chan.pooled_fit.range_bias_per_decade_m
        assert any(f"channel_per_anchor.{aid} range-bias slope" in n for n in chan.notes)


def test_a_link_heard_less_at_every_range_keeps_a_positive_horizon():
    from physynth.calibrate.availability_fit import fit_link
    from physynth.scenario import ChannelParams

    rng = np.random.default_rng(2)
    r = rng.uniform(50.0, 600.0, 6000)
    # P(heard) falls over every range seen: the unconstrained fit puts the horizon at R < 0
    heard = rng.random(r.size) < 0.9 / (1.0 + np.exp((r + 200.0) / 100.0))  # unconstrained: R = -257 m
    fit = fit_link(r, heard)
    assert fit["identifiable"] and fit["max_range_m"] > 0
    ChannelParams(max_range_m=fit["max_range_m"], edge_width_m=fit["edge_width_m"])  # validates


def test_the_same_recording_twice_is_refused():
    import pytest

    from physynth.calibrate import CalibrationError, calibrate

    trace = next(generate_traces(load_scenario("cablecar-descending"), 1, seed=1))
    with pytest.raises(CalibrationError, match="hold the same recording"):
        calibrate([trace, trace])


def _outage_attempts(rng: np.random.Generator, n_rec: int, n: int, r_of) -> tuple[np.ndarray, np.ndarray]:
    """Attempts of ``n_rec`` recordings of ``n`` each at ranges ``r_of(k)`` (k the attempt index within a
    recording), heard with 0.96 unless in an outage; outages of ~300 attempts cover about half the time."""
    rs, hs = [], []
    for _ in range(n_rec):
        k = np.arange(n)
        state = np.zeros(n, dtype=bool)  # True: in outage
        i = int(rng.integers(0, 300))
        while i < n:  # a few dozen alternations per recording
            length = int(rng.exponential(300.0))
            state[i:i + length] = True
            i += length + int(rng.exponential(300.0))
        rs.append(r_of(k))
        hs.append(~state & (rng.random(n) < 0.96))
    return np.concatenate(rs), np.concatenate(hs)


def test_outages_that_fall_at_long_range_are_not_a_radio_horizon():
    from physynth.calibrate.availability_fit import fit_link

    rng = np.random.default_rng(12)
    n_rec, n = 4, 4000
    r, heard = _outage_attempts(rng, n_rec, n, lambda k: 20.0 + 0.15 * k)  # 20-620 m, no range dependence
    fit = fit_link(r, heard, [n] * n_rec)
    # read as independent attempts, this draw shows a horizon by both criteria: a large LR and enough
    # attempts beyond the edge (outages that happened to come at long range)
    assert fit["lr_statistic"] >= 10.0 and fit["n_attempts_beyond"] >= 30, "pick another seed"
    assert fit["design_effect"] > 10.0
    assert not fit["identifiable"] and "design effect" in fit["why"]
    # a real horizon with the same outages stays identifiable, its edge where it was drawn
    r2, h2 = _outage_attempts(rng, n_rec, n, lambda k: 20.0 + 0.15 * k)  # 20-620 m
    h2 &= rng.random(r2.size) < 1.0 / (1.0 + np.exp((r2 - 400.0) / 10.0))
    real = fit_link(r2, h2, [n] * n_rec)
    assert real["identifiable"], real
    assert abs(real["max_range_m"] - 400.0) < 15.0


def test_lengths_must_cover_the_attempts():
    import pytest

    from physynth.calibrate.availability_fit import fit_link

    with pytest.raises(ValueError, match="lengths"):
        fit_link(np.linspace(1.0, 100.0, 50), np.ones(50, dtype=bool), [20, 20])


def test_a_soft_edge_wider_than_the_ranges_keeps_attempts_in_range():
    from physynth.calibrate.availability_fit import in_range_limit

    link = {"max_range_m": 359.0, "edge_width_m": 92.7}  # its 0.999 point lies at -281 m
    r = np.linspace(50.0, 450.0, 1000)
    assert in_range_limit(link, r) == 359.0 and "in_range_note" in link
    sharp = {"max_range_m": 400.0, "edge_width_m": 5.0}
    assert abs(in_range_limit(sharp, r) - (400.0 - 5.0 * np.log(999.0))) < 1e-9 and "in_range_note" not in sharp
