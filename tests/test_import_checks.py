"""Unit and sanity checks of the Hanyang and BROAD importers, on corrupted copies of the real files.

Each copy is one mistake a user or a broken logger makes (a column in mm, deg/s, g units, a text cell, a
truncated row or file, an empty file...): it is either one clear RecordingError naming the file and the
problem (exit 2 and one line from the CLI), or imported with the coerced cells counted in the report.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import copy_hanyang_run, edit_csv_columns, run_cli
from scipy.io import loadmat, savemat

from physynth.errors import RecordingError
from physynth.io.importers import import_broad, import_hanyang

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
LOS1 = DATA / "hanyang-uwb" / "Dynamic_measurements" / "LOS" / "Trajectory_A" / "Case_1"
BROAD = DATA / "broad-imu" / "data_mat"
TRIAL10 = BROAD / "10_undisturbed_slow_translation_A.mat"
hanyang_data = pytest.mark.skipif(not LOS1.is_dir(), reason=f"real Hanyang data not found at {LOS1}")
broad_data = pytest.mark.skipif(not TRIAL10.is_file(), reason=f"real BROAD data not found at {TRIAL10}")


# --------------------------------------------------------------------------------------------------
# Hanyang
# --------------------------------------------------------------------------------------------------


def _set_cell(path: Path, row: int, col: int, value: str) -> None:
    lines = path.read_text().splitlines()
    p = lines[row].split(",")
    p[col] = value
    lines[row] = ",".join(p)
    path.write_text("\n".join(lines) + "\n")


@hanyang_data
@pytest.mark.parametrize(("file", "cols", "scale", "needle"), [
    ("trajectory.csv", [1, 2, 3], 1000.0, r"A3\.csv: the ranges are .* times the distances .* positions in "
                                          r"millimetres"),
    ("A9.csv", [3, 4, 5], 100.0, r"A9\.csv: the ranges are .* times the distances .* positions in millimetres "
                                 r"or centimetres"),
    ("A5.csv", [6], 100.0, r"A5\.csv: .*(ranges in millimetres or centimetres|implausible for metres)"),
    ("trajectory.csv", [0], 1e-9, r"trajectory\.csv: timestamp values around .* are not Unix nanoseconds"),
    ("A12.csv", [1], 1e-6, r"A12\.csv: field\.stamp values around .* are not Unix nanoseconds"),
])
def test_hanyang_column_in_another_unit(tmp_path, file, cols, scale, needle):
    run = copy_hanyang_run(LOS1, tmp_path)
    edit_csv_columns(run / file, cols, lambda v: repr(float(v) * scale))
    with pytest.raises(RecordingError, match=needle):
        import_hanyang(run)


@hanyang_data
def test_hanyang_coerced_cells_are_counted(tmp_path):
    real, real_report = import_hanyang(LOS1)
    run = copy_hanyang_run(LOS1, tmp_path)
    _set_cell(run / "A5.csv", 5, 6, "n/a")  # range not a number: kept as an invalid attempt
    _set_cell(run / "A5.csv", 6, 6, "65535")  # a radio's error code: no geometry explains it
    _set_cell(run / "A5.csv", 7, 1, "abc")  # stamp not a number: the row cannot be placed in time
    _set_cell(run / "A5.csv", 8, 3, "?")  # anchor x not a number: the position comes from the other rows
    _set_cell(run / "A5.csv", 9, 4, "inf")
    _set_cell(run / "A5.csv", 10, 2, "")  # field.id empty
    _set_cell(run / "trajectory.csv", 12, 2, "bad")  # a truth coordinate not a number
    lines = (run / "A9.csv").read_text().splitlines()
    lines[20] = lines[20][:30]  # truncated row
    lines.insert(30, "")  # empty row
    (run / "A9.csv").write_text("\n".join(lines) + "\n")
    trace, report = import_hanyang(run)
    assert report.flagged["A5.csv"] == {"nan_range": 1, "implausible_range": 1}
    assert report.dropped["A5.csv"] == {"nan_time": 1}
    assert report.repaired["A5.csv"] == {"field.id_empty": 1, "anchor_xyz_not_a_number": 2}
    assert report.dropped["trajectory.csv"] == {"nan_value": 1}
    assert report.dropped["A9.csv"] == {"empty_row": 1, "truncated_row": 1}
    assert "A3.csv" not in report.dropped and "A3.csv" not in report.flagged
    assert len(trace.uwb) == len(real.uwb) - 2  # the stamp-less and the truncated row
    assert int((~trace.uwb.valid).sum()) == int((~real.uwb.valid).sum()) + 2
    assert trace.truth.t_s.size == real.truth.t_s.size - 1
    np.testing.assert_array_equal(trace.anchors.pos_enu_m, real.anchors.pos_enu_m)
    assert real_report.n_dropped == real_report.n_flagged == real_report.n_repaired == 0


@hanyang_data
@pytest.mark.parametrize("file", ["A3.csv", "trajectory.csv"])
def test_hanyang_empty_and_header_only_files(tmp_path, file):
    run = copy_hanyang_run(LOS1, tmp_path)
    (run / file).write_text("")
    with pytest.raises(RecordingError, match=rf"{file}: empty file or no header row"):
        import_hanyang(run)
    header = (LOS1 / file).read_text().splitlines()[0]
    (run / file).write_text(header + "\n")
    needle = "no coordinates" if file == "A3.csv" else "no data rows"
    with pytest.raises(RecordingError, match=rf"{file}: .*{needle}"):
        import_hanyang(run)


@hanyang_data
def test_hanyang_cli_counts_and_one_line_errors(tmp_path, capsys):
    run = copy_hanyang_run(LOS1, tmp_path)
    _set_cell(run / "A5.csv", 5, 6, "n/a")
    _set_cell(run / "A5.csv", 8, 3, "?")
    code, out, err = run_cli(capsys, "import", "hanyang", str(run), "--out", str(tmp_path / "ds"))
    assert code == 0, err
    assert "A5.csv: read" in out and "repaired anchor_xyz_not_a_number=1" in out and "nan_range=1" in out
    edit_csv_columns(run / "A9.csv", [3, 4, 5], lambda v: repr(float(v) * 1000))
    code, out, err = run_cli(capsys, "import", "hanyang", str(run), "--out", str(tmp_path / "ds2"))
    assert code == 2 and err.count("\n") == 1 and "A9.csv: the ranges are" in err and "Traceback" not in err
    assert not (tmp_path / "ds2").exists()


# --------------------------------------------------------------------------------------------------
# BROAD
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trial10():
    return {k: v for k, v in loadmat(TRIAL10).items() if not k.startswith("__")}


def _variant(tmp_path: Path, mat: dict, **override) -> Path:
    path = tmp_path / TRIAL10.name
    savemat(path, {**mat, **override})
    return path


def _rotate_x90(q: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z) of the same attitudes in a lab frame turned 90 degrees about x."""
    from scipy.spatial.transform import Rotation

    ok = np.all(np.isfinite(q), axis=1)
    out = q.copy()
    turned = Rotation.from_euler("x", 90, degrees=True) * Rotation.from_quat(q[ok], scalar_first=True)
    out[ok] = turned.as_quat(scalar_first=True)
    return out


@broad_data
@pytest.mark.parametrize(("change", "needle"), [
    (lambda m: {"imu_acc": m["imu_acc"] / 9.80665}, r"median \|imu_acc\| 1\.0\d* m/s\^2 is implausible.*not g"),
    (lambda m: {"imu_acc": m["imu_acc"] * 1000}, r"median \|imu_acc\| .* is implausible"),
    # the slow trial's median 0.41 rad/s reads 23 deg/s: only the comparison with the optical rate tells
    (lambda m: {"imu_gyr": np.degrees(m["imu_gyr"])}, r"\|imu_gyr\| is 5\d\.?\d* times the body rate .* deg/s"),
    (lambda m: {"opt_pos": m["opt_pos"] * 1000}, r"opt_pos reaches .* millimetres\? convert to metres"),
    (lambda m: {"opt_quat": m["opt_quat"] * 2}, r"attitude quaternion\(s\) are not unit .* opt_quat"),
    # a y-up optical lab frame (90 degrees about x): gravity at rest along the lab's y, not z
    (lambda m: {"opt_quat": _rotate_x90(m["opt_quat"])}, r"rest-phase specific force .* does not point up"),
    (lambda m: {"sampling_rate": 1.0 / m["sampling_rate"]}, r"sampling_rate 0\.0035 is implausible .* Hz"),
    (lambda m: {"opt_pos": m["opt_pos"][:-10]}, r"opt_pos has shape \(\d+, 3\), expected"),
])
def test_broad_variable_in_another_unit_or_truncated(tmp_path, trial10, change, needle):
    with pytest.raises(RecordingError, match=needle) as exc:
        import_broad(_variant(tmp_path, trial10, **change(trial10)))
    assert str(exc.value).startswith(str(tmp_path / TRIAL10.name))


@broad_data
def test_broad_coerced_samples_are_counted(tmp_path, trial10):
    real, real_report = import_broad(TRIAL10)
    acc, gyr, mov = trial10["imu_acc"].copy(), trial10["imu_gyr"].copy(), trial10["movement"].copy()
    masked = np.isnan(trial10["opt_quat"]).any(axis=1) | np.isnan(trial10["opt_pos"]).any(axis=1)
    i, j, k = np.flatnonzero(~masked)[[100, 200, 300]]
    acc[i, 0] = np.inf
    gyr[j, 1] = np.nan
    mov.reshape(-1)[k] = 7
    trace, report = import_broad(_variant(tmp_path, trial10, imu_acc=acc, imu_gyr=gyr, movement=mov))
    name = TRIAL10.name
    assert report.flagged[name]["nan_imu"] == real_report.flagged[name].get("nan_imu", 0) + 1
    assert report.flagged[name]["nan_gyro"] == 1
    assert report.repaired[name] == {"movement_not_0_or_1": 1}
    assert np.isnan(trace.imu.acc_body_mps2[i, 0]) and np.isnan(trace.imu.acc_mps2[i]).all()
    assert np.isnan(trace.imu.gyro_body_radps[j, 1])
    assert trace.imu.t_s.size == real.imu.t_s.size  # nothing dropped: masked and counted
    assert "nan_gyro" not in real_report.flagged[name] and name not in real_report.repaired


@broad_data
def test_broad_empty_and_truncated_files(tmp_path):
    empty = tmp_path / "empty.mat"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"empty\.mat: cannot read MATLAB file"):
        import_broad(empty)
    cut = tmp_path / "cut.mat"
    raw = TRIAL10.read_bytes()
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(RecordingError, match=r"cut\.mat: (cannot read MATLAB file|missing variable)"):
        import_broad(cut)


@broad_data
def test_broad_cli_one_line_and_counts(tmp_path, capsys, trial10):
    bad = _variant(tmp_path, trial10, imu_gyr=np.degrees(trial10["imu_gyr"]))
    code, _, err = run_cli(capsys, "import", "broad", str(bad), "--out", str(tmp_path / "ds"))
    assert code == 2 and err.count("\n") == 1 and "deg/s" in err and "Traceback" not in err
    gyr = trial10["imu_gyr"].copy()
    gyr[5000, 0] = np.inf
    ok = _variant(tmp_path, trial10, imu_gyr=gyr)
    code, out, err = run_cli(capsys, "import", "broad", str(ok), "--out", str(tmp_path / "ds2"))
    assert code == 0, err
    assert "nan_gyro=1" in out
