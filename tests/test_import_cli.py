"""``physynth import {csv,hanyang,broad}``: exit codes, one-line errors, dataset.json contents."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
HANYANG = DATA / "hanyang-uwb" / "Dynamic_measurements"
BROAD15 = DATA / "broad-imu" / "data_mat" / "15_undisturbed_fast_translation_A.mat"


def write_rec(folder: Path, *, range_col: str = "range_m") -> Path:
    """A small recording: 3 anchors, a tag walking east at 1 m/s for 5 s, 10 Hz truth and ranges."""
    folder.mkdir(parents=True)
    anchors = {"A1": (0.0, 0.0, 2.0), "A2": (10.0, 0.0, 2.0), "A3": (0.0, 10.0, 2.0)}
    (folder / "anchors.csv").write_text(
        "anchor_id,e_m,n_m,u_m\n" + "".join(f"{a},{e},{n},{u}\n" for a, (e, n, u) in anchors.items()))
    t = [round(0.1 * k, 1) for k in range(51)]
    (folder / "truth.csv").write_text("t_s,e_m,n_m,u_m\n" + "".join(f"{x},{x},5.0,1.0\n" for x in t))
    rows = []
    for x in t[1:-1]:
        for j, (a, (e, n, u)) in enumerate(anchors.items()):
            r = ((x - e) ** 2 + (5.0 - n) ** 2 + (1.0 - u) ** 2) ** 0.5
            rows.append(f"{x + 0.002 * j:.3f},{a},{r:.4f}\n")
    (folder / "uwb.csv").write_text(f"t_s,anchor_id,{range_col}\n" + "".join(rows))
    return folder


def test_csv_good_recording(tmp_path, capsys):
    rec = write_rec(tmp_path / "rec")
    out_dir = tmp_path / "ds"
    code, out, err = run_cli(capsys, "import", "csv", str(rec), "--out", str(out_dir))
    assert code == 0, err
    assert "wrote 1 real trace from csv" in out and "uwb.csv: read" in out
    meta = json.loads((out_dir / "dataset.json").read_text())
    assert meta["kind"] == "real" and meta["source"] == "csv"
    assert meta["import_report"][0]["rows_read"]["uwb.csv"] > 0
    assert meta["traces"][0]["source"] == "csv"
    # an existing dataset is not replaced without --overwrite
    code, _, err = run_cli(capsys, "import", "csv", str(rec), "--out", str(out_dir))
    assert code == 2 and "already exists" in err
    code, _, _ = run_cli(capsys, "import", "csv", str(rec), "--out", str(out_dir), "--overwrite", "-q")
    assert code == 0


def test_csv_bad_recording_one_line_exit_2(tmp_path, capsys):
    rec = write_rec(tmp_path / "rec", range_col="range_mm")
    code, out, err = run_cli(capsys, "import", "csv", str(rec), "--out", str(tmp_path / "ds"))
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("physynth: error:") and "range_mm" in err
    assert not (tmp_path / "ds").exists()


def test_csv_bad_recording_subprocess(tmp_path):
    rec = tmp_path / "rec"
    rec.mkdir()
    proc = subprocess.run([sys.executable, "-m", "physynth.cli", "import", "csv", str(rec), "--out",
                           str(tmp_path / "ds")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "missing file anchors.csv" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.skipif(not HANYANG.is_dir(), reason=f"real Hanyang data not found at {HANYANG}")
def test_hanyang_two_runs(tmp_path, capsys):
    runs = [HANYANG / "LOS" / "Trajectory_A" / "Case_1", HANYANG / "NLOS" / "Trajectory_A" / "Case_2"]
    out_dir = tmp_path / "ds"
    code, out, err = run_cli(capsys, "import", "hanyang", *map(str, runs), "--out", str(out_dir))
    assert code == 0, err
    assert "wrote 2 real traces from hanyang-uwb" in out and "not corrected" in out
    meta = json.loads((out_dir / "dataset.json").read_text())
    assert meta["source"] == "hanyang-uwb" and len(meta["import_report"]) == 2
    assert [t["run"] for t in meta["traces"]] == ["LOS/Trajectory_A/Case_1", "NLOS/Trajectory_A/Case_2"]
    assert all(t["uwb_time_lag_applied"] is False for t in meta["traces"])


@pytest.mark.skipif(not HANYANG.is_dir(), reason=f"real Hanyang data not found at {HANYANG}")
@pytest.mark.skipif(not (HANYANG / "LOS" / "Trajectory_A" / "Case_1").is_dir(), reason="Hanyang data not found")
def test_hanyang_note_names_the_option_not_the_parameter(tmp_path, capsys):
    run = HANYANG / "LOS" / "Trajectory_A" / "Case_1"  # its truth continues 2.4 s after the last range
    code, out, err = run_cli(capsys, "import", "hanyang", str(run), "--out", str(tmp_path / "ds"))
    assert code == 0, err
    assert "use --crop-to-uwb to drop it" in out and "crop_to_uwb" not in out


def test_the_same_recording_twice_is_refused(tmp_path, capsys):
    rec = write_rec(tmp_path / "rec")
    for twice in ([str(rec), str(rec)], [str(rec), str(tmp_path / "." / "rec") + "/"]):
        code, _, err = run_cli(capsys, "import", "csv", *twice, "--out", str(tmp_path / "ds"))
        assert code == 2 and err.count("\n") == 1 and "each recording may be imported once" in err
    assert not (tmp_path / "ds").exists()


def test_hanyang_bad_run_folder(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    code, _, err = run_cli(capsys, "import", "hanyang", str(tmp_path / "run"), "--out", str(tmp_path / "ds"))
    assert code == 2 and err.count("\n") == 1 and "no A<id>.csv anchor files" in err


@pytest.mark.skipif(not BROAD15.is_file(), reason=f"real BROAD data not found at {BROAD15}")
def test_broad(tmp_path, capsys):
    out_dir = tmp_path / "ds"
    code, out, err = run_cli(capsys, "import", "broad", str(BROAD15), "--out", str(out_dir))
    assert code == 0, err
    assert "optical_dropout=" in out
    meta = json.loads((out_dir / "dataset.json").read_text())
    assert meta["source"] == "broad" and meta["traces"][0]["gravity_rest_norm_mps2"] > 9.8


def test_broad_bad_file_exit_2(tmp_path, capsys):
    bad = tmp_path / "trial.mat"
    bad.write_text("nope")
    code, _, err = run_cli(capsys, "import", "broad", str(bad), "--out", str(tmp_path / "ds"))
    assert code == 2 and err.count("\n") == 1 and "trial.mat: cannot read MATLAB file" in err


def test_broad_text_sampling_rate_exit_2(tmp_path, capsys):
    from scipy.io import savemat

    bad = tmp_path / "trial.mat"
    savemat(bad, {"imu_acc": np.zeros((20, 3)), "opt_quat": np.tile([1.0, 0, 0, 0], (20, 1)),
                  "opt_pos": np.zeros((20, 3)), "movement": np.zeros(20, np.uint8), "sampling_rate": "abc"})
    code, _, err = run_cli(capsys, "import", "broad", str(bad), "--out", str(tmp_path / "ds"))
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("physynth: error: ") and "sampling_rate is not a number" in err
    assert not (tmp_path / "ds").exists()
