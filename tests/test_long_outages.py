"""Long outages: the sampler's statistics, recovery of its parameters by the fit, and the calibration switch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physynth.calibrate.outage_range import anchor_runs, fit_long_outages
from physynth.models.availability import AvailabilityParams, long_outage_mask, outage_mask

HANYANG = Path(__file__).resolve().parents[2] / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"


def test_constant_rate_covers_the_busy_fraction_of_a_boolean_model():
    """Poisson onsets of rate h, exponential lengths of mean m, merged: P(covered) = 1 - exp(-h m)."""
    rate, mean, span = 0.01, 2.0, 1.0e6
    t = np.arange(0.0, span, 1.0)
    mask = long_outage_mask(t, np.full(t.size, 20.0), rate, mean, 0.0, 20.0, rng=np.random.default_rng(4))
    expected = 1.0 - np.exp(-rate * mean)
    # covered time is a compound Poisson sum: variance rate * span * E[D^2] = rate * span * 2 m^2
    sd = np.sqrt(rate * span * 2.0 * mean**2) / span
    assert abs(mask.mean() - expected) < 4.0 * sd + 1.0 / np.sqrt(t.size)


def test_onset_rate_grows_with_range_and_lengths_do_not():
    """Half the time at 10 m, half at 30 m, slope 0.05 / m: e^1 times as many onsets far out, same lengths."""
    rate, mean, slope = 0.01, 1.0, 0.05
    half = 2.0e5
    t = np.arange(0.0, 2 * half, 0.1)
    r = np.where(t < half, 10.0, 30.0)
    mask = long_outage_mask(t, r, rate, mean, slope, 10.0, rng=np.random.default_rng(5))
    rise = np.flatnonzero(mask[1:] & ~mask[:-1]) + 1
    fall = np.flatnonzero(~mask[1:] & mask[:-1]) + 1
    near, far = (t[rise] < half).sum(), (t[rise] >= half).sum()
    ratio = far / near
    # merged outages hide a few onsets: the busy fraction differs between the halves
    want = np.e * np.exp(-rate * mean * (np.e - 1.0))
    assert abs(ratio - want) < 4.0 * want * np.sqrt(1.0 / near + 1.0 / far)
    lengths = (t[fall[: rise.size]] - t[rise[: fall.size]]) if fall[0] > rise[0] else None
    assert lengths is not None
    n = lengths.size
    assert abs(lengths.mean() - mean) < 4.0 * mean / np.sqrt(n) + 0.1


def test_range_cap_stops_the_rate_growing():
    t = np.arange(0.0, 5.0e4, 0.1)
    far = long_outage_mask(t, np.full(t.size, 200.0), 0.01, 1.0, 0.1, 10.0, max_range_m=20.0,
                           rng=np.random.default_rng(6))
    at_cap = long_outage_mask(t, np.full(t.size, 20.0), 0.01, 1.0, 0.1, 10.0, rng=np.random.default_rng(6))
    assert np.array_equal(far, at_cap)


def test_zero_rate_draws_nothing():
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    assert not long_outage_mask(np.arange(100.0), np.full(100, 5.0), 0.0, 1.0, 0.0, 0.0, rng=rng).any()
    assert rng.bit_generator.state == state


def _synthetic_sequences(seed: int, n_runs: int, rate_l: float, mean_l: float, slope: float, r_ref: float):
    """Attempt codes at 10 Hz of one anchor on a walk out to 50 m and back, from the generator's own samplers:
    ordinary outages (onset 0.003 per attempt, mean 0.25 s), dropouts 0.03, and long outages."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 250.0, 0.1)
    r = 5.0 + 45.0 * (1.0 - np.abs(t / 125.0 - 1.0))
    codes, ranges = [], []
    for _ in range(n_runs):
        out = outage_mask(t, 0.003, 10.0, 0.25, start_stationary=True, rng=rng)
        out |= long_outage_mask(t, r, rate_l, mean_l, slope, r_ref, rng=rng)
        heard = ~out & (rng.random(t.size) >= 0.03)
        codes.append(heard.astype(np.int8))
        ranges.append(r)
    return codes, ranges


def test_fit_recovers_rate_mean_and_slope():
    rate_l, mean_l, slope, r_ref = 0.002, 2.0, 0.08, 27.5
    codes, ranges = _synthetic_sequences(11, 60, rate_l, mean_l, slope, r_ref)
    runs = anchor_runs("A1", 0.1, codes, ranges)
    fit = fit_long_outages([runs])
    assert fit["identifiable"], fit
    # expected number of long outages over the walks (the rate averaged over the ranges walked)
    r = ranges[0]
    n_long = len(codes) * rate_l * float(np.mean(np.exp(slope * (r - r_ref)))) * 250.0
    rel = 4.0 / np.sqrt(n_long)
    assert abs(fit["mean_s"] / mean_l - 1.0) < rel, fit
    # a log-linear Poisson regression: se(slope) ~ 1 / (sqrt(n) sd(range at the onsets))
    w = np.exp(slope * (r - r_ref))
    sd_r = np.sqrt(np.average((r - np.average(r, weights=w)) ** 2, weights=w))
    assert abs(fit["range_slope_per_m"] - slope) < 4.0 / (np.sqrt(n_long) * sd_r), fit
    rate_at_ref = fit["rate_per_s"] * np.exp(fit["range_slope_per_m"] * (r_ref - fit["ref_range_m"]))
    assert abs(np.log(rate_at_ref / rate_l)) < rel + 4.0 / (np.sqrt(n_long) * sd_r) * 25.0, fit


def test_fit_recovers_the_spread_between_placements():
    """Each placement (anchor x run) fades at its own rate G x h, G ~ Gamma(k, 1/k): the fit finds k."""
    from scipy.special import polygamma

    k, rate_l, mean_l, n_place = 0.5, 0.05, 2.0, 60
    rng = np.random.default_rng(21)
    g = rng.gamma(k, 1.0 / k, n_place)
    runs = []
    for i in range(n_place):
        codes, ranges = _synthetic_sequences(100 + i, 1, rate_l * g[i], mean_l, 0.0, 0.0)
        runs.append(anchor_runs("A1", 0.1, codes, ranges))
    fit = fit_long_outages(runs)
    assert fit["identifiable"] and fit["frailty_shape"] is not None, fit
    # with G observed, var(log k_hat) = 1 / (n k^2 (trigamma(k) - 1 / k)); G is seen through ~12 long
    # outages per placement at G = 1 (Poisson noise adds ~1/12 to var(G) = 1/k = 2): 10 % more
    sd = 1.1 / np.sqrt(n_place * k**2 * (float(polygamma(1, k)) - 1.0 / k))
    assert abs(np.log(fit["frailty_shape"] / k)) < 4.0 * sd, fit
    assert abs(fit["mean_s"] / mean_l - 1.0) < 0.2, fit


def test_placements_alike_keep_no_frailty():
    runs = [anchor_runs("A1", 0.1, *_synthetic_sequences(200 + i, 1, 0.02, 2.0, 0.0, 0.0)) for i in range(20)]
    fit = fit_long_outages(runs)
    assert fit["identifiable"] and fit["frailty_shape"] is None, fit
    assert fit["lr_frailty"] < 10.0


def test_generated_frailty_spreads_the_anchors_and_keeps_the_mean():
    from physynth.models.availability import availability_arrays, simulate_availability

    t = np.arange(0.0, 2000.0, 0.1)
    n_a = 50
    params = AvailabilityParams(dropout_prob=0.0, outage_onset_prob=0.0, long_outage_rate_per_s=0.01,
                                long_outage_mean_s=1.0, long_outage_frailty_shape=0.5)
    av = availability_arrays(params, [params] * n_a)
    tt = np.tile(t, n_a)
    anchor = np.repeat(np.arange(n_a), t.size)
    out, _ = simulate_availability(tt, anchor, np.zeros(tt.size, np.int64), t, av, 10.0,
                                   range_m=np.full(tt.size, 20.0), rng=np.random.default_rng(8))
    frac = out.reshape(n_a, t.size).mean(axis=1)
    # per anchor the busy fraction is 1 - exp(-G h m); over anchors its mean is E[1 - exp(-G h m)]
    # = 1 - (1 + h m / k)^-k and its spread that of G (sd sqrt(1/k) h m): far wider than one rate's
    h_m, k = 0.01 * 1.0, 0.5
    want = 1.0 - (1.0 + h_m / k) ** -k
    assert abs(frac.mean() - want) < 4.0 * np.sqrt(1.0 / k) * h_m / np.sqrt(n_a)
    one_rate_sd = np.sqrt(0.01 * 2000.0 * 2.0) / 2000.0  # compound Poisson spread of one anchor at G = 1
    assert frac.std() > 3.0 * one_rate_sd


def test_fit_finds_no_long_outages_where_there_are_none():
    codes, ranges = _synthetic_sequences(12, 30, 0.0, 2.0, 0.0, 0.0)
    fit = fit_long_outages([anchor_runs("A1", 0.1, codes, ranges)])
    assert not fit["identifiable"], fit
    assert "likelihood ratio" in fit["why"] or "long mean" in fit["why"]


@pytest.mark.skipif(not HANYANG.exists(), reason="shared Hanyang data not present")
def test_calibration_reports_long_outages_and_generates_them_only_when_asked():
    from physynth.calibrate import calibrate
    from physynth.generate import generate_trace
    from physynth.io.importers import import_hanyang

    runs = [import_hanyang(HANYANG / env / "Trajectory_A" / case, crop_to_uwb=True)[0]
            for env, case in (("LOS", "Case_2"), ("NLOS", "Case_2"))]
    off = calibrate(runs)
    fit = off.report["availability"]["long_outages"]
    assert fit["identifiable"] and fit["lr_long"] >= 10.0
    assert fit["range_slope_per_m"] > 0  # the long fades of these runs start 45-50 m out
    assert off.scenario.availability.long_outage_rate_per_s == 0.0
    assert any("long_outage" in s for s in off.report["not_identifiable"])
    on = calibrate(runs, long_outages=True)
    av = on.scenario.availability
    assert av.long_outage_rate_per_s > 0 and av.long_outage_range_slope_per_m > 0
    assert av.long_outage_max_range_m is not None and av.long_outage_max_range_m <= 52.0
    # generated traces: more long single-anchor gaps than without, and only past the reference range
    def long_gaps(scn) -> tuple[int, list[float]]:
        n, where = 0, []
        for i in range(8):
            tr = generate_trace(scn, i, 3)
            u = tr.uwb
            for k in range(len(tr.anchors)):
                t = np.sort(u.t_s[u.valid & (u.anchor == k)])
                gap = np.flatnonzero(np.diff(t) > 2.0)
                n += gap.size
                pos = tr.truth.position_at(t[gap])
                where += list(np.linalg.norm(pos - tr.anchors.pos_enu_m[k], axis=1))
        return n, where

    n_off, _ = long_gaps(off.scenario)
    n_on, where = long_gaps(on.scenario)
    assert n_on > n_off
    assert np.median(where) > av.long_outage_ref_range_m


def test_default_scenario_has_no_long_outages():
    assert AvailabilityParams().long_outage_rate_per_s == 0.0
