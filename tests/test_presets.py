"""The shipped presets land on the paper's REAL columns (Tables I-II) with 20 generated traces.

Tolerances are the issue's: IMU std per axis within 3 %, duration within 5 %, every other metric
within 15 %. Seed 2026 is fixed; the expected values were checked on 150 traces (README).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from physynth.evaluate.metrics import compute_metrics
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import list_presets, load_scenario

REAL = {
    "cablecar-descending": {
        "duration_s": 102.1, "uwb_ge1_frac": 0.178, "uwb_ge2_frac": 0.112, "residual_std_m": 7.485,
        "residual_median_m": 0.947, "abs_residual_p95_m": 18.12, "abs_residual_p99_m": 21.29, "mean_aoi_s": 14.6,
        "imu_std_mps2": (1.616, 0.880, 1.066),
    },
    "cablecar-ascending": {
        "duration_s": 113.1, "uwb_ge1_frac": 0.183, "uwb_ge2_frac": 0.127, "residual_std_m": 0.407,
        "residual_median_m": 0.235, "abs_residual_p95_m": 0.830, "abs_residual_p99_m": 1.208, "mean_aoi_s": 14.6,
    },
}


@pytest.fixture(scope="module", params=sorted(REAL))
def preset_metrics(request):
    cs = compile_scenario(load_scenario(request.param))
    return request.param, compute_metrics([generate_trace(cs, i, 2026) for i in range(20)])


def test_presets_are_listed():
    assert {"cablecar-descending", "cablecar-ascending"} <= set(list_presets())


def test_preset_lands_on_the_real_column(preset_metrics):
    name, m = preset_metrics
    real = REAL[name]
    assert m.duration_s == pytest.approx(real["duration_s"], rel=0.05)
    for key in ("uwb_ge1_frac", "uwb_ge2_frac", "residual_std_m", "residual_median_m", "abs_residual_p95_m",
                "abs_residual_p99_m", "mean_aoi_s"):
        assert getattr(m, key) == pytest.approx(real[key], rel=0.15), key
    if "imu_std_mps2" in real:
        assert m.imu_std_mps2 == pytest.approx(real["imu_std_mps2"], rel=0.03)


def test_descending_preset_matches_the_paper_layout():
    s = load_scenario("cablecar-descending")
    assert s.anchor_ids == ("A101", "A103", "A105", "A106", "A107", "A108")
    assert s.path.length_m == pytest.approx(710.2)
    assert len(s.uwb.zones) >= 1
    assert s.imu.white_noise_density_mps2_per_sqrt_hz == [0.161, 0.086, 0.106]
    assert (s.availability.dropout_prob, s.availability.outage_onset_prob, s.availability.outage_mean_s) == (
        0.04, 0.003, 16.0)
    for a in s.anchor_ids:
        assert 17.0 <= s.channel_for(a).rate_hz <= 20.0


# ------------------------------------------------------------------ presets calibrated on real recordings
SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
HANYANG_A = SHARED / "hanyang-uwb" / "Dynamic_measurements"
BROAD = SHARED / "broad-imu" / "data_mat"
needs_hanyang = pytest.mark.skipif(not HANYANG_A.is_dir(), reason=f"real Hanyang data not found at {HANYANG_A}")
needs_broad = pytest.mark.skipif(not BROAD.is_dir(), reason=f"real BROAD data not found at {BROAD}")


def test_real_presets_generate_what_they_describe():
    import numpy as np

    walk = generate_trace(load_scenario("walk-hanyang"), 0, 2026)
    assert walk.anchors.ids == ("A3", "A5", "A9", "A12") and np.isfinite(walk.uwb.range_m).mean() > 0.5
    assert walk.imu.acc_mps2 is not None and walk.imu.gyro_body_radps is not None
    speed = np.linalg.norm(walk.truth.vel_enu_mps[:, :2], axis=1)
    assert 0.8 < np.median(speed[speed > 0.3]) < 2.0  # a walk (m/s)
    hand = generate_trace(load_scenario("handheld-broad"), 0, 2026)
    assert len(hand.anchors) == 0 and len(hand.uwb) == 0 and hand.imu.gyro_body_radps is not None
    travel = np.ptp(hand.truth.pos_enu_m, axis=0)
    assert np.all(travel < 5.0) and np.std(hand.imu.acc_body_mps2[:, 2]) > 0.3  # shaken in place (m, m/s^2)


@needs_hanyang
def test_walk_preset_records_the_layouts_of_its_runs():
    import numpy as np

    from physynth.io.importers import import_hanyang
    from physynth.models.variation import recorded_layouts

    scn = load_scenario("walk-hanyang")
    lays = recorded_layouts(scn.provenance, scn.anchor_ids)
    real = [import_hanyang(HANYANG_A / env / "Trajectory_A" / case, crop_to_uwb=True)[0].anchors.pos_enu_m
            for env in ("LOS", "NLOS") for case in ("Case_1", "Case_2")]
    assert len(lays) == 4 and all(np.allclose(a, b, atol=1e-3) for a, b in zip(lays, real, strict=True))


@needs_hanyang
def test_walk_preset_reproduces_a_run_it_was_calibrated_on(tmp_path):
    from physynth.io import write_dataset
    from physynth.io.importers import import_hanyang
    from physynth.workflows import validate_datasets

    trace, _ = import_hanyang(HANYANG_A / "NLOS" / "Trajectory_A" / "Case_2", crop_to_uwb=True)
    write_dataset(tmp_path / "real", [trace], meta={"kind": "real", "source": "hanyang-uwb"})
    rep = validate_datasets(tmp_path / "real", scenario="walk-hanyang", n=4, seed=1, transfer=True)
    assert rep.ks_statistic <= 0.10  # issue 12's target for a run, met on the runs without an offset
    assert abs(rep.comparison["uwb_ge1_frac"]["deviation"]) <= 15.0  # per cent


@needs_broad
def test_handheld_preset_reproduces_a_trial_it_was_calibrated_on(tmp_path):
    import numpy as np

    from physynth.io import write_dataset
    from physynth.io.importers import import_broad
    from physynth.workflows import validate_datasets

    trace, _ = import_broad(BROAD / "15_undisturbed_fast_translation_A.mat")
    write_dataset(tmp_path / "real", [trace], meta={"kind": "real", "source": "broad-imu"})
    rep = validate_datasets(tmp_path / "real", scenario="handheld-broad", n=2, seed=1, transfer=True).to_dict()
    dev = rep["relative_deviation_pct"]
    assert np.all(np.abs(dev["imu_error_std_mps2"]) <= 20.0) and np.all(np.abs(dev["acc_body_error_std_mps2"]) <= 20.0)
    assert np.all(np.abs(dev["gyro_error_std_radps"]) <= 30.0)
