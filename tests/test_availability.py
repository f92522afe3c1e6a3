"""The availability model on its own: dropout, per-anchor and tag outages, the shared renewal sampler."""

from __future__ import annotations

import numpy as np
import pytest

from physynth.models.availability import (
    AvailabilityParams,
    availability_arrays,
    outage_mask,
    simulate_availability,
    stationary_availability,
)
from physynth.models.renewal import initial_pairs, switch_counts


def _attempts(n_bursts: int, n_anchors: int, rate_hz: float):
    bursts = np.arange(n_bursts) / rate_hz
    burst = np.repeat(np.arange(n_bursts), n_anchors)
    anchor = np.tile(np.arange(n_anchors), n_bursts)
    return bursts[burst] + 0.001 * anchor, anchor, burst, bursts


def test_dropout_is_independent_per_attempt_with_the_set_probability():
    t, anchor, burst, bursts = _attempts(20000, 2, 20.0)
    p = AvailabilityParams(dropout_prob=0.1, outage_onset_prob=0.0)
    av = availability_arrays(p, [p, AvailabilityParams(dropout_prob=0.3, outage_onset_prob=0.0)])
    outage, dropped = simulate_availability(t, anchor, burst, bursts, av, 20.0, rng=np.random.default_rng(1))
    assert not outage.any()
    for i, q in enumerate((0.1, 0.3)):
        frac = dropped[anchor == i].mean()
        assert frac == pytest.approx(q, abs=5 * np.sqrt(q * (1 - q) / 20000))


def test_per_anchor_outages_are_independent_and_tag_outages_hit_every_anchor():
    t, anchor, burst, bursts = _attempts(200000, 3, 20.0)
    p = AvailabilityParams(dropout_prob=0.0, outage_onset_prob=0.002, outage_mean_s=5.0,
                           tag_outage_onset_prob=0.0005, tag_outage_mean_s=8.0)
    av = availability_arrays(p, [p] * 3)
    outage, _ = simulate_availability(t, anchor, burst, bursts, av, 20.0, rng=np.random.default_rng(2))
    per_burst = outage.reshape(-1, 3)
    up_anchor = stationary_availability(0.002, 20.0, 5.0)
    up_tag = stationary_availability(0.0005, 20.0, 8.0)
    assert 1 - per_burst.mean() == pytest.approx(up_anchor * up_tag, abs=0.02)
    all_out = per_burst.all(axis=1).mean()
    # all three out: the tag is out, or all three anchors happen to be out at once
    expected = (1 - up_tag) + up_tag * (1 - up_anchor) ** 3
    assert all_out == pytest.approx(expected, abs=0.01)


def test_no_onset_means_no_outage_and_no_draw():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    assert not outage_mask(np.arange(100.0), 0.0, 20.0, 5.0, start_stationary=True, rng=rng).any()
    assert rng.bit_generator.state == state


def test_switch_counts_doubles_until_the_span_is_covered():
    calls = []

    def draw(n):
        calls.append(n)
        return np.ones((n, 2)), None

    t = np.linspace(0.0, 99.5, 50)
    k, _ = switch_counts(t, draw, initial_pairs(1.0, 2.0))
    assert calls == [9, 18, 36, 72]  # 72 pairs of 1 s cover 100 s, 36 do not
    np.testing.assert_array_equal(k, np.floor(t).astype(int))  # one switch per second, at whole seconds



def test_switch_counts_are_searchsorted_counts():
    """The counts placed by switch (sorted times) equal numpy.searchsorted(switches, t, "right") exactly,
    with ties, times outside the switches, unsorted times and NaN (which take the plain search)."""
    from physynth.models.renewal import count_at_or_before

    rng = np.random.default_rng(3)
    for trial in range(300):
        switches = np.cumsum(rng.exponential(1.0, int(rng.integers(1, 40))))
        t = np.sort(rng.uniform(-2.0, switches[-1] + 2.0, int(rng.integers(1, 200))))
        t[rng.integers(0, t.size, 3)] = rng.choice(switches, 3)  # ties with switch times
        t = np.sort(t)
        if trial % 5 == 1:
            rng.shuffle(t)
        if trial % 7 == 2:
            t[rng.integers(0, t.size)] = np.nan
        got = count_at_or_before(switches, t)
        want = np.searchsorted(switches, t, side="right")
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)



def test_rows_by_label_are_flatnonzero_rows():
    from physynth.models.renewal import rows_by_label

    rng = np.random.default_rng(4)
    cases = [rng.integers(0, 6, 500), np.zeros(0, np.int64), np.array([3, 3, 1]), rng.integers(-1, 4, 50),
             rng.integers(0, 300, 2000).astype(np.int16), np.array([0, 7])]
    for labels in cases:
        for n in (1, 4, 6, 300):
            got = rows_by_label(labels, n)
            assert len(got) == n
            for i, rows in enumerate(got):
                np.testing.assert_array_equal(rows, np.flatnonzero(labels == i))


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError):
        AvailabilityParams(dropout_prob=1.5)
    with pytest.raises(ValueError):
        AvailabilityParams(outage_mean_s=0.0)
