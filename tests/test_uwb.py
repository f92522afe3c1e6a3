"""UWB ranging and availability models against their analytic laws."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import binomial_tol, simple_scenario

from physynth.generate import compile_scenario, generate_trace
from physynth.models.availability import alternating_renewal, outage_mask, stationary_availability
from physynth.records import Reason


def _traces(scn, n, seed=1):
    cs = compile_scenario(scn)
    return [generate_trace(cs, i, seed) for i in range(n)]


def test_noiseless_range_is_the_distance_to_the_anchor():
    tr = _traces(simple_scenario(), 1)[0]
    u = tr.uwb
    assert np.all(u.reason == Reason.OK) and np.all(np.isfinite(u.range_m))
    # independent oracle: truth interpolated at the stamp times, Euclidean distance to the anchor
    pos = tr.truth.position_at(u.t_s)
    dist = np.sqrt(((pos - tr.anchors.pos_enu_m[u.anchor]) ** 2).sum(axis=1))
    np.testing.assert_allclose(u.range_m, dist, atol=1e-6)
    np.testing.assert_allclose(u.true_range_m, dist, atol=1e-6)


def test_burst_schedule_and_effective_rate():
    scn = simple_scenario(**{"uwb.burst_rate_hz": 23.0, "uwb.burst_jitter_s": 0.002, "channel.rate_hz": 18.0})
    tr = _traces(scn, 1)[0]
    u = tr.uwb
    span = tr.duration_s
    n_bursts = np.unique(u.burst).size
    # every burst with at least one attempt is seen; with 3 anchors at 18/23 that is all but (5/23)^3
    assert n_bursts / span == pytest.approx(23.0 * (1 - (5 / 23) ** 3), rel=0.03)
    for i in range(3):
        n_i = np.count_nonzero(u.anchor == i)
        assert n_i / span == pytest.approx(18.0, rel=binomial_tol(18 / 23, int(23 * span)) / (18 / 23) + 0.01)
    assert np.all(np.diff(u.t_s) >= 0)


def test_los_errors_are_gaussian_with_the_set_mean_and_std():
    scn = simple_scenario(**{"channel.los_mean_m": 0.12, "channel.los_std_m": 0.08})
    trs = _traces(scn, 4)
    err = np.concatenate([t.uwb.range_m - t.uwb.true_range_m for t in trs])
    n = err.size
    assert err.mean() == pytest.approx(0.12, abs=5 * 0.08 / np.sqrt(n))
    assert err.std() == pytest.approx(0.08, rel=5 * np.sqrt(1 / (2 * n)))


def test_range_proportional_bias():
    scn = simple_scenario(**{"channel.range_bias_per_m": 0.004, "channel.los_std_m": 0.01})
    u = _traces(scn, 2)[0].uwb
    slope = np.polyfit(u.true_range_m, u.range_m - u.true_range_m, 1)[0]
    assert slope == pytest.approx(0.004, abs=5e-4)


def test_nlos_fraction_and_bimodal_offsets():
    modes = [{"weight": 0.3, "mean_m": 2.0, "std_m": 0.2}, {"weight": 0.7, "mean_m": 15.0, "std_m": 0.5}]
    scn = simple_scenario(**{"channel.nlos_prob": 0.25, "channel.nlos_modes": modes, "uwb.nlos_dwell_s": 0.3})
    trs = _traces(scn, 10)
    nlos = np.concatenate([t.uwb.nlos for t in trs])
    err = np.concatenate([t.uwb.range_m - t.uwb.true_range_m for t in trs])
    duration = sum(t.duration_s for t in trs) * 3  # anchor-seconds
    # NLOS episodes are correlated: the effective number of samples is the number of episodes
    n_episodes = duration * 0.25 / 0.3
    assert nlos.mean() == pytest.approx(0.25, abs=5 * np.sqrt(0.25 * 0.75 / n_episodes))
    e = err[nlos]
    high = e > 8.0
    assert high.mean() == pytest.approx(0.7, abs=binomial_tol(0.7, e.size))
    assert e[high].mean() == pytest.approx(15.0, abs=5 * 0.5 / np.sqrt(high.sum()))
    assert e[~high].mean() == pytest.approx(2.0, abs=5 * 0.2 / np.sqrt((~high).sum()))
    assert np.all(np.abs(err[~nlos]) < 1e-6)
    # NLOS comes in bursts: the chance that the next attempt of an anchor is NLOS too is far above p
    u = trs[0].uwb
    a0 = u.nlos[u.anchor == 0]
    stay = np.mean(a0[1:][a0[:-1]])
    assert stay > 0.6


def test_nlos_zone_raises_nlos_probability_near_the_pylon():
    zone = [{"s_m": 150.0, "half_width_m": 20.0, "nlos_prob": 0.8}]
    scn = simple_scenario(**{"uwb.zones": zone, "channel.nlos_modes": [{"weight": 1, "mean_m": 5, "std_m": 1}]})
    trs = _traces(scn, 3)
    inside, outside = [], []
    for t in trs:
        # path coordinate s of the straight-ish walk: distance travelled along the truth
        seg = np.linalg.norm(np.diff(t.truth.pos_enu_m, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        s_at = np.interp(t.uwb.t_s, t.truth.t_s, s)
        inside.append(t.uwb.nlos[np.abs(s_at - 150.0) < 18.0])
        outside.append(t.uwb.nlos[np.abs(s_at - 150.0) > 22.0])
    inside, outside = np.concatenate(inside), np.concatenate(outside)
    assert inside.mean() == pytest.approx(0.8, abs=binomial_tol(0.8, inside.size))
    assert outside.mean() == 0.0


def test_dropout_fraction():
    scn = simple_scenario(**{"availability.dropout_prob": 0.04})
    reason = np.concatenate([t.uwb.reason for t in _traces(scn, 8)])
    frac = np.mean(reason == Reason.DROPOUT)
    assert frac == pytest.approx(0.04, abs=binomial_tol(0.04, reason.size))
    assert set(np.unique(reason)) <= {Reason.OK, Reason.DROPOUT}


def test_link_model_silences_far_anchors():
    scn = simple_scenario(**{"channel.max_range_m": 60.0, "channel.edge_width_m": 1.0})
    u = _traces(scn, 2)[0].uwb
    far, near = u.true_range_m > 70.0, u.true_range_m < 50.0
    assert np.all(u.reason[far] == Reason.NO_LINK) and np.all(np.isnan(u.range_m[far]))
    assert np.all(u.reason[near] == Reason.OK)


def test_outage_durations_are_exponential_with_the_set_mean():
    rng = np.random.default_rng(11)
    rate, p_o, mean_s = 23.0, 0.003, 16.0
    t = np.arange(0, 200_000.0, 1 / rate)
    out = outage_mask(t, p_o, rate, mean_s, start_stationary=True, rng=rng)
    edges = np.flatnonzero(np.diff(out.astype(np.int8)))
    starts, ends = edges[out[edges + 1]] + 1, edges[~out[edges + 1]] + 1
    if ends.size and starts.size and ends[0] < starts[0]:
        ends = ends[1:]
    m = min(starts.size, ends.size)
    durations = (ends[:m] - starts[:m]) / rate
    n = durations.size
    assert durations.mean() == pytest.approx(mean_s, rel=5 / np.sqrt(n))
    assert np.std(durations) == pytest.approx(mean_s, rel=8 / np.sqrt(n))  # exponential: std = mean
    # onset: outages start at p_o per burst of up time
    up_bursts = np.count_nonzero(~out)
    assert n / up_bursts == pytest.approx(p_o, rel=5 / np.sqrt(n))
    assert np.mean(~out) == pytest.approx(stationary_availability(p_o, rate, mean_s), abs=0.02)


def test_outage_rows_keep_their_reason_and_a_nan_range():
    scn = simple_scenario(**{"availability.outage_onset_prob": 0.01, "availability.outage_mean_s": 5.0})
    u = _traces(scn, 2)[0].uwb
    out = u.reason == Reason.OUTAGE
    assert out.any() and np.all(np.isnan(u.range_m[out])) and np.all(np.isfinite(u.true_range_m[out]))


def test_tag_outage_silences_every_anchor_at_once():
    scn = simple_scenario(**{"availability.tag_outage_onset_prob": 0.01, "availability.tag_outage_mean_s": 4.0})
    u = _traces(scn, 1, seed=3)[0].uwb
    out_bursts = np.unique(u.burst[u.reason == Reason.OUTAGE])
    assert out_bursts.size > 0
    in_out = np.isin(u.burst, out_bursts)
    assert np.all(u.reason[in_out] == Reason.OUTAGE)


def test_alternating_renewal_long_run_fraction():
    rng = np.random.default_rng(5)
    t = np.linspace(0, 50_000, 500_001)
    on = alternating_renewal(t, 3.0, 1.0, start_on_prob=0.75, rng=rng)
    n_cycles = 50_000 / 4.0
    assert on.mean() == pytest.approx(0.75, abs=5 * np.sqrt(0.75 * 0.25 / n_cycles))
    with pytest.raises(ValueError):
        alternating_renewal(t, 0.0, 1.0, start_on_prob=0.5, rng=rng)


def test_nlos_episode_keeps_its_mode_and_modes_have_their_own_dwell():
    modes = [{"weight": 0.5, "mean_m": 2.0, "std_m": 0.2, "dwell_s": 2.0},
             {"weight": 0.5, "mean_m": 15.0, "std_m": 0.5, "dwell_s": 0.2}]
    scn = simple_scenario(**{"channel.nlos_prob": 0.3, "channel.nlos_modes": modes})
    trs = _traces(scn, 10)
    runs = {True: [], False: []}
    n_pairs = n_switch = 0
    for t in trs:
        u = t.uwb
        for i in range(3):
            rows = u.anchor == i
            e = (u.range_m - u.true_range_m)[rows]
            nl = u.nlos[rows]
            high = e > 8.0
            # consecutive NLOS rows switch reflector only where two episodes touch between attempts
            both = nl[1:] & nl[:-1]
            n_pairs += int(both.sum())
            n_switch += int(np.sum(high[1:][both] != high[:-1][both]))
            # episode lengths per mode
            x = np.concatenate([[0], nl.astype(np.int8), [0]])
            starts, ends = np.flatnonzero(np.diff(x) == 1), np.flatnonzero(np.diff(x) == -1)
            for a, b in zip(starts, ends, strict=True):
                runs[bool(high[a])].append((b - a) / 20.0)  # 20 attempts per second
    assert n_switch / n_pairs < 0.05  # modes drawn per row would switch in about half of the pairs
    long_mode, short_mode = np.mean(runs[False]), np.mean(runs[True])
    # a geometric run of mean dwell * rate samples: ~2.0 s and ~0.2 s (+ one sample of discretisation)
    assert long_mode == pytest.approx(2.0, rel=5 / np.sqrt(len(runs[False])))
    assert short_mode < 0.35
    # weights are shares of NLOS time: both modes hold about half of the NLOS rows
    e_all = np.concatenate([(t.uwb.range_m - t.uwb.true_range_m)[t.uwb.nlos] for t in trs])
    assert np.mean(e_all > 8.0) == pytest.approx(0.5, abs=0.1)


def test_fixed_hold_episodes_repeat_one_wrong_range():
    # a wrong range the radio repeats for exactly 3 bursts (0.15 s at 20 Hz), the offset held with 1 cm jitter
    modes = [{"weight": 1.0, "mean_m": -5.0, "std_m": 2.0, "dwell_s": 0.15, "fixed_dwell": True,
              "held_jitter_m": 0.01}]
    scn = simple_scenario(**{"channel.nlos_prob": 0.02, "channel.nlos_modes": modes})
    trs = _traces(scn, 6)
    lengths, within, between = [], [], []
    for t in trs:
        u = t.uwb
        for i in range(3):
            rows = u.anchor == i
            e, nl = (u.range_m - u.true_range_m)[rows], u.nlos[rows]
            x = np.concatenate([[0], nl.astype(np.int8), [0]])
            starts, ends = np.flatnonzero(np.diff(x) == 1), np.flatnonzero(np.diff(x) == -1)
            for a, b in zip(starts, ends, strict=True):
                lengths.append(b - a)
                if b - a == 3:  # one episode (not two touching)
                    within.append(e[a:b] - e[a:b].mean())
                    between.append(e[a])
    lengths = np.array(lengths)
    # exactly 3 attempts of a 20 Hz lattice fall in a 0.15 s window (two episodes may touch: 6)
    assert np.mean(lengths == 3) > 0.95 and set(np.unique(lengths)) <= {3, 6}
    w = np.concatenate(within)
    dof = w.size - len(within)
    assert np.sqrt(np.sum(w**2) / dof) == pytest.approx(0.01, rel=5 / np.sqrt(2 * dof))
    assert np.std(between) == pytest.approx(2.0, rel=5 / np.sqrt(2 * len(between)))


def test_run_offsets_are_drawn_per_trace_and_leave_other_scenarios_unchanged():
    base = simple_scenario(**{"channel.los_std_m": 0.01})
    spread = simple_scenario(**{"channel.los_std_m": 0.01, "uwb.run_offset_std_m": 0.05,
                                "uwb.run_anchor_offset_std_m": 0.03})
    a, b = _traces(base, 40), _traces(spread, 40)
    off = np.array([[np.mean((t.uwb.range_m - t.uwb.true_range_m)[t.uwb.anchor == i]) for i in range(3)]
                    for t in b])  # (traces, anchors); the within-trace mean removes the 1 cm noise
    n = off.shape[0]
    common = off.mean(axis=1)
    assert np.std(common, ddof=1) == pytest.approx(np.hypot(0.05, 0.03 / np.sqrt(3)), rel=5 / np.sqrt(2 * n))
    rem = off - common[:, None]
    assert np.sqrt(np.sum(rem**2) / (n * 2)) == pytest.approx(0.03, rel=5 / np.sqrt(2 * n * 2))
    # the offsets are drawn after everything else: times, anchors and NLOS states are those of the base
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.uwb.t_s, y.uwb.t_s)
        np.testing.assert_array_equal(x.uwb.anchor, y.uwb.anchor)
        d = y.uwb.range_m - x.uwb.range_m
        for i in range(3):
            np.testing.assert_allclose(d[y.uwb.anchor == i], d[y.uwb.anchor == i][0], atol=1e-9)


def test_gamma_rate_posterior_against_scipy_and_its_prior():
    from scipy import stats

    from physynth.models.availability import RATE_PRIOR_SHAPE, gamma_rate_posterior

    post = gamma_rate_posterior(events=1, exposure_s=250.0)
    assert post.mean_per_s == pytest.approx((1 + RATE_PRIOR_SHAPE) / 250.0)
    lo, hi = post.interval_per_s()
    assert stats.gamma.cdf(lo, a=1.5, scale=1 / 250.0) == pytest.approx(0.05)
    assert stats.gamma.cdf(hi, a=1.5, scale=1 / 250.0) == pytest.approx(0.95)
    assert lo < 1 / 250.0 < hi  # one event in 250 s: the naive rate lies inside a wide interval
    with pytest.raises(ValueError):
        gamma_rate_posterior(events=-1, exposure_s=1.0)


def test_tag_outage_rate_drawn_per_trace_from_its_gamma_law():
    # shape 1.5 (one event + the Jeffreys half): per-trace rates scatter as Gamma(1.5), mean kept
    kw = {"availability.tag_outage_onset_prob": 0.004, "availability.tag_outage_mean_s": 2.0}
    fixed = _traces(simple_scenario(**kw), 30, seed=4)
    drawn = _traces(simple_scenario(**kw, **{"availability.tag_outage_onset_shape": 1.5}), 30, seed=4)

    def n_outages(t):
        out = np.zeros(t.uwb.burst.max() + 1, dtype=np.int8)
        out[t.uwb.burst[t.uwb.reason == Reason.OUTAGE]] = 1
        return int(np.sum(np.diff(out) == 1) + out[0])

    nf = np.array([n_outages(t) for t in fixed])
    nd = np.array([n_outages(t) for t in drawn])
    # fixed rate: Poisson counts (variance = mean); drawn rate: negative binomial, variance mean + mean^2 / 1.5
    m = nf.mean()
    assert nf.var(ddof=1) < 2.5 * m
    assert nd.var(ddof=1) > 1.5 * m
    assert nd.mean() == pytest.approx(m, abs=5 * np.sqrt((m + m * m / 1.5) / nd.size))
    # without a shape nothing is drawn: the trace equals the one of a scenario that never had the field
    np.testing.assert_array_equal(fixed[0].uwb.reason, _traces(simple_scenario(**kw), 1, seed=4)[0].uwb.reason)


def test_nlos_states_equal_the_anchors_episodes_one_after_another():
    """nlos_states (all anchors' episode states at once) is nlos_episodes anchor by anchor, with the
    episode ids numbered on over the anchors, the same draws in the same order; zones off."""
    from dataclasses import replace

    from physynth.models.renewal import rows_by_label
    from physynth.models.uwb import nlos_episodes, nlos_states

    cs = compile_scenario(simple_scenario())
    a = cs.channel.nlos_prob.shape[0]
    ch = replace(cs.channel, zone_s_m=np.zeros(0), zone_half_width_m=np.zeros(0), zone_nlos_prob=np.zeros(0),
                 nlos_prob=np.linspace(0.05, 0.6, a), mode_fixed_dwell=np.ones_like(cs.channel.mode_fixed_dwell))
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 300.0, 4000))
    anchor = rng.integers(0, a, t.size)
    got = nlos_states(t, anchor, np.zeros(t.size), ch, rng=np.random.default_rng(5))
    ref = [np.zeros(t.size, bool), np.full(t.size, -1), np.full(t.size, -1)]
    base, ref_rng = 0, np.random.default_rng(5)
    weights = np.diff(ch.mode_cumw, axis=1, prepend=0.0)
    for i, rows in enumerate(rows_by_label(anchor, a)):
        one = nlos_episodes(t[rows], ch.nlos_prob[i], weights[i], ch.mode_dwell_s[i], rng=ref_rng,
                            fixed_dwell=ch.mode_fixed_dwell[i], first_episode=base)
        for column, values in zip(ref, one, strict=True):
            column[rows] = values
        base = max(base, int(one[2].max()) + 1)
    for g, r in zip(got, ref, strict=True):
        np.testing.assert_array_equal(g, r)
    assert got[0].any() and got[2].max() > 10  # several anchors with episodes


def test_zone_prob_near_the_zones_equals_the_full_interpolation():
    """zone_nlos_prob_at (the path coordinate interpolated only near each zone) is the zones' probability
    of numpy.interp at every row, bit for bit: runs forwards and backwards, with stops, zones at the ends
    of the path or beyond it, overlapping zones, a non-monotone path coordinate, unsorted times."""
    from dataclasses import replace

    from physynth.models.uwb.nlos import zone_nlos_prob, zone_nlos_prob_at

    ch0 = compile_scenario(simple_scenario()).channel
    rng = np.random.default_rng(11)
    grid_t = np.arange(2001) / 20.0
    speed = np.clip(rng.normal(1.0, 1.0, grid_t.size), 0.0, None)  # stops (equal path coordinates)
    forwards = np.concatenate([[0.0], np.cumsum(speed[1:])]) * 0.05
    zones = [(np.array([0.0, 3.0, 40.0]), np.array([0.5, 2.0, 9.0]), np.array([0.3, 0.6, 0.2])),
             (np.array([forwards[-1], 20.0, 21.0]), np.array([1.0, 3.0, 0.05]), np.array([0.9, 0.4, 0.7])),
             (np.array([-5.0, 500.0]), np.array([1.0, 1.0]), np.array([0.5, 0.5]))]
    paths = [forwards, forwards[-1] - forwards, 10.0 * np.sin(grid_t / 7.0)]  # the last is not monotone
    for s_grid in paths:
        for z_s, half, prob in zones:
            ch = replace(ch0, zone_s_m=z_s, zone_half_width_m=half, zone_nlos_prob=prob)
            t = np.sort(rng.uniform(-1.0, grid_t[-1] + 1.0, 3000))
            t[100:110] = grid_t[500:510]  # on the knots
            t = np.sort(t)
            want = zone_nlos_prob(np.interp(t, grid_t, s_grid), ch)
            np.testing.assert_array_equal(zone_nlos_prob_at(t, grid_t, s_grid, ch), want)
            np.testing.assert_array_equal(zone_nlos_prob_at(t, grid_t, s_grid, ch, ascending=True), want)
            shuffled = rng.permutation(t)
            np.testing.assert_array_equal(zone_nlos_prob_at(shuffled, grid_t, s_grid, ch),
                                          zone_nlos_prob(np.interp(shuffled, grid_t, s_grid), ch))
