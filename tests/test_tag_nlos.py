"""Tag-side NLOS: one episode process for the whole tag, striking every anchor at once, and its estimate."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import simple_scenario

from physynth.calibrate import calibrate
from physynth.calibrate.tag_nlos import fit_tag_nlos
from physynth.generate import compile_scenario, generate_trace, generate_traces
from physynth.models.uwb.tag_nlos import tag_mode_index, tag_thinning

HANYANG = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"
MODES = [{"weight": 0.2, "mean_m": -6.0, "std_m": 2.0}, {"weight": 0.8, "mean_m": 0.3, "std_m": 0.15}]


def _scenario(p_tag: float, **more):
    return simple_scenario(**{"channel.nlos_prob": 0.1, "channel.nlos_modes": MODES, "channel.los_std_m": 0.02,
                              "uwb.nlos_dwell_s": 0.5, "uwb.tag_nlos_prob": p_tag, "motion.cruise_speed_mps": 1.0,
                              **more})


def test_near_los_mode_is_the_heaviest_within_half_a_metre():
    assert tag_mode_index(np.array([0.2, 0.8]), np.array([-6.0, 0.3]), np.array([2.0, 0.15])) == 1
    assert tag_mode_index(np.array([0.5, 0.3, 0.2]), np.array([-6.0, 0.1, -0.2]), np.array([2.0, 0.2, 0.1])) == 1
    assert tag_mode_index(np.array([1.0]), np.array([-6.0]), np.array([0.3])) == -1  # gross only: no tag mode


def test_thinning_keeps_each_anchors_nlos_fraction_and_mode_shares():
    p = np.array([0.1, 0.05, 0.02, 0.0])
    w = np.array([[0.2, 0.8], [0.5, 0.5], [0.1, 0.9], [0.2, 0.8]])
    mean = np.array([[-6.0, 0.3]] * 4)
    std = np.array([[2.0, 0.15]] * 4)
    out = tag_thinning(0.03, p, np.cumsum(w, axis=1), mean, std)
    t = 0.03 * out["join"]
    near_own = p * w[:, 1] * (1 - out["drop"])  # own near-LOS time left after the drops
    q = p * w[:, 0] + near_own  # own NLOS time: the other mode untouched
    np.testing.assert_allclose(q + (1 - q) * t, p, atol=1e-12)  # NLOS fraction of every anchor
    # time share of each mode: own episodes (which win), plus the tag's where the own process is LOS
    np.testing.assert_allclose(near_own + (1 - q) * t, p * w[:, 1], atol=1e-12)
    np.testing.assert_allclose(out["join"], [1.0, min(1.0, 0.5 * 0.05 / 0.03), 0.9 * 0.02 / 0.03, 0.0])
    assert ((out["drop"] >= 0) & (out["drop"] <= 1)).all() and out["drop"][3] == 0.0


def test_default_draws_nothing_and_compiles_no_tag_process():
    assert compile_scenario(_scenario(0.0)).channel.tag_prob == 0.0
    a, b = generate_trace(_scenario(0.0), 0, 3), generate_trace(_scenario(1e-12), 0, 3)
    np.testing.assert_array_equal(a.uwb.range_m, b.uwb.range_m)  # a vanishing process changes nothing


def _bursts(trace):
    """(burst id, anchor, NLOS, error) of the valid rows."""
    u = trace.uwb
    ok = u.valid
    return u.burst[ok], u.anchor[ok], u.nlos[ok], (u.range_m - u.true_range_m)[ok]


def test_tag_episodes_strike_the_anchors_together_and_keep_their_nlos_fraction():
    traces = {p: list(generate_traces(_scenario(p), 6, seed=4)) for p in (0.0, 0.06)}
    both = {}
    for p, trs in traces.items():
        nl, pairs, joint = [], 0, 0
        for tr in trs:
            b, a, n, _ = _bursts(tr)
            nl.append(n)
            m = np.zeros((int(b.max()) + 1, 3), dtype=bool)
            seen = np.zeros_like(m)
            m[b, a] = n
            seen[b, a] = True
            ok = seen[:, 0] & seen[:, 1]
            pairs += int(ok.sum())
            joint += int((m[ok, 0] & m[ok, 1]).sum())
        frac = np.concatenate(nl).mean()
        n_eps = sum(tr.duration_s for tr in trs) / 0.5 * 0.1  # about as many NLOS episodes per anchor
        assert frac == pytest.approx(0.1, abs=5 * 0.1 / np.sqrt(n_eps))
        both[p] = joint / pairs
    assert both[0.0] < 0.1 * 0.1 * 3  # independent anchors: about p^2
    assert both[0.06] > 0.06 * 0.6  # shared episodes: at least most of the tag's fraction
    b, a, n, err = _bursts(traces[0.06][0])
    near = n & (np.abs(err - 0.3) < 1.0)
    # rows of one burst in a tag episode share their draw: equal errors (same mode) across anchors
    key = b[near]
    _, first, inv, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    shared = counts[inv] > 1
    assert shared.sum() > 20
    spread = err[near][shared] - err[near][first][inv][shared]
    assert np.median(np.abs(spread)) < 0.01  # the anchors' own near-LOS draws would differ by ~0.2 m


def test_tag_side_leaves_the_anchors_own_draws_alone():
    """The tag side draws from its own stream and changes only the rows it strikes: the schedule, the
    LOS errors and the run-level draws (run offsets) stay those of the same seed without it."""
    scn = {"uwb.run_offset_std_m": 0.05}
    a, b = generate_trace(_scenario(0.0, **scn), 0, 3), generate_trace(_scenario(0.06, **scn), 0, 3)
    np.testing.assert_array_equal(a.uwb.t_s, b.uwb.t_s)
    np.testing.assert_array_equal(a.uwb.true_range_m, b.uwb.true_range_m)
    both_los = ~a.uwb.nlos & ~b.uwb.nlos & a.uwb.valid & b.uwb.valid
    assert both_los.mean() > 0.6
    np.testing.assert_array_equal(a.uwb.range_m[both_los], b.uwb.range_m[both_los])
    changed = a.uwb.nlos != b.uwb.nlos
    assert 0.01 < changed.mean() < 0.2  # the tag side moved some NLOS time, not the rest


def test_estimator_finds_the_shared_fraction_and_none_without_it():
    # without their IMU samples: the UWB fit does not use them (the same report section and scenario.uwb,
    # checked), and the IMU calibration would double the test's time
    res = {p: calibrate([replace(t, imu=None) for t in generate_traces(_scenario(p), 4, seed=9)]) for p in (0.0, 0.05)}
    fits = {p: r.report["tag_nlos"] for p, r in res.items()}
    assert fits[0.0]["prob"] < 0.01
    assert fits[0.05]["identifiable"]
    assert 0.025 < fits[0.05]["prob"] < 0.1
    assert fits[0.05]["applied"] and res[0.05].scenario.uwb.tag_nlos_prob == pytest.approx(fits[0.05]["prob"],
                                                                                          abs=1e-4)


def test_validation_measures_how_clean_the_range_differences_are():
    """residual_burst_deviation_std_m: shared tag-side errors leave the range differences cleaner."""
    from physynth.validate.compare import compare

    shared = list(generate_traces(_scenario(0.08), 3, seed=21))
    own = list(generate_traces(_scenario(0.0), 3, seed=22))
    rep = compare(shared, own)
    dev = rep.extended["residual_burst_deviation_std_m"]
    assert dev["synthetic"] > 1.2 * dev["real"]  # per-anchor episodes: noisier differences
    assert rep.extended["residual_burst_deviation_ratio"] == pytest.approx(dev["synthetic"] / dev["real"])
    same = compare(own, list(generate_traces(_scenario(0.0), 3, seed=23))).extended["residual_burst_deviation_ratio"]
    assert same == pytest.approx(1.0, abs=0.15)


def test_estimator_on_known_indicators():
    """The pair equation on flags drawn with a known shared fraction and every near row seen (d = 1)."""
    rng = np.random.default_rng(2)
    n, p_tag, own = 40000, 0.05, 0.04
    shared = rng.random(n) < p_tag
    t = np.repeat(np.arange(n) * 0.1, 3)
    anchor = np.tile(np.arange(3), n)
    near = np.repeat(shared, 3) | (rng.random(3 * n) < own)
    fit = fit_tag_nlos([(t, anchor, near)], 3, 0.1)
    assert fit["identifiable"]
    se = np.sqrt(p_tag * (1 - p_tag) / n)
    assert fit["prob"] == pytest.approx(p_tag, abs=6 * se + 0.005)
    assert not fit_tag_nlos([(t[:300], anchor[:300], near[:300])], 3, 0.1)["identifiable"]  # too few bursts


def test_an_anchor_without_a_near_mode_does_not_dilute_the_fraction():
    """A fourth anchor whose mixture has no near-LOS mode never joins a tag-side episode: its pairs are
    left out, and the fraction the three others share is found as without it (before, its three pairs
    of six entered as 0 and halved the estimate)."""
    rng = np.random.default_rng(3)
    n, p_tag, own = 40000, 0.05, 0.04
    shared = rng.random(n) < p_tag
    t = np.repeat(np.arange(n) * 0.1, 4)
    anchor = np.tile(np.arange(4), n)
    near = (np.repeat(shared, 4) | (rng.random(4 * n) < own)) & (anchor < 3)  # anchor 3: never seen near
    share = np.array([0.1, 0.1, 0.1, 0.0])  # the mixtures' near-mode fractions: none for anchor 3
    three = fit_tag_nlos([(t[anchor < 3], anchor[anchor < 3], near[anchor < 3])], 3, 0.1, share[:3])
    four = fit_tag_nlos([(t, anchor, near)], 4, 0.1, share)
    assert len(four["per_pair"]) == 3 and all(3 not in p["anchors"] for p in four["per_pair"])
    assert four["pairs_without_near_mode"] == 3
    # with no anchor able to show a tag-side episode nothing is fitted, and the report says why
    none = fit_tag_nlos([(t, anchor, near)], 4, 0.1, np.zeros(4))
    assert not none["identifiable"] and none["prob"] == 0.0 and "without a near-LOS NLOS mode" in none["why"]
    assert four["prob"] == pytest.approx(three["prob"], abs=1e-12)
    se = np.sqrt(p_tag * (1 - p_tag) / n)
    assert four["prob"] == pytest.approx(p_tag, abs=6 * se + 0.005)


@pytest.mark.skipif(not HANYANG.is_dir(), reason=f"real Hanyang data not found at {HANYANG}")
def test_hanyang_walks_share_their_wide_errors():
    """The real walks' near-LOS NLOS rows come to several anchors at once (data in ../shared)."""
    from physynth.studies.tracking import hanyang_default_runs

    train, test = hanyang_default_runs()
    fit = calibrate([r.trace for r in [*train, test]], anchor_policy="per-run").report["tag_nlos"]
    assert fit["identifiable"]
    assert fit["prob"] > 0.005
