"""Tests of ``physynth validate``: report files, metrics against physynth.metrics, self-consistency,
separation of different scenarios, transfer, the Allan deviation against its analytic laws, and every
bad-input class through the CLI (one line on stderr, exit code 2)."""

from __future__ import annotations

import base64
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import simple_scenario_dict

from physynth.cli import main
from physynth.evaluate.metrics import METRIC_KEYS, compute_metrics
from physynth.evaluate.stats import allan_deviation
from physynth.generate import generate_trace, generate_traces
from physynth.io import DatasetWriter, read_dataset, write_dataset
from physynth.records import Trace, Truth, Uwb
from physynth.scenario import scenario_from_dict
from physynth.validate.compare import EXTENDED_STATISTICS, read_report, typical_value
from physynth.workflows import validate_datasets

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
HANYANG = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "hanyang-uwb"


def _scenario_dict(**updates) -> dict:
    """A short (about 35 s) run past three anchors with every error term on."""
    base = {
        "motion.cruise_speed_mps": 10.0,
        "motion.cruise_speed_spread_frac": 0.1,
        "path.perturbation": {"lateral_std_m": 1.0, "sag_std_m": 0.5},
        "imu.white_noise_density_mps2_per_sqrt_hz": [0.1, 0.06, 0.08],
        "imu.bias_rw_mps2_per_sqrt_s": 0.002,
        "imu.vibration": {"amplitude_mps2": 0.1},
        "channel": {"rate_hz": 15.0, "los_mean_m": 0.05, "los_std_m": 0.1, "nlos_prob": 0.1,
                    "nlos_modes": [{"weight": 1.0, "mean_m": 1.0, "std_m": 0.4}], "max_range_m": 1e6},
        "availability": {"dropout_prob": 0.05, "outage_onset_prob": 0.003, "outage_mean_s": 2.0},
    }
    base.update(updates)
    return simple_scenario_dict(**base)


def _real_meta() -> dict:
    return {"kind": "real", "source": "test"}


def _run(argv: list[str]) -> int:
    try:
        main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A 'real' dataset (one trace), a synthetic dataset (three traces) and scenario files."""
    root = tmp_path_factory.mktemp("validate")
    scn_a = scenario_from_dict(_scenario_dict(), "a")
    write_dataset(root / "real", [generate_trace(scn_a, 0, 101)], meta=_real_meta())
    write_dataset(root / "synth", list(generate_traces(scn_a, 3, seed=7)), meta={"kind": "synthetic"})
    (root / "a.yaml").write_text(yaml.safe_dump(_scenario_dict()), encoding="utf-8")
    far = _scenario_dict(channel={"rate_hz": 15.0, "los_mean_m": 1.5, "los_std_m": 0.6, "nlos_prob": 0.0,
                                  "max_range_m": 1e6})
    (root / "b.yaml").write_text(yaml.safe_dump(far), encoding="utf-8")
    return root


@pytest.fixture(scope="module")
def full_report(data):
    """One complete report through the CLI, with figures."""
    out = data / "report"
    code = _run(["validate", "--real", str(data / "real"), "--scenario", str(data / "a.yaml"), "-n", "3",
                 "--seed", "11", "--out", str(out), "--quiet"])
    assert code == 0
    return out


# ---------------------------------------------------------------- report files
def test_report_files_exist_and_parse(full_report):
    rep = json.loads((full_report / "report.json").read_text())
    for key in ("real", "synthetic", "relative_deviation_pct", "ks_statistic", "extended", "per_anchor"):
        assert key in rep
    assert set(rep["real"]) == set(METRIC_KEYS) | {"per_anchor"}
    assert set(rep["synthetic"]) == set(METRIC_KEYS) | {"per_anchor"}
    assert set(rep["relative_deviation_pct"]) == set(METRIC_KEYS)
    assert set(EXTENDED_STATISTICS) <= set(rep["extended"])
    assert set(rep["per_anchor"]) == {"A1", "A2", "A3"}
    assert 0.0 <= rep["ks_statistic"] <= 1.0
    assert rep["inputs"]["synthetic"]["root_seed"] == 11
    assert rep["inputs"]["n_traces"] == {"real": 1, "synthetic": 3}
    assert read_report(full_report).to_dict() == rep  # matched write/read pair
    scn = yaml.safe_load((full_report / "scenario.yaml").read_text())
    assert scn["name"] == "test-line"

    md = (full_report / "report.md").read_text()
    assert "Table I." in md and "Table II." in md
    for label in ("Duration (s)", "UWB ≥ 1", "UWB ≥ 2", "Residual std", "Residual med.", "P95", "P99",
                  "KS statistic", "Mean AoI", "| East |", "| North |", "| Up |", "| Mean |"):
        assert label in md, label


def test_figures_are_pngs_and_embedded(full_report):
    pngs = sorted(full_report.glob("*.png"))
    names = {p.stem for p in pngs}
    assert {"paths", "speed", "ranges", "residual_cdf", "residual_per_anchor", "availability", "aoi", "outages",
            "imu_spectrum", "allan"} <= names
    html = (full_report / "report.html").read_text()
    embedded = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    assert len(embedded) == len(pngs)
    for p in pngs:
        data = p.read_bytes()
        assert data[:8] == PNG_SIGNATURE and len(data) > 5_000, p.name
        assert base64.b64encode(data).decode() in embedded, p.name
    assert "<table>" in html and "http" not in html.replace("http-equiv", "")  # self-contained
    md = (full_report / "report.md").read_text()
    assert all(f"({p.name})" in md for p in pngs)


def test_metrics_equal_physynth_metrics(data, full_report):
    rep = read_report(full_report)
    real = compute_metrics(read_dataset(data / "real").traces).to_dict()
    assert _same(rep.real, real)
    synth = validate_datasets(data / "real", synthetic=data / "synth").synthetic
    assert _same(synth, compute_metrics(read_dataset(data / "synth").traces).to_dict())


def _same(a, b) -> bool:
    """Equal up to the JSON form (NaN <-> None, tuples <-> lists)."""
    return json.loads(json.dumps(a, allow_nan=True).replace("NaN", "null")) == \
        json.loads(json.dumps(b, allow_nan=True).replace("NaN", "null"))


def test_dataset_against_itself_is_perfect(data):
    rep = validate_datasets(data / "synth", synthetic=data / "synth")
    assert rep.ks_statistic == 0.0
    for key, value in rep.relative_deviation_pct.items():
        expected = [0.0, 0.0, 0.0] if key == "imu_std_mps2" else None if key == "residual_median_m" else 0.0
        assert value == expected, key
    assert rep.comparison["residual_median_m"]["deviation"] == 0.0
    ext = rep.extended
    assert ext["residual_wasserstein_m"] == 0.0
    assert ext["gap_ks_statistic"] == 0.0 and ext["aoi_ks_statistic"] == 0.0
    assert ext["residual_acf_max_abs_diff"] == 0.0 and ext["residual_acf_inliers_max_abs_diff"] == 0.0
    assert np.allclose(ext["imu_allan_ratio"]["ratio"], 1.0)
    assert ext["imu_log_spectral_distance_db"]["mean"] == 0.0
    assert rep.fidelity_score == 0.0
    assert all(d["ks_statistic"] == 0.0 for d in rep.per_anchor.values())


def test_different_scenarios_give_large_ks(data):
    rep = validate_datasets(data / "real", scenario=str(data / "b.yaml"), n=2, seed=3)
    assert rep.ks_statistic > 0.3
    assert rep.extended["residual_wasserstein_m"] > 0.5
    same = validate_datasets(data / "real", scenario=str(data / "a.yaml"), n=2, seed=3)
    assert same.ks_statistic < 0.15 < rep.ks_statistic


def test_no_figures_and_overwrite(data, tmp_path):
    out = tmp_path / "rep"
    args = ["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"), "--out", str(out),
            "--no-figures", "-q"]
    assert _run(args) == 0
    assert not list(out.glob("*.png"))
    assert "data:image/png" not in (out / "report.html").read_text()
    assert _run(args) == 2  # a report is there already
    assert _run(args + ["--overwrite"]) == 0


def test_imu_statistics_left_out_without_real_imu(data, tmp_path):
    tr = read_dataset(data / "real").traces[0]
    no_imu = Trace(truth=tr.truth, uwb=tr.uwb, anchors=tr.anchors, imu=None)
    write_dataset(tmp_path / "real", [no_imu], meta=_real_meta())
    rep = validate_datasets(tmp_path / "real", synthetic=data / "synth")
    assert rep.extended["imu_allan_ratio"] is None
    assert rep.extended["imu_log_spectral_distance_db"] is None
    assert rep.extended["imu_note"] == "the real data has no usable IMU samples"
    from physynth.validate.render import available_figures, render_markdown

    assert "allan" not in available_figures(rep.evidence)
    assert "Table I and the IMU statistics left out: the real data has no usable IMU samples" in render_markdown(rep)


# ---------------------------------------------------------------- transfer
def test_transfer_keeps_parameters_and_takes_geometry(data, tmp_path):
    pytest.importorskip("physynth.calibrate", reason="calibration module not installed")
    from physynth.calibrate import transfer_scenario  # noqa: F401  (the function --transfer uses)

    # the real run: another path, other speed, other anchors (ids and positions)
    other = _scenario_dict(**{
        "path.waypoints_enu_m": [[20, -30, 2], [120, 40, 4], [260, 60, 3]],
        "motion.cruise_speed_mps": 7.0,
        "anchors": [{"id": "B1", "pos_enu_m": [40, 10, 3]}, {"id": "B2", "pos_enu_m": [150, 0, 3]},
                    {"id": "B3", "pos_enu_m": [230, 80, 3]}, {"id": "B4", "pos_enu_m": [100, 80, 3]}],
    })
    real_trace = generate_trace(scenario_from_dict(other, "real"), 0, 5)
    write_dataset(tmp_path / "real", [real_trace], meta=_real_meta())
    scn = scenario_from_dict(_scenario_dict(), "a")

    assert _run(["validate", "--real", str(tmp_path / "real"), "--scenario", str(data / "a.yaml"), "-n", "2",
                 "--out", str(tmp_path / "no-transfer"), "-q", "--no-figures"]) == 2
    rep = validate_datasets(tmp_path / "real", scenario=str(data / "a.yaml"), n=2, seed=4, transfer=True)

    t = rep.transfer
    assert set(t["from_real"]) == {"path", "motion", "anchors", "uwb.burst_phase_s"}
    assert {"imu", "uwb", "channel", "availability"} <= set(t["from_scenario"])
    assert t["unexpected_changes"] == []
    assert t["anchors"]["transferred"] == ["B1", "B2", "B3", "B4"]
    assert t["anchors"]["pooled_channel"] == []  # the scenario has no per-anchor channels: nothing to say
    # a scenario calibrated per anchor on B1 and others: B2-B4 range with its pooled channel, and the report says so
    own = _scenario_dict(anchors=[{"id": "B1", "pos_enu_m": [50, 20, 3]}, {"id": "A2", "pos_enu_m": [150, -20, 3]}],
                         channel_per_anchor={"B1": {"los_std_m": 0.2}, "A2": {"los_std_m": 0.3}})
    per = validate_datasets(tmp_path / "real", scenario=scenario_from_dict(own, "own"), n=1, seed=4, transfer=True)
    assert per.transfer["anchors"]["pooled_channel"] == ["B2", "B3", "B4"]
    from physynth.validate.render import render_markdown

    assert "No channel of their own in the scenario (calibrated on other anchors): B2, B3, B4" in render_markdown(per)
    moved = scenario_from_dict(rep.inputs["synthetic"]["scenario_config"], "transferred")
    # every sensor, channel and availability parameter as in the scenario
    for section in ("imu", "channel", "availability", "truth_rate_hz", "grid_rate_hz"):
        assert getattr(moved, section) == getattr(scn, section), section
    # the UWB acquisition too, but for the burst clock's alignment, which is the real run's
    assert moved.uwb.model_copy(update={"burst_phase_s": None}) == scn.uwb.model_copy(update={"burst_phase_s": None})
    real_start = real_trace.uwb.t_s[0] - real_trace.t0_s
    period = 1.0 / scn.uwb.burst_rate_hz
    assert moved.uwb.burst_phase_s == pytest.approx(real_start % period, abs=0.003)
    for a in moved.anchor_ids:
        assert moved.channel_for(a) == scn.channel
        assert moved.availability_for(a) == scn.availability
    assert moved.path.perturbation == scn.path.perturbation
    # geometry from the real run
    assert moved.anchor_ids == real_trace.anchors.ids
    assert np.allclose([a.pos_enu_m for a in moved.anchors], real_trace.anchors.pos_enu_m)
    gen = generate_trace(moved, 0, rep.inputs["synthetic"]["root_seed"])
    real_pos = real_trace.truth.pos_enu_m
    assert np.linalg.norm(gen.truth.pos_enu_m[0] - real_pos[0]) < 3.0
    assert np.linalg.norm(gen.truth.pos_enu_m[-1] - real_pos[-1]) < 3.0
    assert abs(gen.duration_s - real_trace.duration_s) / real_trace.duration_s < 0.25
    assert rep.real["duration_s"] == pytest.approx(real_trace.duration_s)


@pytest.mark.skipif(not HANYANG.is_dir(), reason=f"real data folder {HANYANG} is absent")
def test_transfer_onto_real_hanyang_run(tmp_path):
    pytest.importorskip("physynth.calibrate", reason="calibration module not installed")
    from physynth.io.importers import import_hanyang

    trace, _ = import_hanyang(HANYANG / "Dynamic_measurements" / "LOS" / "Trajectory_A" / "Case_1")
    write_dataset(tmp_path / "real", [trace], meta={"kind": "real", "source": "hanyang-uwb"})
    rep = validate_datasets(tmp_path / "real", scenario="cablecar-ascending", n=2, seed=1, transfer=True)
    assert rep.transfer["anchors"]["transferred"] == list(trace.anchors.ids)
    assert rep.transfer["unexpected_changes"] == []
    assert rep.real["duration_s"] == pytest.approx(trace.duration_s)
    assert 0.0 <= rep.ks_statistic <= 1.0


# ---------------------------------------------------------------- Allan deviation against analytic laws
def test_allan_deviation_white_noise_and_random_walk():
    rng = np.random.default_rng(0)
    rate, n = 100.0, 200_000
    white = rng.normal(0.0, 0.5, n)
    taus = np.array([0.01, 0.1, 1.0, 10.0])
    adev = allan_deviation(white, rate, taus)
    expected = 0.5 / np.sqrt(taus * rate)  # sigma / sqrt(m)
    assert np.allclose(adev, expected, rtol=0.08)
    k = 0.02  # random-walk density [unit / sqrt(s)]
    walk = np.cumsum(rng.normal(0.0, k / np.sqrt(rate), n))
    adev_rw = allan_deviation(walk, rate, [10.0, 50.0])
    assert np.allclose(adev_rw, k * np.sqrt(np.array([10.0, 50.0]) / 3.0), rtol=0.2)
    assert np.isnan(allan_deviation(white[:100], rate, [1.0])[0])  # too short for 2 tau
    both = allan_deviation(np.stack([white, 2 * white], axis=1), rate, [0.1])
    assert both.shape == (2, 1) and both[1, 0] == pytest.approx(2 * both[0, 0])


# ---------------------------------------------------------------- bad input: one line, exit code 2
def _bad(argv: list[str], capsys, *needles: str) -> str:
    assert _run(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("physynth: error:"), err
    for needle in needles:
        assert needle in err, err
    return err


def test_bad_input_synthetic_scenario_choice(data, tmp_path, capsys):
    base = ["validate", "--real", str(data / "real"), "--out", str(tmp_path / "r"), "-q"]
    _bad(base, capsys, "neither")
    _bad(base + ["--synthetic", str(data / "synth"), "--scenario", str(data / "a.yaml")], capsys, "both")
    _bad(base + ["--synthetic", str(data / "synth"), "--transfer"], capsys, "--transfer needs --scenario")
    _bad(base + ["--scenario", str(data / "a.yaml"), "-n", "0"], capsys, "greater than or equal to 1")
    assert not (tmp_path / "r").exists()


def test_bad_input_mismatched_anchors(data, tmp_path, capsys):
    base = ["validate", "--real", str(data / "real"), "--out", str(tmp_path / "r"), "-q"]
    _bad(base + ["--scenario", "cablecar-descending"], capsys, "anchor ids differ",
         "only in the real dataset: A1, A2, A3", "A101", "--transfer")
    other = scenario_from_dict(_scenario_dict(anchors=[{"id": "A1", "pos_enu_m": [50, 20, 3]},
                                                       {"id": "A9", "pos_enu_m": [150, -20, 3]}]), "o")
    write_dataset(tmp_path / "other", list(generate_traces(other, 1, seed=1)))
    _bad(base + ["--synthetic", str(tmp_path / "other")], capsys, "only in the real dataset: A2, A3",
         "A9")


def test_bad_input_empty_datasets(data, tmp_path, capsys):
    DatasetWriter(tmp_path / "empty", meta=_real_meta()).close()  # a dataset of no traces (write_dataset refuses)
    out = ["--out", str(tmp_path / "r"), "-q"]
    _bad(["validate", "--real", str(tmp_path / "empty"), "--synthetic", str(data / "synth")] + out, capsys,
         "real dataset", "no traces")
    _bad(["validate", "--real", str(data / "real"), "--synthetic", str(tmp_path / "empty")] + out, capsys,
         "synthetic dataset", "no traces")
    tr = read_dataset(data / "real").traces[0]
    silent = Trace(truth=tr.truth, anchors=tr.anchors, imu=tr.imu,
                   uwb=Uwb(t_s=tr.uwb.t_s, anchor=tr.uwb.anchor, range_m=np.full(len(tr.uwb), np.nan)))
    write_dataset(tmp_path / "silent", [silent], meta=_real_meta())
    _bad(["validate", "--real", str(tmp_path / "silent"), "--synthetic", str(data / "synth")] + out, capsys,
         "no valid UWB range")


def test_bad_input_real_without_truth(data, tmp_path, capsys):
    tr = read_dataset(data / "real").traces[0]
    nan = np.full_like(tr.truth.pos_enu_m, np.nan)
    blind = Trace(truth=Truth(t_s=tr.truth.t_s, pos_enu_m=nan, vel_enu_mps=nan), uwb=tr.uwb,
                  anchors=tr.anchors, imu=tr.imu)
    write_dataset(tmp_path / "blind", [blind], meta=_real_meta())
    _bad(["validate", "--real", str(tmp_path / "blind"), "--synthetic", str(data / "synth"), "--out",
          str(tmp_path / "r"), "-q"], capsys, "no ground truth")


def test_bad_input_unreadable_files(data, tmp_path, capsys):
    out = ["--out", str(tmp_path / "r"), "-q"]
    _bad(["validate", "--real", str(tmp_path / "missing"), "--synthetic", str(data / "synth")] + out, capsys,
         "real dataset", "does not exist")
    broken = tmp_path / "broken"
    write_dataset(broken, read_dataset(data / "real").traces, meta=_real_meta())
    (broken / "uwb.parquet").write_bytes(b"not a parquet file")
    _bad(["validate", "--real", str(broken), "--synthetic", str(data / "synth")] + out, capsys,
         "real dataset", "uwb.parquet")
    bad_json = tmp_path / "badjson"
    write_dataset(bad_json, read_dataset(data / "synth").traces)
    (bad_json / "dataset.json").write_text("{ nope", encoding="utf-8")
    _bad(["validate", "--real", str(data / "real"), "--synthetic", str(bad_json)] + out, capsys,
         "synthetic dataset", "dataset.json")
    (tmp_path / "bad.yaml").write_text("name: [unclosed", encoding="utf-8")
    _bad(["validate", "--real", str(data / "real"), "--scenario", str(tmp_path / "bad.yaml")] + out, capsys,
         "bad.yaml")
    _bad(["validate", "--real", str(data / "real"), "--scenario", str(tmp_path / "none.yaml")] + out, capsys,
         "none.yaml")


def test_missing_matplotlib_is_one_clear_line(data, tmp_path, capsys, monkeypatch):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    _bad(["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"), "--out",
          str(tmp_path / "r"), "-q"], capsys, "physynth[report]", "pip install -e '.[report]'", "(--no-figures)")
    assert not (tmp_path / "r").exists()
    assert _run(["validate", "--real", str(data / "real"), "--synthetic", str(data / "synth"), "--out",
                 str(tmp_path / "r"), "-q", "--no-figures"]) == 0


def test_comparison_bands_and_absolute_median(data, full_report):
    rep = json.loads((full_report / "report.json").read_text())
    comp = rep["comparison"]
    assert set(comp) == set(METRIC_KEYS)
    # the signed median is compared by its absolute difference, never by a relative one
    med = comp["residual_median_m"]
    assert med["deviation_kind"] == "absolute" and rep["relative_deviation_pct"]["residual_median_m"] is None
    assert med["deviation"] == pytest.approx(rep["synthetic"]["residual_median_m"] - rep["real"]["residual_median_m"])
    # the band is the 5-95 % of the per-trace metrics of the three synthetic traces (oracle: compute_metrics)
    traces = list(generate_traces(scenario_from_dict(_scenario_dict(), "a"), 3, seed=11))
    for key in ("uwb_ge1_frac", "residual_median_m", "abs_residual_p95_m", "mean_aoi_s"):
        per_trace = [getattr(compute_metrics([t]), key) for t in traces]
        lo, hi = np.percentile(per_trace, [5, 95])
        c = comp[key]
        assert c["band_5_95"] == pytest.approx([lo, hi]), key
        assert c["real_in_band"] == (lo <= rep["real"][key] <= hi), key
        if key != "residual_median_m":
            assert c["deviation_kind"] == "relative_pct"
            assert c["deviation"] == pytest.approx(rep["relative_deviation_pct"][key])
    # the heavy-tailed mean AoI: deviation against the median synthetic run (one real trace), pooled kept
    aoi = comp["mean_aoi_s"]
    typical = float(np.median([compute_metrics([t]).mean_aoi_s for t in traces]))
    assert aoi["typical"] == pytest.approx(typical) and aoi["deviation_against"] == "typical"
    assert aoi["synthetic"] == pytest.approx(compute_metrics(traces).mean_aoi_s)
    assert aoi["deviation"] == pytest.approx(100 * abs(typical - rep["real"]["mean_aoi_s"]) / rep["real"]["mean_aoi_s"])
    assert all("typical" not in comp[k] for k in ("uwb_ge1_frac", "abs_residual_p95_m"))
    # and per anchor: against that anchor's own median synthetic run, the pooled value kept beside it
    pooled = compute_metrics(traces).to_dict()["per_anchor"]
    for a, d in rep["per_anchor"].items():
        own = [compute_metrics([t]).to_dict()["per_anchor"][a]["mean_aoi_s"] for t in traces]
        assert d["typical"]["mean_aoi_s"] == pytest.approx(float(np.median(own))), a
        assert d["synthetic"]["mean_aoi_s"] == pytest.approx(pooled[a]["mean_aoi_s"])
        real = d["real"]["mean_aoi_s"]
        assert d["relative_deviation_pct"]["mean_aoi_s"] == pytest.approx(100 * abs(np.median(own) - real) / real), a
    assert len(comp["imu_std_mps2"]) == 3 and all(len(c["band_5_95"]) == 2 for c in comp["imu_std_mps2"])
    for page in ("report.md", "report.html"):
        text = (full_report / page).read_text()
        assert "Synth 5–95 %" in text and "Real in band" in text, page


def test_summary_fits_80_columns_and_shows_the_typical_mean_aoi(data, tmp_path, capsys):
    """The command's summary: one line per headline metric within 79 characters, the mean AoI against the
    median synthetic run (as Table II), the band and whether the real value is in it."""
    assert _run(["validate", "--real", str(data / "real"), "--scenario", str(data / "a.yaml"), "-n", "3",
                 "--seed", "11", "--out", str(tmp_path / "r"), "--no-figures"]) == 0
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "r" / "report.json").read_text())
    assert max(len(line) for line in out.splitlines() if not line.startswith("wrote ")) <= 79  # (a path)
    for key in ("uwb_ge1_frac", "residual_median_m", "abs_residual_p95_m", "mean_aoi_s"):
        c = rep["comparison"][key]
        words = next(line for line in out.splitlines() if line.startswith(f"  {key} ")).split()
        assert words[2] == f"{rep['real'][key]:.3f}"
        assert words[4] == f"{c.get('typical', rep['synthetic'][key]):.3f}", key
        assert words[-2] == f"{c['band_5_95'][0]:.3f}-{c['band_5_95'][1]:.3f}"
        assert words[-1] == ("in" if c["real_in_band"] else "OUT")
    assert f"pooled over the runs {rep['synthetic']['mean_aoi_s']:.3f} s" in out


def test_typical_value_is_the_median_group_pooled_by_duration():
    per_trace = [{"m": v, "duration_s": d} for v, d in ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (101.0, 1.0))]
    assert typical_value(per_trace, "m", 1) == 1.0  # one rare outlier does not move the typical run
    assert typical_value(per_trace, "m", 2) == pytest.approx(0.5 * (1.0 + 51.0))  # groups [1, 1], [1, 101]
    assert typical_value(per_trace, "m", 4) == pytest.approx(26.0)  # one group: the pooled mean
    assert typical_value(per_trace, "m", 9) == pytest.approx(26.0)  # fewer traces than the real side
    weighted = [{"m": 1.0, "duration_s": 3.0}, {"m": 3.0, "duration_s": 1.0}]
    assert typical_value(weighted, "m", 2) == pytest.approx(1.5)  # a time average weighs by duration
    assert np.isnan(typical_value([], "m", 1))


def test_docs_explain_every_extended_statistic():
    doc = Path(__file__).resolve().parents[1] / "docs" / "validation.md"
    text = doc.read_text(encoding="utf-8")
    for name in EXTENDED_STATISTICS:
        assert f"`{name}`" in text, name


def test_body_imu_errors_compared_when_both_sides_have_them():
    """A UWB + body-IMU validation compares accelerometer and gyroscope errors: doubling the gyro's
    white noise (which dominates its 400 Hz error) doubles its error std (+100 %, within the sampling
    spread of ~125k samples per axis: well under 2 %), and leaves the accelerometer's alone."""
    from physynth.generate import compile_scenario, generate_trace
    from physynth.io.scenario_file import load_scenario
    from physynth.validate.compare import compare
    from physynth.validate.render import render_markdown

    body = load_scenario("cablecar-descending").model_copy(update={"imu_frames": ["enu-gravity-free", "body-flu"]})
    gyro = body.body_imu.gyroscope
    noisy = body.model_copy(update={"body_imu": body.body_imu.model_copy(update={"gyroscope": gyro.model_copy(
        update={"noise_density_radps_per_sqrt_hz": 2.0 * gyro.noise_density_radps_per_sqrt_hz})})})
    real = compile_scenario(body)
    rep = compare((generate_trace(real, i, 1) for i in range(2)),
                  (generate_trace(compile_scenario(noisy), i, 2) for i in range(2)))
    dev = rep.imu_errors["relative_deviation_pct"]
    assert all(95.0 < d < 105.0 for d in dev["gyro_error_std_radps"]), dev
    assert all(abs(d) < 5.0 for d in dev["acc_body_error_std_mps2"]), dev
    assert rep.imu_errors["real"]["imu_error_std_mps2"] is None  # the ENU side is Table I's job
    assert rep.imu_errors["extended"]["gyro_allan_ratio"]["tau_s"] == [0.01, 0.1, 1.0, 10.0]
    assert "## IMU errors: real vs synthetic" in render_markdown(rep)
    back = type(rep).from_dict(json.loads(rep.to_json()))
    assert back.imu_errors == json.loads(rep.to_json())["imu_errors"]

    enu = compile_scenario(load_scenario("cablecar-descending"))
    rep2 = compare([generate_trace(enu, 0, 1)], [generate_trace(real, 0, 2)])
    assert rep2.imu_errors is None  # only one side has a body IMU
    assert "IMU errors" not in render_markdown(rep2)


def test_cli_prints_body_imu_error_deviations(tmp_path, capsys):
    from physynth.generate import compile_scenario
    from physynth.io.scenario_file import load_scenario

    cs = compile_scenario(load_scenario("cablecar-descending").model_copy(
        update={"imu_frames": ["enu-gravity-free", "body-flu"]}))
    write_dataset(tmp_path / "r", [generate_trace(cs, 0, 1)])
    write_dataset(tmp_path / "s", [generate_trace(cs, 0, 2)])
    capsys.readouterr()
    assert main(["validate", "--real", str(tmp_path / "r"), "--synthetic", str(tmp_path / "s"),
                 "--no-figures", "--out", str(tmp_path / "rep")]) in (0, None)
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    lines = out.splitlines()
    i = lines.index("  gyro_error_std_radps (x/y/z)")
    assert lines[i + 2].split()[-3:] == [f"{x:+.1f}" for x in rep["imu_errors"]["relative_deviation_pct"]
                                         ["gyro_error_std_radps"]], out
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["imu_errors"] is not None


def test_inlier_autocorrelation_tells_a_slow_error_from_a_white_one(tmp_path):
    """Same LOS spread, one slow (antenna sway) and one white: residual_acf_inliers sees the difference,
    and computed by hand on the traces it agrees with the report."""
    from helpers import simple_scenario

    from physynth.generate import generate_traces
    from physynth.io import write_dataset
    from physynth.validate.evidence import INLIER_HALF_WIDTH_M

    slow = simple_scenario(**{"uwb.antenna_sway_std_m": 0.06, "uwb.antenna_sway_tau_s": 2.0,
                              "channel.los_std_m": 0.02, "channel.nlos_prob": 0.1,
                              "channel.nlos_modes": [{"weight": 1.0, "mean_m": 5.0, "std_m": 1.0}]})
    white = simple_scenario(**{"channel.los_std_m": float(np.hypot(0.06, 0.02)), "channel.nlos_prob": 0.1,
                               "channel.nlos_modes": [{"weight": 1.0, "mean_m": 5.0, "std_m": 1.0}]})
    write_dataset(tmp_path / "slow", list(generate_traces(slow, 2, seed=1)), meta={"kind": "synthetic"})
    rep = validate_datasets(tmp_path / "slow", scenario=white, n=2, seed=2)
    a = rep.extended["residual_acf_inliers"]
    assert a["real"][0] > 0.8 and a["synthetic"][0] < 0.2  # 20 Hz bursts: the sway barely moves in 0.05 s
    assert rep.extended["residual_acf_inliers_max_abs_diff"] > 0.6
    assert rep.extended["residual_acf"]["real"][0] < a["real"][0]  # the 5 m outliers mask it in residual_acf
    # by hand on one anchor of the slow side: consecutive inliers, the anchor's mean removed
    from physynth.evaluate.metrics import residuals

    t = next(generate_traces(slow, 1, seed=1))
    r, idx, _ = residuals(t)
    x = r[idx == 1]
    x = x[np.abs(x - np.median(x)) < INLIER_HALF_WIDTH_M]
    x = x - x.mean()
    assert float(x[1:] @ x[:-1] / (x @ x)) == pytest.approx(a["real"][0], abs=0.05)


def test_still_correlation_tells_an_error_that_follows_the_motion_from_one_that_follows_the_clock(tmp_path):
    """Stops of 20 s at both ends: on the distance clock the sway holds while the tag stands (still
    correlation near 1: only the 2 mm white rest moves), on the time clock (tau 2 s) pairs 1-3 s apart
    keep exp(-1 / 2)-exp(-3 / 2) of it; both fade alike while the tag walks 1 m/s."""
    from helpers import simple_scenario

    from physynth.generate import generate_traces
    from physynth.io import write_dataset

    def scenario(clock: str):
        return simple_scenario(**{"uwb.antenna_sway_std_m": 0.06, "uwb.antenna_sway_clock": clock,
                                  "uwb.antenna_sway_tau_s": 2.0, "uwb.antenna_sway_length_m": 2.0,
                                  "channel.los_std_m": 0.002, "motion.cruise_speed_mps": 1.0,
                                  "motion.dwell_start_s": 20.0, "motion.dwell_end_s": 20.0})

    write_dataset(tmp_path / "motion", list(generate_traces(scenario("distance"), 2, seed=1)),
                  meta={"kind": "synthetic"})
    rep = validate_datasets(tmp_path / "motion", scenario=scenario("time"), n=2, seed=2)
    sc = rep.extended["residual_still_correlation"]
    assert sc["still"]["real"] > 0.95  # the distance clock: held while standing
    assert 0.1 < sc["still"]["synthetic"] < 0.7  # the time clock: exp(-dt / 2 s) over 1-3 s, and pairs apart
    for side in ("real", "synthetic"):  # 1-3 m walked over 1-3 s, length or tau 2: both about exp(-1)
        assert 0.1 < sc["moving"][side] < 0.7
