"""Calibration: round trip on synthetic traces, transfer, scenario output, bad input.

Round trip: traces generated from a known scenario (fixed seed) are calibrated and every parameter is
recovered within a tolerance derived from the number of samples behind it (k standard errors, stated
per parameter below, plus a small stated allowance for the known approximations of the estimator).
With k = 4 a correct estimator fails a single check with probability ~6e-5.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from physynth.calibrate import CalibrationError, calibrate, fit_motion, fit_path, transfer_scenario
from physynth.cli import main as cli_main
from physynth.errors import PhySynthError
from physynth.generate import compile_scenario, generate_trace
from physynth.io import write_dataset
from physynth.io.scenario_file import load_scenario, save_scenario
from physynth.models.uwb import los_error_mean, range_decades
from physynth.records import Anchors, Trace, Truth, Uwb
from physynth.scenario import scenario_from_dict, scenario_to_dict

K = 4.0  # standard errors allowed per check

TRUE = {
    "burst_rate_hz": 20.0, "slot_s": 0.002, "time_offset_s": 0.12, "rate_hz": 16.0, "los_mean_m": 0.1,
    "los_std_m": 0.08, "range_bias_per_m": 0.004, "nlos_prob": 0.1, "modes": [(0.6, 1.5, 0.4), (0.4, 5.0, 1.0)],
    "nlos_dwell_s": 0.5, "dropout_prob": 0.05, "outage_onset_prob": 0.005, "outage_mean_s": 3.0,
    "white": [0.05, 0.08, 0.1], "vib_hz": 4.0, "vib_amp": 0.1, "cruise_speed_mps": 5.0, "max_range_m": 150.0,
}


def roundtrip_dict() -> dict:
    """A 400 m gently curved cable past four anchors, every model term switched on."""
    return {
        "name": "roundtrip",
        "path": {"kind": "polynomial", "length_m": 400.0,
                 "coeffs_enu_m": [[0.0, 390.0, 0.0], [0.0, 80.0, -80.0], [60.0, -50.0, 0.0]],
                 "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}},
        "motion": {"cruise_speed_mps": TRUE["cruise_speed_mps"], "cruise_speed_spread_frac": 0.0,
                   "length_spread_frac": 0.0, "dwell_start_s": 5.0, "dwell_end_s": 4.0,
                   "profile": {"kind": "polynomial", "coeffs": [0.0, 8.0, -24.0, 32.0, -16.0]}},
        "imu": {"rate_hz": 200.0, "white_noise_density_mps2_per_sqrt_hz": TRUE["white"],
                "bias_rw_mps2_per_sqrt_s": 0.001,
                "vibration": {"fundamental_hz": TRUE["vib_hz"], "amplitude_mps2": TRUE["vib_amp"],
                              "harmonic_weights": [1.0, 0.5], "bandwidth_hz": 0.3}},
        "uwb": {"burst_rate_hz": TRUE["burst_rate_hz"], "burst_jitter_s": 0.002, "slot_s": TRUE["slot_s"],
                "time_offset_s": TRUE["time_offset_s"], "nlos_dwell_s": TRUE["nlos_dwell_s"]},
        "anchors": [{"id": "A1", "pos_enu_m": [50.0, 40.0, 40.0]}, {"id": "A2", "pos_enu_m": [150.0, 10.0, 30.0]},
                    {"id": "A3", "pos_enu_m": [250.0, 40.0, 20.0]}, {"id": "A4", "pos_enu_m": [350.0, 5.0, 10.0]}],
        "channel": {"rate_hz": TRUE["rate_hz"], "los_mean_m": TRUE["los_mean_m"], "los_std_m": TRUE["los_std_m"],
                    "range_bias_per_m": TRUE["range_bias_per_m"], "nlos_prob": TRUE["nlos_prob"],
                    "nlos_modes": [{"weight": w, "mean_m": m, "std_m": s} for w, m, s in TRUE["modes"]],
                    "max_range_m": TRUE["max_range_m"], "edge_width_m": 5.0},
        "availability": {"dropout_prob": TRUE["dropout_prob"], "outage_onset_prob": TRUE["outage_onset_prob"],
                         "outage_mean_s": TRUE["outage_mean_s"]},
    }


N_TRACES = 8


@pytest.fixture(scope="module")
def roundtrip():
    scn = scenario_from_dict(roundtrip_dict(), "roundtrip")
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 20240611) for i in range(N_TRACES)]
    return scn, traces, calibrate(traces, name="rt", range_bias_law="linear")  # the data's bias is linear in r


def _per_anchor(result, field: str) -> np.ndarray:
    return np.array([getattr(result.scenario.channel_for(a), field) for a in result.scenario.anchor_ids])


def _se(result, key: str) -> float:
    return float(result.report["parameters"][key]["std_error"])


def test_roundtrip_path_and_motion(roundtrip):
    scn, traces, res = roundtrip
    s = res.scenario
    # degree-10 polynomial of an exactly polynomial (degree-2) noise-free path: cross-track RMSE is the
    # smoothing/resampling error only; 2 cm is 10x what it is, and 0.05 % of the 400 m length
    assert s.path.kind == "polynomial"
    assert res.report["path"]["rmse_m"] < 0.02
    # cruise speed: the true cruise speed is the truth's peak speed (the declared length_m of the
    # polynomial differs from its arc length, so it is not exactly 5.0); noise-free truth: 1 %
    peak = np.mean([np.max(np.linalg.norm(t.truth.vel_enu_mps, axis=1)) for t in traces])
    assert s.motion.cruise_speed_mps == pytest.approx(peak, rel=0.01)
    assert s.motion.profile.kind == "polynomial"
    assert res.report["motion"]["speed_poly_r2"] > 0.999
    # dwells: stop detection at 0.1 % of the peak speed of a polynomial ramp loses < 0.2 s
    assert s.motion.dwell_start_s == pytest.approx(5.0, abs=0.2)
    assert s.motion.dwell_end_s == pytest.approx(4.0, abs=0.2)
    # no spread in the scenario: 8 runs must show (almost) none
    assert s.motion.cruise_speed_spread_frac < 0.01


def test_roundtrip_uwb_timing(roundtrip):
    _, _, res = roundtrip
    s = res.scenario
    se = _se(res, "uwb.time_offset_s")
    assert s.uwb.time_offset_s == pytest.approx(TRUE["time_offset_s"], abs=K * se + 0.001)
    # every run has the same lag: Cochran's Q does not see a spread, and none is written
    assert not res.report["time_offset"]["run_spread"]["significant"] and s.uwb.time_offset_std_s == 0.0
    # burst period: median of ~17,000 jittered periods (jitter 2 ms): SE ~ 2e-5 s; 0.1 % is > 10 SE
    assert s.uwb.burst_rate_hz == pytest.approx(TRUE["burst_rate_hz"], rel=1e-3)
    # jitter: robust (MAD) spread of ~17,000 periods; relative SE of a MAD ~ 1.17 / sqrt(2 n) < 1 %
    assert s.uwb.burst_jitter_s == pytest.approx(0.002, rel=0.05)
    # grid-equivalent slot: fraction of ~17,000 bursts split over 10 ms bins (binomial, p ~ 0.5):
    # relative SE ~ 1 %, plus the random phase of each trace: 20 %
    assert s.uwb.slot_s == pytest.approx(TRUE["slot_s"], rel=0.2)
    # effective rate: attempts / bursts per anchor, ~7,000 bursts each: SE = 20 sqrt(q(1-q)/n) ~ 0.1 Hz
    n_bursts = res.report["availability"]["per_anchor"]["A1"]["bursts"]
    se_rate = TRUE["burst_rate_hz"] * np.sqrt(0.8 * 0.2 / n_bursts)
    assert np.all(np.abs(_per_anchor(res, "rate_hz") - TRUE["rate_hz"]) < K * se_rate)


def test_roundtrip_ranging_errors(roundtrip):
    _, _, res = roundtrip
    mode_dwells = []
    for a in res.scenario.anchor_ids:
        c = res.scenario.channel_for(a)
        pre = f"channel_per_anchor.{a}"
        # LOS mean, slope and spread: regression standard errors from n ~ 5,000 LOS rows per anchor
        assert c.los_mean_m == pytest.approx(TRUE["los_mean_m"], abs=K * _se(res, f"{pre}.los_mean_m"))
        assert c.range_bias_per_m == pytest.approx(TRUE["range_bias_per_m"],
                                                   abs=K * _se(res, f"{pre}.range_bias_per_m"))
        # sigma: SE sigma / sqrt(2 n); allowance 2 % for the EM's share of LOS-NLOS overlap
        assert c.los_std_m == pytest.approx(TRUE["los_std_m"], abs=K * _se(res, f"{pre}.los_std_m") + 0.0016)
        # NLOS probability: episodes of 0.5 s make rows dependent; SE from the episode count
        assert c.nlos_prob == pytest.approx(TRUE["nlos_prob"], abs=K * _se(res, f"{pre}.nlos_prob"))
        # two NLOS modes found by BIC, means within K SE (sd / sqrt(n_mode)) + 0.05 m
        assert len(c.nlos_modes) == 2
        modes = sorted((m.mean_m, m.std_m, m.weight) for m in c.nlos_modes)
        se_means = res.report["parameters"][f"{pre}.nlos_modes"]["std_error"]
        # an NLOS episode keeps its mode: the weights are known to the number of episodes, not of rows
        n_ep = sum(res.report["channel"]["per_anchor"][a]["nlos_mode_episodes"])
        for (mean, _, w), (tw, tm, _), se in zip(modes, sorted(TRUE["modes"], key=lambda x: x[1]),
                                                 sorted(se_means), strict=True):
            assert mean == pytest.approx(tm, abs=K * se + 0.05)
            assert w == pytest.approx(tw, abs=K * np.sqrt(tw * (1 - tw) / n_ep) + 0.02)
        for m, n in zip(c.nlos_modes, res.report["channel"]["per_anchor"][a]["nlos_mode_episodes"], strict=True):
            mode_dwells.append((m.dwell_s, n))
        # radio horizon: identifiable here (the path leaves the 150 m range of every anchor)
        assert c.max_range_m == pytest.approx(TRUE["max_range_m"], abs=5.0)
    # each mode's episode length (both 0.5 s here), pooled over anchors and modes weighted by episodes:
    # geometric runs have std ~ mean, so the SE is 1/sqrt(episodes); runs are counted in delivered rows
    # (dropouts and labelling errors shorten them): allowance 25 %
    d, n = np.array(mode_dwells, dtype=float).T
    pooled = float(np.sum(d * n) / n.sum())
    assert pooled == pytest.approx(TRUE["nlos_dwell_s"], rel=K / np.sqrt(n.sum()) + 0.25)
    # NLOS dwell: ~1,000 episodes pooled; the geometric-run estimator is biased by LOS rows labelled
    # NLOS and vice versa: 30 %
    assert res.scenario.uwb.nlos_dwell_s == pytest.approx(TRUE["nlos_dwell_s"], rel=0.3)


def test_roundtrip_availability(roundtrip):
    _, _, res = roundtrip
    s = res.scenario
    ids = s.anchor_ids
    drop = np.array([s.availability_for(a).dropout_prob for a in ids])
    onset = np.array([s.availability_for(a).outage_onset_prob for a in ids])
    mean = np.array([s.availability_for(a).outage_mean_s for a in ids])
    se = {k: np.array([_se(res, f"availability_per_anchor.{a}.{k}") for a in ids])
          for k in ("dropout_prob", "outage_onset_prob", "outage_mean_s")}
    # per anchor: HMM likelihood standard errors (~5,000 attempts, ~40 outages per anchor);
    # allowance 0.005 on the dropout for attempts lost at the soft edge of the radio horizon
    assert np.all(np.abs(drop - TRUE["dropout_prob"]) < K * se["dropout_prob"] + 0.005)
    assert np.all(np.abs(onset - TRUE["outage_onset_prob"]) < K * se["outage_onset_prob"])
    assert np.all(np.abs(mean - TRUE["outage_mean_s"]) < K * se["outage_mean_s"])
    # pooled over the four anchors the errors shrink by 2: 2.5 SE of the mean
    assert abs(onset.mean() - TRUE["outage_onset_prob"]) < 2.5 * np.sqrt(np.sum(se["outage_onset_prob"] ** 2)) / 4
    assert abs(mean.mean() - TRUE["outage_mean_s"]) < 2.5 * np.sqrt(np.sum(se["outage_mean_s"] ** 2)) / 4
    assert s.availability.tag_outage_onset_prob == 0.0


def test_roundtrip_imu(roundtrip):
    _, _, res = roundtrip
    imu = res.scenario.imu
    d = res.report["imu"]
    # white density from the median of ~4,000 Welch bins x 100 averages: relative SE < 0.5 %;
    # 3 % allows for the median-of-chi2 bias and the vibration tails
    assert np.allclose(imu.white_noise_density_mps2_per_sqrt_hz, TRUE["white"], rtol=0.03)
    # vibration: frequency within 2 Welch bins (20 s segments: 0.05 Hz), amplitude within 20 %
    # (the 0.1 m/s^2 lines sit below a white floor of ~1 m/s^2 per sample)
    df = d["vibration"]["frequency_resolution_hz"]
    assert imu.vibration.fundamental_hz == pytest.approx(TRUE["vib_hz"], abs=2 * df)
    assert imu.vibration.amplitude_mps2 == pytest.approx(TRUE["vib_amp"], rel=0.2)
    assert len(imu.vibration.harmonic_weights) == 2
    assert imu.rate_hz == pytest.approx(200.0)
    assert "allan_deviation" in d and len(d["allan_deviation"]["tau_s"]) > 10


def test_report_has_uncertainty_or_count_for_every_parameter(roundtrip):
    _, _, res = roundtrip
    rep = res.report
    json.dumps(rep)  # JSON-able
    for key, item in rep["parameters"].items():
        assert item.get("std_error") is not None or item.get("n_samples") is not None, key
    for key in ("path", "motion", "time_offset", "burst_schedule", "channel", "availability", "imu"):
        assert key in rep
    assert min(rep["time_offset"]["search_curve"]["robust_spread_m"]) == pytest.approx(
        rep["time_offset"]["spread_at_offset_m"], rel=0.05)
    for a in res.scenario.anchor_ids:
        assert rep["channel"]["per_anchor"][a]["bic_per_order"]["2"]["admissible"]


def test_scenario_round_trips_through_yaml_and_generates(roundtrip, tmp_path):
    _, _, res = roundtrip
    path = save_scenario(res.scenario, tmp_path / "cal.yaml")
    back = load_scenario(path)
    assert back == res.scenario
    assert back.provenance["calibrated_by"].startswith("physynth")
    tr = generate_trace(compile_scenario(back), 0, 1)
    assert len(tr.uwb) > 0 and tr.imu is not None


def test_one_run_keeps_default_spreads_and_says_so():
    scn = scenario_from_dict(roundtrip_dict(), "roundtrip")
    tr = generate_trace(compile_scenario(scn), 0, 3)
    fit = fit_motion(tr)
    assert fit.params.cruise_speed_spread_frac == 0.12 and fit.params.length_spread_frac == 0.05
    assert "cruise_speed_spread_frac" in fit.diagnostics["not_identifiable"]


def test_spreads_from_several_runs():
    d = roundtrip_dict()
    d["motion"]["cruise_speed_spread_frac"] = 0.12
    d["imu"]["vibration"]["amplitude_mps2"] = 0.0
    scn = scenario_from_dict(d, "spread")
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 5) for i in range(12)]
    fit = fit_motion(traces)
    # uniform +-12 %: the half-width from 12 runs via sqrt(3) std has a relative SE of ~20 %
    assert fit.params.cruise_speed_spread_frac == pytest.approx(0.12, rel=0.45)
    speeds = [t.meta["speed_factor"] * 5.0 for t in traces]
    per_run = [r["cruise_speed_mps"] for r in fit.diagnostics["per_run"].values()]
    assert np.corrcoef(speeds, per_run)[0, 1] > 0.99


def test_fit_path_preset_polynomial_and_waypoints():
    scn = load_scenario("cablecar-descending")
    tr = generate_trace(compile_scenario(scn), 0, 11)
    fit = fit_path(tr)
    assert fit.params.kind == "polynomial"
    assert fit.diagnostics["rmse_m"] < 0.05  # noise-free 710 m cable: paper reached 0.087 m on GNSS truth
    assert fit.diagnostics["length_m"] == pytest.approx(710.2, rel=0.01)
    way = fit_path(tr, "waypoints")
    assert way.params.kind == "waypoints" and way.diagnostics["rmse_m"] < 0.1
    assert len(way.params.waypoints_enu_m) < 100


def test_transfer_scenario_keeps_sensor_models():
    base = load_scenario("cablecar-descending")
    real = generate_trace(compile_scenario(scenario_from_dict(roundtrip_dict(), "rt")), 0, 2)
    out = transfer_scenario(base, [real])
    assert out.anchor_ids == ("A1", "A2", "A3", "A4")
    assert out.imu == base.imu and out.channel == base.channel
    # UWB acquisition kept, but for the burst clock's alignment, which is the real run's
    assert out.uwb.model_copy(update={"burst_phase_s": None}) == base.uwb
    assert out.uwb.burst_phase_s is not None and 0 <= out.uwb.burst_phase_s < 1 / TRUE["burst_rate_hz"]
    assert out.availability == base.availability
    assert out.channel_per_anchor == {} and out.availability_per_anchor == {}  # preset ids are not in real
    assert out.path.perturbation == base.path.perturbation
    assert out.motion.cruise_speed_spread_frac == base.motion.cruise_speed_spread_frac
    assert out.motion.dwell_start_s == pytest.approx(5.0, abs=0.2)
    # anchors the scenario has overrides for keep them
    d = roundtrip_dict()
    d["channel_per_anchor"] = {"A2": {"los_std_m": 0.5}, "A9": {"los_std_m": 0.7}}
    d["anchors"].append({"id": "A9", "pos_enu_m": [0.0, 0.0, 0.0]})
    out2 = transfer_scenario(scenario_from_dict(d, "with-overrides"), [real])
    assert set(out2.channel_per_anchor) == {"A2"}


# ------------------------------------------------------------------------------------ bad input


def _trace(n_truth=100, uwb_rows=True, anchors=(("A1", (0.0, 0.0, 0.0)),)):
    t = np.arange(n_truth) * 0.1
    pos = np.stack([t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    truth = Truth(t_s=t, pos_enu_m=pos, vel_enu_mps=np.tile([1.0, 0.0, 0.0], (n_truth, 1)))
    n = 50 if uwb_rows else 0
    uwb = Uwb(t_s=np.linspace(0, 9, n), anchor=np.zeros(n, np.int16), range_m=np.linspace(0, 9, n))
    a = Anchors(ids=tuple(x[0] for x in anchors), pos_enu_m=np.array([x[1] for x in anchors]))
    return Trace(truth=truth, uwb=uwb, anchors=a, meta={"run": "bad"})


def test_bad_input_messages():
    with pytest.raises(CalibrationError, match="no traces"):
        calibrate([])
    with pytest.raises(CalibrationError, match="no UWB rows"):
        calibrate(_trace(uwb_rows=False))
    with pytest.raises(CalibrationError, match="no usable ground truth"):
        calibrate(_trace(n_truth=3))
    a = _trace(anchors=(("A1", (0.0, 0.0, 0.0)),))
    b = _trace(anchors=(("A1", (5.0, 0.0, 0.0)),))
    with pytest.raises(CalibrationError, match="conflicting anchors.*A1"):
        calibrate([a, b], anchor_policy="strict")
    with pytest.raises(CalibrationError, match="layout_from='nope' names no recording"):
        calibrate([a, b], layout_from="nope")
    assert issubclass(CalibrationError, PhySynthError)


def test_cli_bad_input_exit_code_2(tmp_path, capsys):
    def run(*args):
        with pytest.raises(SystemExit) as exc:
            cli_main(list(args))
        return exc.value.code, capsys.readouterr().err

    code, err = run("calibrate", str(tmp_path / "missing"), "--out", str(tmp_path / "s.yaml"))
    assert code == 2 and "does not exist" in err and err.count("\n") == 1
    (tmp_path / "empty").mkdir()
    code, err = run("calibrate", str(tmp_path / "empty"), "--out", str(tmp_path / "s.yaml"))
    assert code == 2 and "not a PhySynth dataset" in err
    write_dataset(tmp_path / "no_uwb", [_trace(uwb_rows=False)])
    code, err = run("calibrate", str(tmp_path / "no_uwb"), "--out", str(tmp_path / "s.yaml"))
    assert code == 2 and "no UWB rows" in err
    write_dataset(tmp_path / "d1", [_trace(anchors=(("A1", (0.0, 0.0, 0.0)),))])
    write_dataset(tmp_path / "d2", [_trace(anchors=(("A1", (5.0, 0.0, 0.0)),))])
    code, err = run("calibrate", str(tmp_path / "d1"), str(tmp_path / "d2"), "--out", str(tmp_path / "s.yaml"),
                    "--anchor-layout", "strict")
    assert code == 2 and "conflicting anchors" in err and "'per-run'" in err
    code, err = run("calibrate", str(tmp_path / "d1"), "--out", str(tmp_path / "s.yaml"), "--layout-from", "1",
                    "--anchor-layout", "first")
    assert code == 2 and "--layout-from needs --anchor-layout per-run" in err
    code, err = run("calibrate", str(tmp_path / "d1"), "--out", str(tmp_path / "s.yaml"), "--path-kind", "spline")
    assert code == 2 and "--path-kind" in err


def test_cli_calibrate_end_to_end(roundtrip, tmp_path, capsys):
    _, traces, _ = roundtrip
    write_dataset(tmp_path / "ds", traces[:3])
    out, rep = tmp_path / "new" / "sub" / "cal.yaml", tmp_path / "other" / "fit.json"  # parents made, as generate's
    cli_main(["calibrate", str(tmp_path / "ds"), "--out", str(out), "--report", str(rep), "--name", "mine", "-q",
              "--tag-pattern", "--run-slopes"])
    assert sorted(p.name for p in out.parent.iterdir()) == ["cal.yaml"]  # written atomically: no temp file left
    scn = load_scenario(out)
    assert scn.name == "mine" and str(tmp_path / "ds") in scn.provenance["datasets"]
    report = json.loads(rep.read_text())
    assert report["parameters"]["uwb.time_offset_s"]["value"] == pytest.approx(0.12, abs=0.01)
    # --tag-pattern: the pattern is applied exactly when the fit keeps it (a cable car never turns: not kept)
    assert report["tag_pattern"]["applied"] == report["tag_pattern"]["kept"]
    assert scn.uwb.tag_pattern_m == pytest.approx(report["tag_pattern"]["coef_m"], abs=1e-4)
    # --run-slopes: the tilt spread is generated exactly when the fit finds one (one preset: none)
    sl = report["run_slopes"]
    assert sl["applied"] == (sl["identifiable"] and sl["significant"])
    assert scn.uwb.run_slope_std_m == (pytest.approx(sl["run_slope_std_m"], abs=1e-4) if sl["applied"] else 0.0)
    # generate accepts the file directly
    cli_main(["generate", "-s", str(out), "-n", "1", "--seed", "1", "--out", str(tmp_path / "gen"), "-q"])
    assert (tmp_path / "gen" / "dataset.json").is_file()


def _imu_only_lab() -> Trace:
    """A lab trial: truth and IMU samples (white densities 0.05 / 0.08 / 0.12), no UWB, no anchors."""
    d = roundtrip_dict()
    d["imu"] = {"white_noise_density_mps2_per_sqrt_hz": [0.05, 0.08, 0.12], "bias_rw_mps2_per_sqrt_s": 0.0,
                "vibration": {"amplitude_mps2": 0.0}}
    lab = generate_trace(compile_scenario(scenario_from_dict(d, "lab")), 0, 3)
    return Trace(truth=lab.truth, imu=lab.imu, anchors=Anchors(ids=(), pos_enu_m=np.zeros((0, 3))),
                 uwb=Uwb(t_s=np.array([]), anchor=np.array([], np.int16), range_m=np.array([])),
                 meta={"run": "lab"})


def test_imu_only_recording_joins_a_uwb_calibration(roundtrip):
    """A UWB recording without IMU plus an IMU-only recording (e.g. a lab trial): the IMU noise comes
    from the second, everything else from the first."""
    scn, traces, _ = roundtrip
    uwb_only = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, meta={**t.meta, "run": f"uwb{i}"})
                for i, t in enumerate(traces[:2])]
    imu_only = _imu_only_lab()
    res = calibrate([*uwb_only, imu_only])
    assert res.report["imu_only_recordings"] == ["lab"]
    assert res.scenario.anchor_ids == scn.anchor_ids
    # white density from the high band of the error PSD of ~40,000 samples: a few % of the true value
    np.testing.assert_allclose(res.scenario.imu.white_noise_density_mps2_per_sqrt_hz, [0.05, 0.08, 0.12], rtol=0.1)
    alone = calibrate([imu_only])  # IMU recordings alone: an IMU-only scenario (no anchors)
    assert alone.scenario.anchors == [] and alone.report["imu_only_recordings"] == ["lab"]
    # one recording along a path shows no run-to-run deformation: none is written, as for UWB runs (the
    # path fit's cable default, 2 m lateral and 1 m sag, used to be)
    assert alone.report["parameters"]["motion.in_place"]["value"] is False
    assert (alone.scenario.path.perturbation.lateral_std_m, alone.scenario.path.perturbation.sag_std_m) == (0.0, 0.0)
    assert alone.report["parameters"]["path.perturbation.sag_std_m"]["value"] == 0.0
    assert "path.perturbation (one run; set to 0)" in alone.report["not_identifiable"]


def test_runs_with_moved_anchors_and_the_progress_protocol():
    # two runs of one site whose anchors were re-placed in between: each run is taken against its own
    # layout, the channel is recovered, the scenario keeps the first layout and records both
    from helpers import simple_scenario

    kw = {"channel.los_mean_m": 0.1, "channel.los_std_m": 0.05}
    a = simple_scenario(**kw)
    b = simple_scenario(**kw, anchors=[{"id": "A1", "pos_enu_m": [60, -25, 2]}, {"id": "A2", "pos_enu_m": [140, 25, 4]},
                                       {"id": "A3", "pos_enu_m": [240, -25, 2]}])
    traces = [generate_trace(a, 0, 5), generate_trace(b, 1, 5)]
    traces = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, meta=t.meta) for t in traces]  # UWB only
    calls = []
    res = calibrate(traces, progress=lambda msg, done=None, total=None: calls.append((msg, done, total)))
    s = res.scenario
    for anchor in s.anchors:
        np.testing.assert_allclose(anchor.pos_enu_m, a.anchors[[x.id for x in a.anchors].index(anchor.id)].pos_enu_m)
    assert len(s.provenance["anchor_layout"]["layouts"]) == 2
    n = sum(int(t.uwb.valid.sum()) for t in traces) / 3  # rows per anchor
    for aid in s.anchor_ids:
        c = s.channel_for(aid)
        # mean error at a mid range: intercept and slope of a line through n rows, about 2 sigma / sqrt(n)
        mid = float(los_error_mean(np.array(50.0), c.los_mean_m, c.range_bias_per_m, c.range_bias_per_decade_m))
        assert mid == pytest.approx(0.1, abs=5 * 2 * 0.05 / np.sqrt(n))
        assert c.los_std_m == pytest.approx(0.05, rel=5 / np.sqrt(2 * n))
    # progress(message, done, total): every step announced, counts never run backwards
    assert len(calls) >= 6 and all(isinstance(m, str) and 0 <= d < t for m, d, t in calls)
    assert [d for _, d, _ in calls] == sorted(d for _, d, _ in calls)


@pytest.mark.parametrize("law", ["log", "linear"])
def test_range_bias_law_recovered(law):
    """Data whose LOS bias grows with log10 of the range (the received-power bias) or linearly (a clock-scale
    error): the calibration with the matching law recovers the slope within its regression standard error,
    and the other term stays 0."""
    from helpers import simple_scenario

    truth = {"log": ("range_bias_per_decade_m", 0.25), "linear": ("range_bias_per_m", 0.004)}[law]
    scn = simple_scenario(**{"channel.los_mean_m": -0.1, "channel.los_std_m": 0.05, f"channel.{truth[0]}": truth[1]})
    traces = [generate_trace(scn, i, 9) for i in range(2)]
    traces = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, meta=t.meta) for t in traces]  # UWB only
    res = calibrate(traces, range_bias_law=law)
    other = "range_bias_per_m" if law == "log" else "range_bias_per_decade_m"
    for aid in res.scenario.anchor_ids:
        c = res.scenario.channel_for(aid)
        se = res.report["parameters"][f"channel_per_anchor.{aid}.{truth[0]}"]["std_error"]
        assert getattr(c, truth[0]) == pytest.approx(truth[1], abs=5 * se)
        assert getattr(c, other) == 0.0


def test_log_law_on_linear_data_is_worse_than_linear_law():
    """The law is a model choice the data can refute: on data whose bias is linear in r over 10-300 m,
    the log law leaves a range-dependent mean error that the linear law does not."""
    from helpers import simple_scenario

    scn = simple_scenario(**{"channel.los_std_m": 0.02, "channel.range_bias_per_m": 0.004})
    t = generate_trace(scn, 0, 3)
    t = Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, meta=t.meta)
    ok = t.uwb.valid
    r, anchor = t.uwb.true_range_m[ok], t.uwb.anchor[ok]
    err = t.uwb.range_m[ok] - r
    misfit = {}
    for law in ("log", "linear"):
        s = calibrate(t, range_bias_law=law).scenario
        pred = np.empty_like(r)
        for k, aid in enumerate(t.anchors.ids):
            c = s.channel_for(aid)
            pred[anchor == k] = los_error_mean(r[anchor == k], c.los_mean_m, c.range_bias_per_m,
                                               c.range_bias_per_decade_m)
        misfit[law] = float(np.sqrt(np.mean((err - pred) ** 2)))
    assert misfit["linear"] < 0.025  # the LOS noise (0.02 m) and little else
    assert misfit["log"] > 1.5 * misfit["linear"], misfit  # measured: 0.086 against 0.020 m
    assert np.all(np.isfinite(range_decades(np.array([0.0, 1.0]))))  # a zero range does not make -inf


def test_the_summary_keeps_parameter_names_whole_in_80_columns(roundtrip, tmp_path, capsys, monkeypatch):
    from physynth.cli.calibrate import print_summary

    _, _, res = roundtrip
    monkeypatch.setenv("COLUMNS", "80")
    print_summary(res, tmp_path / "cal.yaml", None)
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80
    keys = [k for k, _, _ in res.summary_rows()]
    assert any(len(k) > 30 for k in keys)  # long keys exist, and each stays on one line
    for k in keys:
        assert any(k in line for line in lines), k
    for _, value, _ in res.summary_rows():  # values unbroken too (three-axis values wrapped into 10 columns)
        assert any(value in line for line in lines), value


def test_the_summary_prints_fields_then_diagnostics_and_options_not_parameters(roundtrip, tmp_path, capsys):
    from physynth.calibrate import CalibrationResult
    from physynth.cli.calibrate import print_summary

    _, _, res = roundtrip
    note = "availability.long_outage_* (fitted and reported; not generated unless long_outages=True)"
    print_summary(CalibrationResult(scenario=res.scenario, report={**res.report, "not_identifiable": [note]}),
                   tmp_path / "cal.yaml", None)
    out = " ".join(capsys.readouterr().out.split())  # lines wrapped at the terminal's width
    assert "not generated unless --long-outages" in out and "long_outages=True" not in out
    fields, diagnostics = out.split("fit diagnostics (not in the scenario)")
    assert "path.rmse_m" in diagnostics and "path.rmse_m" not in fields and "path.kind" in fields


def test_a_wide_terminal_keeps_the_table(roundtrip, tmp_path, capsys, monkeypatch):
    from physynth.cli.calibrate import print_summary

    _, _, res = roundtrip
    monkeypatch.setenv("COLUMNS", "200")
    print_summary(res, tmp_path / "cal.yaml", None)
    out = capsys.readouterr().out
    assert "uncertainty / samples" in out and max(len(line) for line in out.splitlines()) <= 200


def test_gross_ranges_are_left_out_and_counted_not_fitted_as_a_mode():
    import dataclasses

    from physynth.calibrate.uwb_fit import GROSS_RESIDUAL_M

    scn = load_scenario("walk-hanyang")
    # without its IMU samples: the UWB fit does not use them (the same scenario but for its imu section, and
    # the same gross_residuals report and warnings about them, checked for both calibrations)
    clean = dataclasses.replace(generate_trace(scn, 0, 3), imu=None)
    r = clean.uwb.range_m.copy()
    rows = np.flatnonzero(np.isfinite(r))[100:111]
    r[rows] = 65535.0  # a radio's "no range" code, 11 rows
    dirty = dataclasses.replace(clean, uwb=dataclasses.replace(clean.uwb, range_m=r))
    res = calibrate([dirty])  # it used to fit an NLOS mode at 65529 m, outside the scenario's bounds
    sec = res.report["gross_residuals"]
    assert list(sec["per_run"].values()) == [11] and sec["limits_m"] == list(GROSS_RESIDUAL_M)
    assert any("11 range(s)" in w for w in res.report["warnings"])
    ref = calibrate([clean])
    assert res.scenario.uwb.time_offset_s == pytest.approx(ref.scenario.uwb.time_offset_s, abs=2e-3)
    assert max(m.mean_m for m in res.scenario.channel.nlos_modes) < GROSS_RESIDUAL_M[1]


@pytest.mark.parametrize(("kwargs", "match"), [({"range_bias": "static"}, "needs static_sweeps"),
                                               ({"static_sweeps": "/no/such/folder"}, "does not exist"),
                                               ({"range_bias_law": "cubic"}, "unknown range-bias law")])
def test_option_mistakes_are_refused_before_any_fitting(kwargs, match):
    ticks = []
    trace = generate_trace(load_scenario("walk-hanyang"), 0, 1)
    with pytest.raises(CalibrationError, match=match):
        calibrate([trace], progress=lambda msg, *_: ticks.append(msg), **kwargs)
    assert ticks == []


def _written(scn, key: str):
    """The value of a dotted report key in the scenario as written to YAML (KeyError: not there)."""
    node = scenario_to_dict(scn)
    for part in key.split("."):
        node = node[part]
    if key.endswith("nlos_modes"):
        node = [[m["weight"], m["mean_m"], m["std_m"]] for m in node]
    return node


def test_report_values_are_the_scenario_as_written(roundtrip):
    """Every report entry is a scenario field whose value is the one written (the fit's own number kept as
    ``fitted`` with ``why`` where they differ), or a diagnostic marked ``field: false``; the summary's first
    table shows only fields, as written."""
    _, _, res = roundtrip
    fields = 0
    for key, item in res.report["parameters"].items():
        assert isinstance(item["field"], bool), key
        if not item["field"]:  # not in the scenario, or a per-anchor override left unset
            try:
                value = _written(res.scenario, key)
            except (KeyError, TypeError):
                continue
            assert value is None and key.startswith(("channel_per_anchor.", "availability_per_anchor.")), key
            continue
        fields += 1
        assert item["value"] == _written(res.scenario, key), key
        assert ("fitted" in item) == ("why" in item), key
    assert fields > 30 and not res.report["parameters"]["path.rmse_m"]["field"]
    shown = {k: v for k, v, _ in res.summary_rows()}
    assert "path.rmse_m" not in shown and "path.rmse_m" in {k for k, _, _ in res.summary_rows(fields=False)}
    los = res.report["parameters"]["channel_per_anchor.A1.los_std_m"]
    assert shown["channel_per_anchor.A1.los_std_m"] == f"{los['value']:.4g}"  # the YAML's, not the fit's
    # the pooled availability the scenario writes is reported
    pooled = res.scenario.availability
    assert res.report["parameters"]["availability.dropout_prob"]["value"] == pooled.dropout_prob


def test_a_per_anchor_override_left_unset_is_no_field():
    from physynth.calibrate.report_fields import reconcile_parameters

    written = {"availability": {"dropout_prob": 0.01}, "availability_per_anchor": {"A1": {"dropout_prob": None}},
               "path": {"length_m": None}}
    report = {"parameters": {"availability_per_anchor.A1.dropout_prob": {"value": 0.02},
                             "availability_per_anchor.A2.dropout_prob": {"value": 0.03},
                             "availability.dropout_prob": {"value": 0.0100001},
                             "path.length_m": {"value": 202.3}, "path.rmse_m": {"value": 0.03}}}
    p = reconcile_parameters(report, written)["parameters"]
    assert [p[k]["field"] for k in p] == [False, False, True, True, False]
    assert p["availability.dropout_prob"] == {"value": 0.01, "field": True}  # rounding only: no fitted
    assert p["path.length_m"]["value"] is None and p["path.length_m"]["fitted"] == 202.3
    assert "along the path" in p["path.length_m"]["why"]
    assert p["availability_per_anchor.A1.dropout_prob"]["value"] == 0.02  # a diagnostic keeps the fit's value


def test_options_that_change_nothing_say_so_once_each(tmp_path):
    from physynth.cli._common import cli_words

    res = calibrate([_imu_only_lab()], static_sweeps=tmp_path, link_budget=True, trusted_truth=True, run_slopes=True,
                    tag_pattern=True, long_outages=True)
    warnings = res.report["warnings"]
    for word, flag in (("static_sweeps", "--static-sweeps"), ("link_budget=True", "--link-budget"),
                       ("trusted_truth=True", "--trusted-truth"), ("run_slopes=True", "--run-slopes"),
                       ("tag_pattern=True", "--tag-pattern"), ("long_outages=True", "--long-outages")):
        said = [w for w in warnings if w.startswith(f"{word} has no effect")]
        assert len(said) == 1 and "IMU only" in said[0], word
        assert cli_words(said[0]).startswith(f"{flag} has no effect")
    assert not any("has no effect" in w for w in calibrate([_imu_only_lab()]).report.get("warnings", []))


def test_one_run_says_run_slopes_need_runs_trusted_truth_needs_untrusted_truth_and_claims_no_deformation(roundtrip):
    _, traces, _ = roundtrip
    res = calibrate(traces[:1], run_slopes=True, trusted_truth=True, range_bias_law="linear")
    notes = [w for w in res.report["warnings"] if "has no effect" in w]
    assert len(notes) == 2
    assert notes[0].startswith("run_slopes=True has no effect with one run")
    assert notes[1].startswith("trusted_truth=True has no effect: no recording marks")
    # one run of a polynomial (cable) path: no run-to-run deformation claimed, as for any path kind
    assert res.scenario.path.kind == "polynomial"
    assert res.scenario.path.perturbation.lateral_std_m == 0.0 and res.scenario.path.perturbation.sag_std_m == 0.0
    assert "path.perturbation (one run; set to 0)" in res.report["not_identifiable"]


def test_csv_recordings_are_named_by_their_recording_and_a_layout_chosen_by_that_name(tmp_path):
    """CSV recordings carry their folder name as ``recording``: the runs are labelled by it, and
    ``layout_from`` takes it with or without the dataset's name."""
    from helpers import simple_scenario

    from physynth.workflows import calibrate_datasets, read_recordings

    a = simple_scenario()
    b = simple_scenario(anchors=[{"id": "A1", "pos_enu_m": [60, -25, 2]}, {"id": "A2", "pos_enu_m": [140, 25, 4]},
                                 {"id": "A3", "pos_enu_m": [240, -25, 2]}])
    traces = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, meta={"source": "csv", "recording": f"r{i}"})
              for i, t in enumerate([generate_trace(a, 0, 5), generate_trace(b, 1, 5)])]
    write_dataset(tmp_path / "lay", traces)
    labels = [t.meta["label"] for t in read_recordings(tmp_path / "lay")[0]]
    assert labels == ["lay/r0", "lay/r1"]
    res = calibrate_datasets(tmp_path / "lay", layout_from="r1")
    assert res.report["anchor_layout"]["generation_layout"] == "lay/r1"
    assert res.scenario.anchors[0].pos_enu_m == [60.0, -25.0, 2.0]
    with pytest.raises(CalibrationError, match="layout_from='r2' names no recording; the recordings are lay/r0"):
        calibrate_datasets(tmp_path / "lay", layout_from="r2")


def test_anchor_layout_first_is_per_run_with_the_first_layout_and_the_help_says_so(capsys):
    from helpers import simple_scenario

    from physynth.calibrate import anchor_layout

    a = simple_scenario()
    b = simple_scenario(anchors=[{"id": "A1", "pos_enu_m": [60, -25, 2]}, {"id": "A4", "pos_enu_m": [140, 25, 4]}])
    traces = [generate_trace(a, 0, 5), generate_trace(b, 1, 5)]
    first, d_first = anchor_layout(traces, policy="first")
    per_run, d_per_run = anchor_layout(traces, policy="per-run")
    assert first == per_run and d_first["conflicts"] == d_per_run["conflicts"] != []
    assert cli_main(["calibrate", "--help"]) in (0, None)
    text = " ".join(capsys.readouterr().out.split())
    assert "first: the same as per-run with the first dataset's layout" in text
    assert "former behaviour" not in text


def test_a_body_frame_imu_beside_uwb_is_said_to_keep_its_defaults():
    scn = load_scenario("walk-hanyang")  # ENU and body-frame IMU, with UWB
    res = calibrate([generate_trace(scn, 0, 2)])
    notes = [n for n in res.report["not_identifiable"] if n.startswith("body_imu")]
    assert len(notes) == 1 and "only when every recording is IMU-only" in notes[0]
    assert res.scenario.body_imu == type(res.scenario.body_imu)()  # the defaults, as the note says
