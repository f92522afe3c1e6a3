"""IMU-only recordings from the command line (issue 12 item 4): calibrate a BROAD trial, validate
another with --transfer, read the documented IMU keys of report.json."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from helpers import run_cli as run

from physynth.io.scenario_file import load_scenario

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad-imu" / "data_mat"
T10 = DATA / "10_undisturbed_slow_translation_A.mat"
T21 = DATA / "21_undisturbed_fast_combined.mat"
pytestmark = pytest.mark.skipif(not T21.is_file(), reason=f"real BROAD data not found at {DATA}")


def test_calibrate_and_validate_imu_only_datasets(tmp_path, capsys):
    for name, f in (("b10", T10), ("b21", T21)):
        code, _, err = run(capsys, "import", "broad", f, "--out", tmp_path / name, "--quiet")
        assert code == 0, err
    code, _, err = run(capsys, "calibrate", tmp_path / "b10", "--out", tmp_path / "s.yaml", "--report",
                       tmp_path / "r.json", "--quiet")
    assert code == 0, err
    scn = load_scenario(tmp_path / "s.yaml")
    assert scn.anchors == [] and scn.imu_frames == ["enu-gravity-free", "body-flu"]
    assert 0.0015 < scn.imu.time_offset_s < 0.0035  # the IMU lags the optical truth (~2.5 ms)
    assert 11.0 <= scn.imu.truth_cutoff_hz <= 16.0  # the band where the optical truth follows the IMU
    assert 5e-3 < scn.imu.lever_arm_m[2] < 16e-3  # the sensor ~1 cm above the optical origin
    assert scn.body_imu.lever_arm_m == scn.imu.lever_arm_m  # one sensor: the body fit takes the same point
    assert scn.motion.dwell_start_s > 20  # rest phases of the trial, from the truth
    raw = yaml.safe_load((tmp_path / "s.yaml").read_text(encoding="utf-8"))
    assert raw["path"]["kind"] == "waypoints"
    code, out, err = run(capsys, "validate", "--real", tmp_path / "b21", "--scenario", tmp_path / "s.yaml",
                         "--transfer", "-n", 2, "--seed", 3, "--out", tmp_path / "rep", "--no-figures")
    assert code == 0, err
    rep = json.loads((tmp_path / "rep" / "report.json").read_text(encoding="utf-8"))
    assert rep["kind"] == "imu"
    for side in ("real", "synthetic"):
        assert len(rep[side]["imu_error_std_mps2"]) == 3 and len(rep[side]["gyro_error_std_radps"]) == 3
    real, synth = rep["real"]["imu_error_std_mps2"], rep["synthetic"]["imu_error_std_mps2"]
    dev = rep["relative_deviation_pct"]["imu_error_std_mps2"]
    assert dev == pytest.approx([100 * (s / r - 1) for r, s in zip(real, synth, strict=True)])
    assert len(rep["extended"]["imu_log_spectral_distance_db"]["per_axis"]) == 3
    assert len(rep["extended"]["imu_allan_ratio"]["ratio"]) == 4
    assert (tmp_path / "rep" / "report.md").is_file() and (tmp_path / "rep" / "report.html").is_file()
    assert "imu_error_std_mps2" in out
    lines = out.splitlines()  # the summary: each per-axis metric in lines that fit 80 columns
    assert max(len(line) for line in lines if not line.startswith("wrote ")) <= 79, out  # (the path it names)
    i = lines.index("  imu_error_std_mps2 (E/N/U)")
    assert lines[i + 1].split()[1:] == [f"{x:.3f}" for x in real]
    assert lines[i + 2].split()[1:4] == [f"{x:.3f}" for x in synth]
    assert lines[i + 2].split()[-3:] == [f"{x:+.1f}" for x in dev]
    assert not list((tmp_path / "rep").glob("*.png"))  # --no-figures
    # the report folder is PhySynth's own: --overwrite replaces it (it was refused before it was marked);
    # with figures: the error spectra and Allan deviations, real against synthetic, also in the pages
    code, _, err = run(capsys, "validate", "--real", tmp_path / "b21", "--scenario", tmp_path / "s.yaml",
                       "--transfer", "-n", 2, "--seed", 3, "--out", tmp_path / "rep", "--overwrite")
    assert code == 0, err
    for name in ("imu_error_psd.png", "imu_error_allan.png"):
        assert (tmp_path / "rep" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({name})" in (tmp_path / "rep" / "report.md").read_text(encoding="utf-8")
    assert (tmp_path / "rep" / "report.html").read_text(encoding="utf-8").count("data:image/png;base64,") == 2
    code, _, err = run(capsys, "validate", "--real", tmp_path / "b21", "--scenario", tmp_path / "s.yaml",
                       "--transfer", "-n", 2, "--seed", 3, "--out", tmp_path / "rep", "--no-figures", "--overwrite")
    assert code == 0, err
    assert not list((tmp_path / "rep").glob("*.png"))  # the earlier report's figures do not stay behind
    # generation from the IMU-only scenario (no anchors): traces without UWB rows
    code, _, err = run(capsys, "generate", "--scenario", tmp_path / "s.yaml", "-n", 1, "--seed", 1,
                       "--out", tmp_path / "g", "--quiet")
    assert code == 0, err


def test_imu_only_validation_against_a_dataset_without_imu_is_one_clear_error(tmp_path, capsys):
    code, _, err = run(capsys, "import", "broad", T10, "--out", tmp_path / "b10", "--quiet")
    assert code == 0, err
    code, _, err = run(capsys, "generate", "-n", 1, "--seed", 1, "--out", tmp_path / "g", "--quiet")
    assert code == 0, err
    import pyarrow.parquet as pq

    # a synthetic dataset whose IMU table is empty: nothing to compare
    table = pq.read_table(tmp_path / "g" / "imu.parquet")
    pq.write_table(table.slice(0, 0), tmp_path / "g" / "imu.parquet")
    import json

    meta = json.loads((tmp_path / "g" / "dataset.json").read_text())
    del meta["files"]  # a dataset written without integrity records (older PhySynth): read as it is
    (tmp_path / "g" / "dataset.json").write_text(json.dumps(meta))
    code, _, err = run(capsys, "validate", "--real", tmp_path / "b10", "--synthetic", tmp_path / "g",
                       "--out", tmp_path / "rep", "--no-figures")
    assert code == 2 and "no IMU error of a kind" in err and "Traceback" not in err
    assert err.strip().count("\n") == 0


def test_run_spreads_of_very_different_runs_are_clipped_and_said():
    """Slow and fast lab trials driven along one fitted path differ in speed by more than a scenario can
    draw (uniform half-width of the cruise speed 1.10 over the four shared trials): the spread is
    clipped to 0.9 with a warning, not refused by the scenario's bounds."""
    from physynth.calibrate import fit_motion
    from physynth.calibrate.geometry import MAX_RUN_SPREAD_FRAC, spread_clip_warnings
    from physynth.io.importers import import_broad

    fit = fit_motion([import_broad(f)[0] for f in sorted(DATA.glob("*.mat"))])
    assert fit.params.cruise_speed_spread_frac == MAX_RUN_SPREAD_FRAC
    clip = fit.diagnostics["spread_clipped"]
    assert "cruise_speed_spread_frac" in clip["fields"] and clip["raw"][0] > MAX_RUN_SPREAD_FRAC
    assert any("cruise_speed_spread_frac" in w and "clipped" in w for w in spread_clip_warnings(fit.diagnostics))


def test_calibrating_every_trial_together_moves_in_place_with_their_spread_of_intensity(tmp_path, capsys):
    """The four shared trials (slow, fast, disturbed) calibrate together from the command line: a motion
    in place whose jitter spreads in intensity as the trials do, with no folded path's speed spread to
    clip (the previous test)."""
    dirs = []
    for i, f in enumerate(sorted(DATA.glob("*.mat"))):
        code, _, err = run(capsys, "import", "broad", f, "--out", tmp_path / f"b{i}", "--quiet")
        assert code == 0, err
        dirs.append(tmp_path / f"b{i}")
    code, _, err = run(capsys, "calibrate", *dirs, "--out", tmp_path / "s.yaml", "--report", tmp_path / "r.json",
                       "--quiet")
    assert code == 0, err
    scn = load_scenario(tmp_path / "s.yaml")
    rep = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    assert rep["parameters"]["motion.in_place"]["value"] is True
    assert scn.motion.jitter.active and scn.motion.jitter.intensity_log_std > 0.3
    assert scn.motion.cruise_speed_spread_frac < 0.5  # the trials' durations (184-194 s) barely differ
    assert not any("clipped" in w for w in rep.get("warnings", []))
