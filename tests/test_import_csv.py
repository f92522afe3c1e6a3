"""The generic recording format importer: a good recording, and every class of bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from physynth import Reason
from physynth.errors import RecordingError
from physynth.evaluate.metrics import residuals
from physynth.io.importers import ImportReport, import_csv

T0_UNIX_S = 1_700_000_000.0
RADIUS_M, OMEGA_RADPS = 5.0, 0.5
ANCHORS = {"A1": (-10.0, -10.0, 2.0), "A2": (10.0, -10.0, 2.0), "A3": (10.0, 10.0, 3.0),
           "A4": (-10.0, 10.0, 1.0)}


def circle_motion(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position [m], velocity [m/s] and acceleration [m/s^2] on a horizontal circle at 1 m height."""
    ph = OMEGA_RADPS * t_s
    z = np.zeros_like(t_s)
    pos = np.stack([RADIUS_M * np.cos(ph), RADIUS_M * np.sin(ph), z + 1.0], axis=1)
    vel = RADIUS_M * OMEGA_RADPS * np.stack([-np.sin(ph), np.cos(ph), z], axis=1)
    acc = -RADIUS_M * OMEGA_RADPS**2 * np.stack([np.cos(ph), np.sin(ph), z], axis=1)
    return pos, vel, acc


def make_tables(duration_s: float = 20.0) -> dict[str, pd.DataFrame]:
    """A clean recording: 10 Hz truth, 10 Hz bursts of 4 anchors (2 ms apart), 100 Hz IMU."""
    rng = np.random.default_rng(7)
    anchors = pd.DataFrame({"anchor_id": list(ANCHORS), "e_m": [a[0] for a in ANCHORS.values()],
                            "n_m": [a[1] for a in ANCHORS.values()], "u_m": [a[2] for a in ANCHORS.values()]})
    t_truth = np.arange(0.0, duration_s + 1e-9, 0.1)
    pos, _, _ = circle_motion(t_truth)
    truth = pd.DataFrame({"t_s": T0_UNIX_S + t_truth, "e_m": pos[:, 0], "n_m": pos[:, 1], "u_m": pos[:, 2]})
    t_burst = np.arange(0.05, duration_s - 0.1, 0.1)
    t_uwb = (t_burst[:, None] + 0.002 * np.arange(4)).ravel()
    aid = np.tile(np.arange(4), t_burst.size)
    a_pos = np.array(list(ANCHORS.values()))
    true_r = np.linalg.norm(circle_motion(t_uwb)[0] - a_pos[aid], axis=1)
    uwb = pd.DataFrame({"t_s": T0_UNIX_S + t_uwb, "anchor_id": np.array(list(ANCHORS))[aid],
                        "range_m": true_r + rng.normal(0.0, 0.01, t_uwb.size)})
    t_imu = np.arange(0.0, duration_s, 0.01)
    acc = circle_motion(t_imu)[2]
    imu = pd.DataFrame({"t_s": T0_UNIX_S + t_imu, "acc_e_mps2": acc[:, 0], "acc_n_mps2": acc[:, 1],
                        "acc_u_mps2": acc[:, 2]})
    return {"anchors": anchors, "truth": truth, "uwb": uwb, "imu": imu}


def write_rec(folder: Path, tables: dict[str, pd.DataFrame], *, fmt: str = "csv") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, df in tables.items():
        if fmt == "parquet":
            df.to_parquet(folder / f"{name}.parquet", index=False)
        else:
            df.to_csv(folder / f"{name}.csv", index=False, float_format="%.9f")
    return folder


@pytest.fixture
def tables() -> dict[str, pd.DataFrame]:
    return make_tables()


def test_good_recording(tmp_path, tables):
    rec = write_rec(tmp_path / "rec", tables)
    (rec / "meta.json").write_text(json.dumps({"site": "lab"}))
    trace, report = import_csv(rec)
    assert isinstance(report, ImportReport)
    assert report.n_dropped == 0 and report.n_repaired == 0 and report.n_flagged == 0
    assert trace.truth.t_s[0] == 0.0
    assert trace.meta["time_origin_s"] == pytest.approx(T0_UNIX_S)
    assert trace.meta["recording_meta"] == {"site": "lab"}
    assert trace.anchors.ids == tuple(ANCHORS)
    assert len(trace.uwb) == len(tables["uwb"])
    assert trace.imu is not None and trace.imu.t_s.size == len(tables["imu"])
    # velocity from smoothed differentiation matches the analytic circle velocity
    _, vel, _ = circle_motion(trace.truth.t_s)
    inner = slice(5, -5)
    np.testing.assert_allclose(trace.truth.vel_enu_mps[inner], vel[inner], atol=0.01 * RADIUS_M * OMEGA_RADPS)
    # ranges agree with the geometry: residuals are the 1 cm noise
    r, _, _ = residuals(trace)
    assert r.size == len(tables["uwb"])
    assert abs(np.median(r)) < 0.005 and np.std(r) < 0.02
    # bursts of four anchors found by gap
    assert trace.uwb.burst.max() + 1 == len(tables["uwb"]) // 4
    assert np.all(np.bincount(trace.uwb.burst) == 4)
    d = report.to_dict()
    assert d["rows_read"]["uwb.csv"] == len(tables["uwb"])
    json.dumps(d)


def test_parquet_tables_and_given_velocity(tmp_path, tables):
    pos, vel, _ = circle_motion(tables["truth"]["t_s"].to_numpy() - T0_UNIX_S)
    tables["truth"] = tables["truth"].assign(ve_mps=vel[:, 0], vn_mps=vel[:, 1], vu_mps=vel[:, 2])
    rec = write_rec(tmp_path / "rec", tables, fmt="parquet")
    trace, report = import_csv(rec)
    np.testing.assert_allclose(trace.truth.vel_enu_mps, vel)
    assert trace.meta["truth_velocity"] == "given in truth table"
    assert report.rows_kept["uwb.parquet"] == len(tables["uwb"])


def _error(rec: Path) -> str:
    with pytest.raises(RecordingError) as info:
        import_csv(rec)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_missing_folder(tmp_path):
    assert "does not exist" in _error(tmp_path / "nope")


def test_missing_file(tmp_path, tables):
    del tables["uwb"]
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "missing file uwb.csv" in msg


def test_both_csv_and_parquet(tmp_path, tables):
    rec = write_rec(tmp_path / "rec", tables)
    tables["uwb"].to_parquet(rec / "uwb.parquet")
    assert "both uwb.csv and uwb.parquet" in _error(rec)


def test_missing_column(tmp_path, tables):
    tables["truth"] = tables["truth"].drop(columns="u_m")
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "truth.csv" in msg and "missing column(s) u_m" in msg


def test_incomplete_velocity_columns(tmp_path, tables):
    tables["truth"] = tables["truth"].assign(ve_mps=0.0)
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "truth.csv" in msg and "vn_mps" in msg


def test_range_in_millimetres_by_name(tmp_path, tables):
    tables["uwb"] = tables["uwb"].rename(columns={"range_m": "range_mm"})
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "uwb.csv" in msg and "range_mm is in mm" in msg and "metres" in msg


def test_range_in_millimetres_by_value(tmp_path, tables):
    tables["uwb"]["range_m"] *= 1000.0
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "uwb.csv" in msg and "implausible for metres" in msg


def test_time_in_milliseconds_by_name(tmp_path, tables):
    tables["imu"] = tables["imu"].rename(columns={"t_s": "t_ms"})
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "imu.csv" in msg and "t_ms is in ms" in msg


def test_time_in_nanoseconds_by_value(tmp_path, tables):
    tables["truth"]["t_s"] *= 1e9
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "truth.csv" in msg and "not seconds" in msg


def test_imu_with_gravity(tmp_path, tables):
    tables["imu"]["acc_u_mps2"] += 9.81
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "imu.csv" in msg and "gravity is not removed" in msg


def test_tables_in_different_time_bases(tmp_path, tables):
    tables["uwb"]["t_s"] -= T0_UNIX_S
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "uwb.csv" in msg and "do not overlap" in msg


def test_anchor_without_coordinates(tmp_path, tables):
    tables["anchors"].loc[2, "n_m"] = np.nan
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "anchors.csv" in msg and "A3" in msg and "no coordinates" in msg


def test_unknown_anchor_in_uwb(tmp_path, tables):
    tables["uwb"].loc[5, "anchor_id"] = "A9"
    msg = _error(write_rec(tmp_path / "rec", tables))
    assert "uwb.csv" in msg and "A9" in msg


@pytest.mark.parametrize(("name", "content", "says"), [
    ("truth.csv", b"\xff\xfe\x00garbage\x81\x82", "truth.csv: not a UTF-8 text CSV"),
    ("uwb.csv", b"", "uwb.csv: empty file"),
    ("uwb.parquet", b"not parquet at all", "cannot read Parquet"),
    ("meta.json", b"{not json", "meta.json: not valid JSON"),
], ids=["unreadable_file", "empty_file", "unreadable_parquet", "bad_meta_json"])
def test_a_broken_file_is_named_with_what_is_wrong(tmp_path, tables, name, content, says):
    rec = write_rec(tmp_path / "rec", {k: v for k, v in tables.items() if name != f"{k}.parquet"})  # no CSV beside
    (rec / name).write_bytes(content)
    msg = _error(rec)
    assert name in msg and says in msg


def test_unsorted_rows_are_sorted_and_counted(tmp_path, tables):
    uwb = tables["uwb"]
    tables["uwb"] = pd.concat([uwb.iloc[40:], uwb.iloc[:40]], ignore_index=True)  # one descent
    tables["truth"] = tables["truth"].iloc[::-1]  # every step a descent
    trace, report = import_csv(write_rec(tmp_path / "rec", tables))
    assert report.repaired["uwb.csv"] == {"unsorted_rows": 1}
    assert report.repaired["truth.csv"] == {"unsorted_rows": len(tables["truth"]) - 1}
    assert np.all(np.diff(trace.uwb.t_s) >= 0) and np.all(np.diff(trace.truth.t_s) > 0)
    assert len(trace.uwb) == len(uwb)


def test_duplicates_are_dropped_and_counted(tmp_path, tables):
    uwb = tables["uwb"]
    conflict = uwb.iloc[[20]].assign(range_m=uwb["range_m"].iloc[20] + 1.0)
    tables["uwb"] = pd.concat([uwb, uwb.iloc[[3, 7, 9]], conflict], ignore_index=True)
    tables["truth"] = pd.concat([tables["truth"], tables["truth"].iloc[[10]]], ignore_index=True)
    trace, report = import_csv(write_rec(tmp_path / "rec", tables))
    assert report.dropped["uwb.csv"] == {"duplicate_row": 3, "duplicate_time_conflict": 1}
    assert report.dropped["truth.csv"] == {"duplicate_row": 1}
    assert len(trace.uwb) == len(uwb)
    assert trace.uwb.range_m[20] == pytest.approx(uwb["range_m"].iloc[20])  # the first one is kept


def test_nan_values(tmp_path, tables):
    tables["truth"].loc[[4, 9], "e_m"] = np.nan
    tables["imu"].loc[[1, 2, 3], "acc_n_mps2"] = np.nan
    tables["uwb"].loc[[10, 11], "range_m"] = np.nan
    tables["uwb"].loc[12, "t_s"] = np.nan
    trace, report = import_csv(write_rec(tmp_path / "rec", tables))
    assert report.dropped["truth.csv"] == {"nan_value": 2}
    assert report.dropped["imu.csv"] == {"nan_value": 3}
    assert report.dropped["uwb.csv"] == {"nan_time": 1}
    assert report.flagged["uwb.csv"] == {"nan_range": 2}
    assert trace.truth.t_s.size == len(tables["truth"]) - 2
    assert len(trace.uwb) == len(tables["uwb"]) - 1
    invalid = trace.uwb.reason == Reason.INVALID
    assert invalid.sum() == 2 and np.all(np.isnan(trace.uwb.range_m[invalid]))


def test_non_numeric_range_is_kept_as_invalid(tmp_path, tables):
    rec = write_rec(tmp_path / "rec", tables)
    lines = (rec / "uwb.csv").read_text().splitlines()
    parts = lines[6].split(",")
    lines[6] = ",".join([*parts[:2], "n/a"])
    (rec / "uwb.csv").write_text("\n".join(lines) + "\n")
    trace, report = import_csv(rec)
    assert report.flagged["uwb.csv"] == {"nan_range": 1}
    assert np.count_nonzero(trace.uwb.reason == Reason.INVALID) == 1


def test_negative_ranges(tmp_path, tables):
    tables["uwb"].loc[[1, 50, 51], "range_m"] = -0.4
    trace, report = import_csv(write_rec(tmp_path / "rec", tables))
    assert report.flagged["uwb.csv"] == {"negative_range": 3}
    assert len(trace.uwb) == len(tables["uwb"])
    bad = trace.uwb.reason == Reason.INVALID
    assert bad.sum() == 3 and np.all(np.isnan(trace.uwb.range_m[bad]))
    assert not trace.uwb.valid[bad].any()


def test_a_radio_error_code_is_kept_as_invalid_not_as_a_range(tmp_path, tables):
    tables["uwb"].loc[[3, 40, 41], "range_m"] = 65535.0  # DW1000 firmware's "no range"
    tables["uwb"].loc[[60], "range_m"] = 800.0  # long but possible: kept
    trace, report = import_csv(write_rec(tmp_path / "rec", tables))
    assert report.flagged["uwb.csv"] == {"implausible_range": 3}
    bad = trace.uwb.reason == Reason.INVALID
    assert bad.sum() == 3 and np.all(np.isnan(trace.uwb.range_m[bad])) and len(trace.uwb) == len(tables["uwb"])
    assert np.nanmax(trace.uwb.range_m) == 800.0  # the long row stays a range


def test_truncated_and_blank_rows_are_skipped(tmp_path, tables):
    rec = write_rec(tmp_path / "rec", tables)
    lines = (rec / "uwb.csv").read_text().splitlines()
    lines[5] = lines[5][: lines[5].rindex(",")]  # last field cut off
    lines[9] = lines[9].split(",")[0]  # only the time
    lines.insert(20, "")
    lines.insert(30, "1.0,A1,2.0,extra")
    (rec / "uwb.csv").write_text("\n".join(lines) + "\n")
    trace, report = import_csv(rec)
    assert report.dropped["uwb.csv"] == {"empty_row": 1, "truncated_row": 2, "malformed_row": 1}
    assert report.rows_read["uwb.csv"] == len(tables["uwb"]) + 2
    assert len(trace.uwb) == len(tables["uwb"]) - 2
    lines = report.summary_lines()
    assert any("truncated_row=2" in ln for ln in lines)


def test_a_uwb_table_without_rows_is_refused(tmp_path, tables):
    tables["uwb"] = tables["uwb"].iloc[:0]
    with pytest.raises(RecordingError, match="no ranging attempt"):
        import_csv(write_rec(tmp_path / "rec", tables))


def test_a_dataset_or_its_csv_export_is_named_as_such(tmp_path):
    from physynth.generate import generate_traces
    from physynth.io import write_dataset
    from physynth.io.export import export_dataset
    from physynth.io.scenario_file import load_scenario

    ds = tmp_path / "ds"
    write_dataset(ds, list(generate_traces(load_scenario("walk-hanyang"), 1, seed=1)))
    with pytest.raises(RecordingError, match="is a PhySynth dataset, not a recording"):
        import_csv(ds)
    export_dataset(ds, tmp_path / "csvout", "csv")
    with pytest.raises(RecordingError, match=r"is a PhySynth dataset \(a CSV export\)"):
        import_csv(tmp_path / "csvout")
