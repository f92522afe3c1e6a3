"""Link-budget calibration: recovers known parameters from simulated powers and detections; on the
Hanyang static sweeps it finds the receiver's saturation and the ground-reflection nulls."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

from physynth.calibrate.link_budget import (
    fit_detection_vs_distance,
    fit_link_budget_hanyang_static,
    fit_path_loss,
    path_loss_model,
)
from physynth.errors import PhySynthError

STATIC = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb" / "Static_measurements"


def test_path_loss_fit_recovers_the_law():
    rng = np.random.default_rng(4)
    d = np.tile(np.arange(2.0, 62.0, 2.0), 6)
    h = np.repeat([0.5, 0.75, 1.0, 1.5, 1.75, 2.0], 30)
    truth = np.array([-45.0, 2.2, 0.5, -70.0])
    p = path_loss_model(truth, d, h, 1.0, 0.0462) + 0.5 * rng.standard_normal(d.size)
    fit = fit_path_loss(d, h, p)
    assert fit.tag_height_fitted and fit.tag_height_m == pytest.approx(1.0, abs=0.05)
    assert fit.path_loss_exponent == pytest.approx(2.2, abs=0.1)
    assert fit.ref_power_dbm == pytest.approx(-45.0, abs=1.5)
    assert fit.ground_reflection == pytest.approx(0.5, abs=0.1)
    assert fit.saturation_dbm == pytest.approx(-70.0, abs=0.5)
    assert fit.shadowing_std_db == pytest.approx(0.5, rel=0.3)
    with pytest.raises(PhySynthError, match="at least 6 positions"):
        fit_path_loss(d[:3], h[:3], p[:3])
    with pytest.raises(PhySynthError, match="tag_height_m must be positive"):
        fit_path_loss(d, h, p, tag_height_m=0.0)


def test_path_loss_fit_finds_the_tag_height_from_the_nulls_and_a_wrong_fixed_one_costs():
    """The nulls lie where 2 h_anchor h_tag / d is a whole number of wavelengths: sweeps over several
    anchor heights give the tag height back; holding it at a wrong value leaves a larger misfit."""
    rng = np.random.default_rng(7)
    d = np.tile(np.arange(2.0, 62.0, 2.0), 7)
    h = np.repeat([0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0], 30)
    truth = np.array([-55.0, 2.0, 0.55, -81.0])
    p = path_loss_model(truth, d, h, 0.7, 0.0462) + 0.5 * rng.standard_normal(d.size)
    fit = fit_path_loss(d, h, p)
    assert fit.tag_height_m == pytest.approx(0.7, abs=0.03)
    assert fit.ground_reflection == pytest.approx(0.55, abs=0.1)
    assert fit.rms_db == pytest.approx(0.5, rel=0.2)
    held = fit_path_loss(d, h, p, tag_height_m=1.0)
    assert not held.tag_height_fitted and held.tag_height_m == 1.0
    assert held.rms_db > 2.0 * fit.rms_db


def test_detection_fit_recovers_the_sensitivity_and_bounds_it_without_losses():
    rng = np.random.default_rng(5)
    power = np.linspace(-70.0, -100.0, 31)
    m = np.full(power.size, 400)
    k = rng.binomial(m, ndtr((power + 90.0) / 3.0))
    fit = fit_detection_vs_distance(power, k, m, shadowing_std_db=3.0)
    assert fit.sensitivity_dbm == pytest.approx(-90.0, abs=0.5)
    assert fit.sensitivity_upper_95_dbm > fit.sensitivity_dbm
    none_lost = fit_detection_vs_distance(power[:5], m[:5], m[:5], shadowing_std_db=3.0)
    assert none_lost.sensitivity_dbm is None
    # every position detected at p >= 0.95 is compatible with the bound
    assert ndtr((power[4] - none_lost.sensitivity_upper_95_dbm) / 3.0) > 0.95


@pytest.mark.skipif(not STATIC.is_dir(), reason=f"real Hanyang static sweeps not found at {STATIC}")
def test_hanyang_static_link_budget():
    params, rep = fit_link_budget_hanyang_static(STATIC / "LOS", environment="LOS")  # LOS files only
    pl = rep["path_loss"]
    assert -82.0 < pl["saturation_dbm"] < -79.0  # the DW1000 first-path power tops out near -80 dBm
    assert 0.1 < pl["ground_reflection"] < 0.9  # the interference nulls of the two-ray term are real
    assert pl["shadowing_std_db"] < 3.0
    assert rep["detection"]["n_detected"] / rep["detection"]["n_attempts"] > 0.97  # measured 0.975
    # the deepest nulls lose rows: the sensitivity is found, a few dB below the -81 dBm plateau and
    # within the powers the law predicts at the weakest positions
    assert rep["note"] == "sensitivity from the detection losses"
    assert rep["weakest_mean_power_dbm"] - 3.0 < params.sensitivity_dbm < -90.0
    assert rep["n_positions_losing_half"] >= 1
    assert max(rep["mean_power_of_positions_losing_half_dbm"]) < -90.0  # they lie in predicted nulls
    # the nulls put the tag antenna about 0.9 m above the ground, and with it the law is free space
    assert 0.8 < pl["tag_height_m"] < 1.0 and pl["tag_height_fitted"]
    assert params.tag_height_m == pytest.approx(pl["tag_height_m"], abs=1e-3)  # carried into a scenario
    assert 1.7 < pl["path_loss_exponent"] < 2.3
    _, held = fit_link_budget_hanyang_static(STATIC / "LOS", environment="LOS", tag_height_m=1.0)
    assert pl["rms_db"] < 0.75 * held["path_loss"]["rms_db"]  # measured 1.30 against 2.61 dB


def test_sensitivity_from_detection_rate_against_distance_of_a_recording():
    """Without received power: detections per distance bin of generated traces give back the sensitivity."""
    from helpers import simple_scenario

    from physynth.calibrate.link_budget import detection_counts_vs_distance
    from physynth.generate import compile_scenario, generate_trace

    lb = {"ref_power_dbm": -40.0, "path_loss_exponent": 2.0, "sensitivity_dbm": -80.0, "shadowing_std_db": 3.0}
    scn = simple_scenario(**{"path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [400, 0, 1]],
                                      "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}},
                             "anchors": [{"id": "A1", "pos_enu_m": [0, 0, 1]}], "channel.link_budget": lb})
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 21) for i in range(4)]
    centre, det, exp = detection_counts_vs_distance(traces, "A1", nominal_rate_hz=20.0, bin_m=10.0)
    assert det[0] / exp[0] > 0.9 and det[-1] / exp[-1] < 0.1
    fit = fit_detection_vs_distance(-40.0 - 20 * np.log10(np.maximum(centre, 1.0)), det, exp, shadowing_std_db=3.0)
    assert fit.sensitivity_dbm == pytest.approx(-80.0, abs=1.0)


def test_link_detection_from_recordings_gives_the_sensitivity_back():
    """Losses along the truth of generated walks past three anchors with one link budget (ground term
    on, the tag antenna's height set): the sensitivity and fading come back, told apart from a constant
    loss rate, and a wrong tag height fits worse."""
    from dataclasses import replace

    from helpers import simple_scenario

    from physynth.calibrate.link_budget import PathLossFit, fit_link_detection
    from physynth.generate import compile_scenario, generate_trace

    lb = {"ref_power_dbm": -40.0, "path_loss_exponent": 2.0, "sensitivity_dbm": -80.0, "shadowing_std_db": 3.0,
          "ground_reflection": 0.5, "tag_height_m": 1.0}
    scn = simple_scenario(**{"path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1.2], [300, 0, 1.2]],
                                      "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}},
                             "anchors": [{"id": "A1", "pos_enu_m": [0, 0, 1.5]}, {"id": "A2", "pos_enu_m": [150, 5, 1]},
                                         {"id": "A3", "pos_enu_m": [300, -5, 2]}],
                             "channel.link_budget": lb})
    cs = compile_scenario(scn)
    traces = [generate_trace(cs, i, 23) for i in range(3)]
    law = PathLossFit(ref_power_dbm=-40.0, path_loss_exponent=2.0, ground_reflection=0.5, saturation_dbm=0.0,
                      shadowing_std_db=0.0, wavelength_m=0.0462, tag_height_m=1.0, tag_height_fitted=False,
                      rms_db=0.0, n_positions=0)
    fit = fit_link_detection(traces, law)
    assert fit["identifiable"] and fit["likelihood_ratio"] > 100.0
    # bursts every anchor missed are unseen (the tag looks silent): a small bias, inside 1 dB here
    assert fit["sensitivity_dbm"] == pytest.approx(-80.0, abs=1.0)
    assert fit["shadowing_std_db"] == pytest.approx(3.0, rel=0.25)
    assert max(fit["baseline_miss"].values()) < 0.02
    wrong = fit_link_detection(traces, replace(law, tag_height_m=2.0))
    assert wrong["likelihood_ratio"] < fit["likelihood_ratio"]


@pytest.mark.skipif(not STATIC.is_dir(), reason=f"real Hanyang static sweeps not found at {STATIC}")
def test_hanyang_link_budget_for_the_dynamic_runs_finds_the_weak_placement():
    """On the four shared walks the losses follow the power the static law predicts, and in the two runs
    where anchor A5 stands at 1.39 m it is the anchor the budget expects to lose most."""
    from scipy.special import ndtr

    from physynth.calibrate.link_budget import PathLossFit, burst_link_rows, link_budget_for_runs
    from physynth.io.importers import import_hanyang

    dyn = STATIC.parent / "Dynamic_measurements"
    runs = [import_hanyang(dyn / env / "Trajectory_A" / case, crop_to_uwb=True)[0]
            for env in ("LOS", "NLOS") for case in ("Case_1", "Case_2")]
    params, mean_det, rep = link_budget_for_runs(runs, STATIC)
    assert params is not None and rep["detection"]["likelihood_ratio"] > 100.0  # measured 407
    assert 0.8 < params.tag_height_m < 1.0 and set(mean_det) == {"A3", "A5", "A9", "A12"}
    law = PathLossFit(**rep["static"]["path_loss"])
    checked = 0
    for tr in runs:
        p, _, idx = burst_link_rows(tr, law)
        det = ndtr((p - params.sensitivity_dbm) / params.shadowing_std_db)
        low = {aid: np.quantile(det[idx == i], 0.05) for i, aid in enumerate(tr.anchors.ids)}
        if abs(tr.anchors.pos_enu_m[tr.anchors.index("A5"), 2] - 1.39) < 0.01:
            assert low["A5"] < min(v for k, v in low.items() if k != "A5"), low
            checked += 1
    assert checked == 2


@pytest.mark.skipif(not STATIC.is_dir(), reason=f"real Hanyang static sweeps not found at {STATIC}")
def test_calibrate_with_link_budget_puts_it_on_every_anchor_and_takes_its_losses_out_of_the_dropouts():
    from physynth.calibrate import CalibrationError, calibrate
    from physynth.io.importers import import_hanyang

    dyn = STATIC.parent / "Dynamic_measurements"
    runs = [import_hanyang(dyn / "LOS" / "Trajectory_A" / "Case_2", crop_to_uwb=True)[0],
            import_hanyang(dyn / "NLOS" / "Trajectory_A" / "Case_1", crop_to_uwb=True)[0]]
    with pytest.raises(CalibrationError, match="link_budget=True needs static_sweeps"):
        calibrate(runs, link_budget=True)
    res = calibrate(runs, link_budget=True, static_sweeps=STATIC)
    scn, lb = res.scenario, res.report["link_budget"]
    assert lb["applied"]
    budgets = [scn.channel_per_anchor[a].link_budget for a in ("A3", "A5", "A9", "A12")]
    assert all(b is not None and b == budgets[0] for b in budgets)
    assert budgets[0].tag_height_m == pytest.approx(lb["static"]["path_loss"]["tag_height_m"], abs=1e-3)
    for aid, before in lb["dropout_prob_before"].items():
        after = scn.availability_per_anchor[aid].dropout_prob
        m = lb["mean_detection_per_anchor"][aid]
        assert after == pytest.approx(max(0.0, 1.0 - (1.0 - before) / m), abs=1e-6)
        assert after <= before
        # what a dropout probability of 0 cannot take out is reported, and only then
        left = lb["link_loss_not_compensated"][aid]
        assert left == pytest.approx(max(0.0, (1.0 - before) - m), abs=1e-6)
        assert (left > 0) == (after == 0.0 and m < 1.0 - before)
    # the report says what the scenario holds, under the scenario's names: the lowered dropouts (the fit's
    # own beside them, and why), the per-anchor outages the scenario pools (re-placed anchors) as diagnostics
    p = res.report["parameters"]
    assert not any(k.startswith("availability.per_anchor.") for k in p)
    for aid in lb["dropout_prob_before"]:
        item = p[f"availability_per_anchor.{aid}.dropout_prob"]
        assert item["field"] and item["value"] == scn.availability_per_anchor[aid].dropout_prob
        assert "fitted" not in item or "link budget" in item["why"]
        assert not p[f"availability_per_anchor.{aid}.outage_onset_prob"]["field"]
    assert any("link budget" in p[f"availability_per_anchor.{a}.dropout_prob"].get("why", "")
               for a in lb["dropout_prob_before"])
