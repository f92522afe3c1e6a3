"""Antenna sway: the generator's slow 3-D offset seen along each line of sight, and its calibration."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import simple_scenario, uwb_only_traces

from physynth.calibrate import calibrate
from physynth.calibrate.antenna_sway import fit_antenna_sway
from physynth.generate import generate_trace
from physynth.models.uwb import antenna_sway, travelled_m


def test_sway_is_a_stationary_ou_process_with_its_std_and_correlation_time():
    std, tau, dt = 0.05, 2.0, 0.1
    t = np.arange(0.0, 4000.0, dt)
    x = antenna_sway(t, 0.0, float(t[-1]), std, tau, rng=np.random.default_rng(3))
    assert x.shape == (t.size, 3)
    n_indep = t[-1] / (2.0 * tau)  # independent stretches of an OU process for its variance
    assert np.std(x, axis=0) == pytest.approx(np.full(3, std), rel=4.0 / np.sqrt(2.0 * n_indep))
    k = int(round(tau / dt))
    rho = np.mean([np.corrcoef(x[:-k, i], x[k:, i])[0, 1] for i in range(3)])
    assert rho == pytest.approx(np.exp(-1.0), abs=4.0 / np.sqrt(3.0 * n_indep))
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < 4.0 / np.sqrt(n_indep)  # independent axes
    start = antenna_sway(np.zeros(1), 0.0, 10.0, std, tau, rng=np.random.default_rng(4))
    assert np.all(np.abs(start) < 6 * std)  # drawn from the stationary law, not from 0 or far out


def test_each_range_sees_the_offset_along_its_line_of_sight():
    """Anchors in one direction see the same error; an anchor on the other side sees it negated."""
    anchors = [{"id": "A1", "pos_enu_m": [-1000.0, 0.0, 1.0]}, {"id": "A2", "pos_enu_m": [-2000.0, 0.0, 1.0]},
               {"id": "A3", "pos_enu_m": [3000.0, 0.0, 1.0]}]
    line = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [300, 0, 1]],
            "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}}  # along x: every line of sight is +-x
    scn = simple_scenario(anchors=anchors, path=line, **{"uwb.antenna_sway_std_m": 0.1, "uwb.antenna_sway_tau_s": 1.0,
                                                         "uwb.slot_s": 0.0, "channel.los_std_m": 1e-9})
    tr = generate_trace(scn, 0, 5)
    u = tr.uwb
    err = u.range_m - u.true_range_m
    e = {a: err[u.anchor == a] for a in range(3)}  # one attempt per anchor and burst, same times
    n = min(x.size for x in e.values())
    assert np.std(e[0][:n]) > 0.03
    np.testing.assert_allclose(e[0][:n], e[1][:n], atol=1e-6)  # same direction (x), same error
    np.testing.assert_allclose(e[0][:n], -e[2][:n], atol=1e-6)  # opposite direction: opposite sign
    plain = generate_trace(simple_scenario(anchors=anchors, path=line,
                                           **{"uwb.slot_s": 0.0, "channel.los_std_m": 1e-9}), 0, 5)
    np.testing.assert_array_equal(plain.uwb.true_range_m, u.true_range_m)  # no other draw moved


def test_calibration_recovers_the_sway_and_keeps_the_white_rest():
    std, tau, white = 0.06, 2.0, 0.02
    scn = simple_scenario(**{"uwb.antenna_sway_std_m": std, "uwb.antenna_sway_tau_s": tau,
                             "channel.los_std_m": white, "motion.cruise_speed_mps": 1.0})
    traces = uwb_only_traces(scn, 3, 7)
    fit = calibrate(traces)
    sc = fit.scenario
    span = sum(t.duration_s for t in traces)
    n_indep = span / (2.0 * tau)
    assert sc.uwb.antenna_sway_clock == "time"  # no stop to tell the clocks apart: the time clock, as before
    assert sc.uwb.antenna_sway_std_m == pytest.approx(std, rel=4.0 / np.sqrt(2.0 * n_indep))
    assert sc.uwb.antenna_sway_tau_s == pytest.approx(tau, rel=0.25)
    assert sc.channel.los_std_m == pytest.approx(white, rel=0.35)


def test_white_errors_give_no_sway():
    traces = uwb_only_traces(simple_scenario(**{"channel.los_std_m": 0.06}), 2, 8)
    fit = calibrate(traces)
    assert fit.scenario.uwb.antenna_sway_std_m == 0.0
    assert not fit.report["antenna_sway"]["identifiable"]
    assert any(s.startswith("uwb.antenna_sway_") for s in fit.report["not_identifiable"])


def test_fit_on_a_known_sequence():
    """The estimator alone, on OU + white sequences of one anchor with gaps in time."""
    rng = np.random.default_rng(11)
    seqs = []
    for _ in range(6):
        t = np.sort(rng.uniform(0.0, 600.0, 5000))
        x = antenna_sway(t, 0.0, 600.0, 0.05, 1.5, rng=rng)[:, 0] + rng.normal(0.0, 0.02, t.size)
        seqs.append((x, t))
    fit = fit_antenna_sway(seqs)
    assert fit["identifiable"]
    assert fit["std_m"] == pytest.approx(0.05, rel=0.15) and fit["tau_s"] == pytest.approx(1.5, rel=0.25)
    assert fit["white_std_m"] == pytest.approx(0.02, rel=0.3)


def test_travelled_distance_integrates_the_speed():
    t = np.arange(0.0, 10.0, 0.5)
    vel = np.zeros((t.size, 3))
    vel[:, 0], vel[:, 1] = 3.0, 4.0  # 5 m/s
    vel[8:12] = 0.0  # a stop: 4 samples at rest
    vel[5, 2] = np.nan  # an unknown velocity counts as rest
    c = travelled_m(t, vel)
    seg = 0.5 * (np.nan_to_num(np.linalg.norm(vel, axis=1))[1:] + np.nan_to_num(np.linalg.norm(vel, axis=1))[:-1]) * 0.5
    np.testing.assert_allclose(c, np.concatenate([[0.0], np.cumsum(seg)]))
    assert c[0] == 0.0 and np.all(np.diff(c) >= 0) and c[11] == c[8]  # nothing travelled while at rest
    assert c[4] == pytest.approx(10.0)  # 2 s at 5 m/s


def _sway_errors(clock: str, speed: float, seed: int, **extra):
    """Range errors of anchor A1 (sway only) of one trace, with its times and the tag's speed."""
    scn = simple_scenario(**{"uwb.antenna_sway_std_m": 0.1, "uwb.antenna_sway_clock": clock,
                             "uwb.antenna_sway_length_m": 2.0, "uwb.antenna_sway_tau_s": 2.0,
                             "motion.cruise_speed_mps": speed, **extra})
    tr = generate_trace(scn, 0, seed)
    u = tr.uwb
    m = (u.anchor == 0) & np.isfinite(u.range_m)
    return u.t_s[m], (u.range_m - u.true_range_m)[m]


def test_distance_clock_holds_the_offset_while_the_tag_stands_still():
    stops = {"motion.dwell_start_s": 20.0, "motion.dwell_end_s": 20.0}
    t, err = _sway_errors("distance", 3.0, 5, **stops)
    still = t < 19.5
    assert still.sum() > 300
    assert np.ptp(err[still]) < 1e-9  # the same offset along the same line of sight
    assert np.std(err[~still]) > 0.02  # and a new one as the tag moves
    t, err = _sway_errors("time", 3.0, 5, **stops)
    assert np.ptp(err[t < 19.5]) > 0.05  # the time clock's offset wanders while the tag stands


def _lag_correlation(t: np.ndarray, err: np.ndarray, lag_s: float) -> tuple[float, int]:
    k = int(np.median(np.searchsorted(t, t + lag_s) - np.arange(t.size)))  # rows one lag apart
    return float(np.corrcoef(err[:-k], err[k:])[0, 1]), err.size


def test_distance_clock_changes_faster_on_a_faster_carrier():
    """Correlation of the errors 1 s apart: exp(-v / L) on the distance clock (v = 1 and 4 m/s, L = 2 m:
    0.61 and 0.14), exp(-1 / tau) = 0.61 at either speed on the time clock."""
    got = {}
    for clock in ("distance", "time"):
        for v in (1.0, 4.0):
            pairs = [_lag_correlation(*_sway_errors(clock, v, s), 1.0) for s in range(4)]
            got[clock, v] = np.mean([p[0] for p in pairs])
    # independent stretches of the 300 m line: 300 / (2 L) at least, over 4 traces: 0.1 is > 2 standard errors
    assert got["distance", 1.0] == pytest.approx(np.exp(-0.5), abs=0.12)
    assert got["distance", 4.0] == pytest.approx(np.exp(-2.0), abs=0.12)
    assert got["time", 1.0] == pytest.approx(np.exp(-0.5), abs=0.12)
    assert got["time", 4.0] == pytest.approx(np.exp(-0.5), abs=0.2)


ZIGZAG = {"kind": "waypoints", "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0},
          "waypoints_enu_m": [[0, 0, 1], [30, 0, 1], [30, 30, 1], [60, 30, 1], [60, 0, 1], [90, 0, 1], [90, 30, 1],
                              [120, 30, 1], [120, 0, 1], [150, 0, 1], [150, 30, 1]]}
"""Ten 30 m legs with a right angle between each: a carrier that turns."""
ZIGZAG_ANCHORS = [{"id": "A1", "pos_enu_m": [-40, -60, 3]}, {"id": "A2", "pos_enu_m": [200, -60, 3]},
                  {"id": "A3", "pos_enu_m": [80, 90, 3]}]


def _change_by_turn(clock: str) -> dict[str, float]:
    """Mean |change| of the range error (sway only, one far anchor: one line of sight) between rows 5 m
    of travel apart, for pairs turned under 0.1 rad and over 0.4 rad between them; six traces."""
    from physynth.models.uwb import turned_rad

    far = [{"id": "A1", "pos_enu_m": [-5000.0, 15.0, 1.0]}]
    scn = simple_scenario(path=ZIGZAG, anchors=far, **{
        "uwb.antenna_sway_std_m": 0.1, "uwb.antenna_sway_clock": clock, "uwb.antenna_sway_length_m": 1000.0,
        "uwb.antenna_sway_turn_rad": 0.5, "uwb.antenna_sway_tau_s": 2.0, "motion.cruise_speed_mps": 2.0,
        "attitude.kind": "tangent"})
    out: dict[str, list[np.ndarray]] = {"straight": [], "turning": []}
    for seed in range(6):
        tr = generate_trace(scn, 0, seed)
        u, truth = tr.uwb, tr.truth
        err = u.range_m - u.true_range_m
        d = np.interp(u.t_s, truth.t_s, travelled_m(truth.t_s, truth.vel_enu_mps))
        h = np.interp(u.t_s, truth.t_s, turned_rad(truth.t_s, truth.vel_enu_mps, truth.omega_body_radps))
        for k in range(20, 120):  # rows k apart: 5 m of travel is about 57 rows at 2 m/s and 20 Hz
            five = np.abs(d[k:] - d[:-k] - 5.0) < 0.5
            dh, de = (h[k:] - h[:-k])[five], np.abs(err[k:] - err[:-k])[five]
            out["straight"].append(de[dh < 0.1])
            out["turning"].append(de[dh > 0.4])
    return {key: float(np.mean(np.concatenate(v))) for key, v in out.items()}


def test_motion_clock_changes_the_offset_where_the_carrier_turns():
    """Length 1 km (the distance alone barely moves it), turn 0.5 rad: over the same 5 m the offset moves
    about 2.4 times as much where the carrier turns (> 0.4 rad) as where it goes straight (< 0.1 rad);
    on the time clock the turns make no difference."""
    motion, time_ = _change_by_turn("motion"), _change_by_turn("time")
    assert motion["turning"] > 1.8 * motion["straight"], motion
    assert 0.7 < time_["turning"] / time_["straight"] < 1.4, time_


@pytest.mark.parametrize("clock", ["distance", "time"])
def test_calibration_tells_the_clocks_apart_when_the_tag_stops(clock):
    """Stops of 15 s at both ends of a 1 m/s walk: the clock the traces were made with is the one picked,
    with its scale (300 m / (2 x 2 m) x 4 traces: 300 independent stretches, a few per cent of sampling
    error; 30 % also leaves room for the range law, which the rows of a long stop at one range pull)."""
    std, scale, white = 0.06, 2.0, 0.02
    scn = simple_scenario(**{"uwb.antenna_sway_std_m": std, "uwb.antenna_sway_clock": clock,
                             "uwb.antenna_sway_tau_s": scale, "uwb.antenna_sway_length_m": scale,
                             "channel.los_std_m": white, "motion.cruise_speed_mps": 1.0,
                             "motion.dwell_start_s": 15.0, "motion.dwell_end_s": 15.0,
                             "uwb.burst_rate_hz": 10.0, "channel.rate_hz": 10.0})  # fewer rows: a faster fit
    fit = calibrate(uwb_only_traces(scn, 4, 7))
    sw = fit.report["antenna_sway"]
    other = "distance" if clock == "time" else "time"
    assert sw["clock"] == clock, sw["fits"]
    assert sw["fits"][clock]["mse_m4"] < 0.7 * sw["fits"][other]["mse_m4"]
    u = fit.scenario.uwb
    assert u.antenna_sway_clock == clock
    fitted = u.antenna_sway_length_m if clock == "distance" else u.antenna_sway_tau_s
    assert fitted == pytest.approx(scale, rel=0.3)
    assert u.antenna_sway_std_m == pytest.approx(std, rel=0.25)


def test_calibration_finds_the_motion_clock_of_a_turning_carrier():
    """A 1 m/s walk along the zigzag: an offset that follows the turns (length 20 m, turn 0.4 rad) is found
    on the motion clock with its turn scale (within a grid step and the sampling error of three traces).
    (An offset that follows the time is kept on the time clock: the stops test above.)"""
    clock = "motion"
    scn = simple_scenario(path=ZIGZAG, anchors=ZIGZAG_ANCHORS, **{
        "uwb.antenna_sway_std_m": 0.06, "uwb.antenna_sway_clock": clock, "uwb.antenna_sway_tau_s": 2.0,
        "uwb.antenna_sway_length_m": 20.0, "uwb.antenna_sway_turn_rad": 0.4, "channel.los_std_m": 0.02,
        "motion.cruise_speed_mps": 1.0, "attitude.kind": "tangent", "motion.dwell_start_s": 10.0,
        "motion.dwell_end_s": 10.0, "uwb.burst_rate_hz": 10.0, "channel.rate_hz": 10.0})
    fit = calibrate(uwb_only_traces(scn, 3, 7))
    sw = fit.report["antenna_sway"]
    other = [k for k in sw["fits"] if k != clock]
    assert sw["clock"] == clock and sw["fits"][clock]["mse_m4"] < 0.5 * sw["fits"][other[0]]["mse_m4"]
    u = fit.scenario.uwb
    assert u.antenna_sway_clock == clock
    assert u.antenna_sway_std_m == pytest.approx(0.06, rel=0.25)
    assert u.antenna_sway_turn_rad == pytest.approx(0.4, rel=0.4)
