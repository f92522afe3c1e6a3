"""Exports read back by their own libraries (h5py, rosbags, csv) and compared with the source dataset."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from physynth.cli import main
from physynth.io.dataset import read_dataset
from physynth.io.export import export_dataset
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path, _ = generate_dataset(load_scenario("cablecar-descending"), 3, tmp_path_factory.mktemp("ex") / "ds",
                               seed=5, shard_traces=2)
    return path, read_dataset(path)


def test_hdf5_one_group_per_trace(dataset, tmp_path):
    h5py = pytest.importorskip("h5py")
    path, ds = dataset
    out = export_dataset(path, tmp_path / "ds.h5", "hdf5")
    with h5py.File(out, "r") as f:
        assert sorted(f["traces"]) == ["00000000", "00000001", "00000002"]
        for i, tr in enumerate(ds.traces):
            g = f["traces"][f"{i:08d}"]
            assert g.attrs["trace"] == i and g.attrs["root_seed"] == 5
            np.testing.assert_array_equal(g["truth/t_s"][()], tr.truth.t_s)
            np.testing.assert_array_equal(g["truth/pos_enu_m"][()], tr.truth.pos_enu_m)
            np.testing.assert_array_equal(g["imu/acc_mps2"][()], tr.imu.acc_mps2)
            assert g["imu/acc_mps2"].dtype == np.float32  # as stored in the dataset
            np.testing.assert_array_equal(g["uwb/range_m"][()], tr.uwb.range_m)
            np.testing.assert_array_equal(g["uwb/anchor"][()], tr.uwb.anchor)
            assert [s.decode() for s in g["anchors/ids"][()]] == list(tr.anchors.ids)


def test_rosbag2_messages_and_stamps(dataset, tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    path, ds = dataset
    out = export_dataset(path, tmp_path / "bags", "rosbag2")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    tr = ds.traces[1]
    with Reader(out / "trace_00000001") as r:
        topics = {c.topic: c.msgtype for c in r.connections}
        assert topics["/imu"] == "sensor_msgs/msg/Imu" and topics["/truth"] == "geometry_msgs/msg/PointStamped"
        ranges: dict[str, list] = {}
        imu_stamps, imu_acc, last = [], [], -1
        for conn, stamp, raw in r.messages():
            assert stamp >= last  # time order
            last = stamp
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/tf_static":  # a TFMessage: its transforms carry the headers (tested below)
                continue
            hdr = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert hdr == stamp
            if conn.topic == "/imu":
                imu_stamps.append(hdr)
                imu_acc.append((msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z))
                assert msg.orientation_covariance[0] == -1.0
            elif conn.topic.startswith("/uwb/"):
                assert conn.msgtype == "sensor_msgs/msg/Range" and msg.header.frame_id == conn.topic[5:]
                ranges.setdefault(msg.header.frame_id, []).append((hdr, msg.range))
    np.testing.assert_array_equal(np.array(imu_stamps), np.round(tr.imu.t_s * 1e9).astype(np.int64))
    np.testing.assert_array_equal(np.array(imu_acc), tr.imu.acc_mps2)
    ok = np.isfinite(tr.uwb.range_m)
    assert sum(len(v) for v in ranges.values()) == int(ok.sum())  # one message per delivered range
    a = tr.anchors.ids[3]
    sel = ok & (tr.uwb.anchor == 3)
    got = np.array(ranges[a])
    np.testing.assert_array_equal(got[:, 0].astype(np.int64), np.round(tr.uwb.t_s[sel] * 1e9).astype(np.int64))
    np.testing.assert_allclose(got[:, 1], tr.uwb.range_m[sel], rtol=1e-7)  # Range.range is float32


def test_csv_per_table(dataset, tmp_path):
    path, ds = dataset
    out = export_dataset(path, tmp_path / "csv", "csv")
    assert sorted(p.name for p in out.iterdir()) == ["anchors.csv", "dataset.json", "imu.csv", "traces.jsonl",
                                                     "truth.csv", "uwb.csv"]
    lines = (out / "traces.jsonl").read_text().splitlines()  # per-trace metadata of a sharded dataset
    assert [json.loads(x)["spawn_key"] for x in lines] == [[0], [1], [2]]
    with open(out / "uwb.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    src = pq.read_table(path / "uwb").to_pylist()
    assert len(rows) == len(src)
    for got, want in zip(rows[::97], src[::97], strict=True):
        assert int(got["trace"]) == want["trace"] and got["anchor_id"] == want["anchor_id"]
        assert float(got["t_s"]) == want["t_s"]
        assert (math.isnan(float(got["range_m"])) and want["range_m"] != want["range_m"]) or \
            float(got["range_m"]) == want["range_m"]
    with open(out / "imu.csv", newline="", encoding="utf-8") as fh:
        imu = np.array([[float(r["acc_e_mps2"]), float(r["t_s"])] for r in csv.DictReader(fh)])
    want = np.concatenate([t.imu.acc_mps2[:, 0] for t in ds.traces])
    np.testing.assert_array_equal(imu[:, 0].astype(np.float32), want.astype(np.float32))


def test_export_cli_errors_are_one_line(dataset, tmp_path, capsys):
    path, _ = dataset
    for argv, needle in ((["export", str(path), "--format", "xls", "--out", str(tmp_path / "x")], "unknown export"),
                         (["export", str(tmp_path / "none"), "--format", "csv", "--out", str(tmp_path / "y")],
                          "does not exist")):
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and needle in err and err.count("\n") == 1
    (tmp_path / "taken").mkdir()  # an empty folder holds nothing to lose: used as if new
    main(["export", str(path), "--format", "csv", "--out", str(tmp_path / "taken"), "-q"])
    assert (tmp_path / "taken" / "truth.csv").is_file()
    with pytest.raises(SystemExit) as e:  # now an export: replaced only with --overwrite
        main(["export", str(path), "--format", "csv", "--out", str(tmp_path / "taken"), "-q"])
    assert e.value.code == 2 and "--overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(("fmt", "module", "name"), [("hdf5", "h5py", "x.h5"), ("csv", "polars", "x")])
def test_missing_extra_is_named_in_one_line(dataset, tmp_path, capsys, monkeypatch, fmt, module, name):
    path, _ = dataset
    monkeypatch.setitem(sys.modules, module, None)  # as if it were not installed: import raises ImportError
    with pytest.raises(SystemExit) as e:
        main(["export", str(path), "--format", fmt, "--out", str(tmp_path / name)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "physynth[export]" in err and module in err and err.count("\n") == 1
    assert not (tmp_path / name).exists()


@pytest.fixture(scope="module")
def body_dataset(tmp_path_factory):
    """ENU and body-frame IMU (accelerometer and gyroscope) and a truth attitude; and a body-only one."""
    scn = load_scenario("cablecar-descending")
    both = scn.model_copy(update={"imu_frames": ["enu-gravity-free", "body-flu"]})
    body = scn.model_copy(update={"imu_frames": ["body-flu"]})
    root = tmp_path_factory.mktemp("exb")
    p_both, _ = generate_dataset(both, 2, root / "both", seed=6)
    p_body, _ = generate_dataset(body, 1, root / "body", seed=6)
    return p_both, read_dataset(p_both), p_body, read_dataset(p_body)


def test_hdf5_keeps_the_body_imu_and_the_attitude(body_dataset, tmp_path):
    h5py = pytest.importorskip("h5py")
    p_both, ds, p_body, ds_body = body_dataset
    with h5py.File(export_dataset(p_both, tmp_path / "b.h5", "hdf5"), "r") as f:
        g, tr = f["traces/00000001"], ds.traces[1]
        for name in ("acc_mps2", "acc_body_mps2", "gyro_body_radps"):
            np.testing.assert_array_equal(g[f"imu/{name}"][()], getattr(tr.imu, name))
        np.testing.assert_array_equal(g["truth/quat_wxyz"][()], tr.truth.quat_wxyz)
        np.testing.assert_array_equal(g["truth/omega_body_radps"][()], tr.truth.omega_body_radps)
        assert json.loads(g["imu"].attrs["frames"]) == ["enu-gravity-free", "body-flu"]
    with h5py.File(export_dataset(p_body, tmp_path / "o.h5", "hdf5"), "r") as f:
        assert "acc_mps2" not in f["traces/00000000/imu"] and "gyro_body_radps" in f["traces/00000000/imu"]


def test_rosbag2_body_imu_topic(body_dataset, tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    p_both, ds, p_body, ds_body = body_dataset
    for path, data, enu in ((p_both, ds, True), (p_body, ds_body, False)):
        out = export_dataset(path, tmp_path / path.name, "rosbag2")
        tr = data.traces[0]
        acc, gyro, quat = [], [], []
        with Reader(out / "trace_00000000") as r:
            topics = {c.topic for c in r.connections}
            assert ("/imu" in topics) == enu and {"/imu/body", "/truth/orientation"} <= topics
            for conn, _, raw in r.messages():
                if conn.topic == "/imu/body":
                    m = ts.deserialize_cdr(raw, conn.msgtype)
                    assert m.header.frame_id == "body" and m.orientation_covariance[0] == -1.0
                    acc.append((m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z))
                    gyro.append((m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z))
                elif conn.topic == "/truth/orientation":
                    q = ts.deserialize_cdr(raw, conn.msgtype).quaternion
                    quat.append((q.w, q.x, q.y, q.z))
        np.testing.assert_array_equal(np.array(acc), tr.imu.acc_body_mps2)
        np.testing.assert_array_equal(np.array(gyro), tr.imu.gyro_body_radps)
        np.testing.assert_array_equal(np.array(quat), tr.truth.quat_wxyz)
        assert np.median(np.linalg.norm(np.array(acc), axis=1)) == pytest.approx(9.81, abs=0.3)  # gravity included


def test_a_csv_export_is_not_taken_for_a_damaged_dataset(dataset, tmp_path, capsys):
    """``inspect`` (and every reader) on a CSV export says what it is, not "truth.parquet is missing"."""
    out = export_dataset(dataset[0], tmp_path / "csv", "csv")
    for argv in (["inspect", str(out)], ["verify", str(out)]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1, err
        assert "is a CSV export of a PhySynth dataset, not a dataset" in err and "missing" not in err
    assert len(read_dataset(dataset[0]).traces) == 3  # the dataset itself still reads


@pytest.mark.skipif(importlib.util.find_spec("rosbags") is None, reason="rosbags (physynth[export]) not installed")
def test_rosbag2_states_each_trace_anchor_layout_on_tf_static(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from physynth.io.scenario_file import load_scenario
    from physynth.scenario import scenario_from_dict, scenario_to_dict
    from physynth.workflows import generate_dataset

    d = scenario_to_dict(load_scenario("cablecar-descending"))
    d["variation"] = {"layout_jitter_m": 2.0}  # every trace its own layout
    path, _ = generate_dataset(scenario_from_dict(d, "t"), 2, tmp_path / "ds", seed=4)
    out = export_dataset(path, tmp_path / "bags", "rosbag2")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    got = []
    for i, tr in enumerate(read_dataset(path).traces):
        with Reader(out / f"trace_{i:08d}") as r:
            conn = [c for c in r.connections if c.topic == "/tf_static"]
            assert len(conn) == 1 and conn[0].msgtype == "tf2_msgs/msg/TFMessage"
            assert conn[0].ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
            (c, stamp, raw), = list(r.messages(connections=conn))
            msg = ts.deserialize_cdr(raw, c.msgtype)
        assert stamp == round(tr.truth.t_s[0] * 1e9)
        assert [t.child_frame_id for t in msg.transforms] == list(tr.anchors.ids)
        assert all(t.header.frame_id == "enu" for t in msg.transforms)
        pos = np.array([[t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
                        for t in msg.transforms])
        np.testing.assert_array_equal(pos, tr.anchors.pos_enu_m)
        got.append(pos)
    assert not np.array_equal(got[0], got[1])


def _damaged_copy(path, tmp_path, name, damage):
    """A copy of the dataset ``path`` without an integrity record (as an older PhySynth wrote it), damaged."""
    import shutil

    import pyarrow.parquet as pq

    copy = tmp_path / name
    shutil.copytree(path, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta.pop("files")
    (copy / "dataset.json").write_text(json.dumps(meta))
    if damage == "truncated":
        f = copy / "imu" / "part-00000.parquet"
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    else:  # a UWB table without its labels
        for f in (copy / "uwb").glob("part-*.parquet"):
            pq.write_table(pq.read_table(f).drop(["true_range_m"]), f)
    return copy


@pytest.mark.parametrize(("damage", "needle"), [("truncated", "cannot read"), ("no_label", "true_range_m")])
def test_csv_export_checks_the_dataset_as_the_other_formats(dataset, tmp_path, capsys, damage, needle):
    """Not "internal error: ArrowInvalid" (exit 3), nor a uwb.csv without the column (exit 0)."""
    copy = _damaged_copy(dataset[0], tmp_path, damage, damage)
    for fmt in ("csv", "rosbag2") if importlib.util.find_spec("rosbags") else ("csv",):
        with pytest.raises(SystemExit) as e:
            main(["export", str(copy), "-f", fmt, "--out", str(tmp_path / f"out-{fmt}"), "-q"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1 and needle in err, err
        assert not (tmp_path / f"out-{fmt}").exists()


@pytest.mark.skipif(importlib.util.find_spec("rosbags") is None, reason="rosbags (physynth[export]) not installed")
def test_rosbag2_leaves_out_and_counts_messages_with_nan_fields(body_dataset, tmp_path):
    """As an imported BROAD trial's masked optical dropouts: NaN truth position and attitude, and NaN ENU
    acceleration (derived from them); the body-frame sensor itself is intact."""
    import dataclasses

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from physynth.io.dataset import write_dataset

    tr = body_dataset[1].traces[0]
    pos, quat, acc = tr.truth.pos_enu_m.copy(), tr.truth.quat_wxyz.copy(), tr.imu.acc_mps2.copy()
    pos[10:14] = np.nan
    quat[[10, 11, 12, 13, 50]] = np.nan
    acc[100:107, 1] = np.nan
    nan_trace = dataclasses.replace(tr, truth=dataclasses.replace(tr.truth, pos_enu_m=pos, quat_wxyz=quat),
                                    imu=dataclasses.replace(tr.imu, acc_mps2=acc))
    src = write_dataset(tmp_path / "nan", [nan_trace])
    said = []
    out = export_dataset(src, tmp_path / "bags", "rosbag2", progress=lambda m, done=None, total=None: said.append(m))
    ts = get_typestore(Stores.ROS2_HUMBLE)
    count: dict[str, int] = {}
    with Reader(out / "trace_00000000") as r:
        for conn, _, raw in r.messages():
            count[conn.topic] = count.get(conn.topic, 0) + 1
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            for field in ("point", "quaternion", "linear_acceleration", "angular_velocity"):
                value = getattr(msg, field, None)
                assert value is None or all(np.isfinite(getattr(value, c)) for c in "xyz")
    n_truth, n_imu = tr.truth.t_s.size, tr.imu.t_s.size
    assert count["/truth"] == n_truth - 4 and count["/truth/orientation"] == n_truth - 5
    assert count["/imu"] == n_imu - 7 and count["/imu/body"] == n_imu
    assert "left out 16 message(s) with a NaN field: /imu 7, /truth 4, /truth/orientation 5" in said


@pytest.mark.skipif(importlib.util.find_spec("rosbags") is None, reason="rosbags (physynth[export]) not installed")
def test_rosbag2_leaves_out_and_counts_messages_stamped_before_zero(dataset, tmp_path):
    """As a Hanyang run imported with --crop-to-uwb: a few UWB ranges before the first truth sample (time
    0). A ROS time is never negative: those messages are left out and counted, the others keep their
    stamps, and no header stamp or record time of the bag is negative."""
    import dataclasses

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from physynth.io.dataset import write_dataset

    tr = dataset[1].traces[0]
    t = tr.uwb.t_s - 0.2
    early = np.isfinite(tr.uwb.range_m) & (np.round(t * 1e9) < 0)
    assert early.any()
    src = write_dataset(tmp_path / "early", [dataclasses.replace(tr, uwb=dataclasses.replace(tr.uwb, t_s=t))])
    said = []
    out = export_dataset(src, tmp_path / "bags", "rosbag2", progress=lambda m, done=None, total=None: said.append(m))
    ts = get_typestore(Stores.ROS2_HUMBLE)
    n_uwb = 0
    with Reader(out / "trace_00000000") as r:
        assert r.start_time >= 0
        for conn, stamp, raw in r.messages():
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            header = getattr(msg, "header", None) or msg.transforms[0].header
            assert stamp >= 0 and header.stamp.sec >= 0
            n_uwb += conn.topic.startswith("/uwb/")
    assert n_uwb == int(np.isfinite(tr.uwb.range_m).sum() - early.sum())
    line = [m for m in said if "stamped before 0 s" in m]
    assert len(line) == 1 and line[0].startswith(f"left out {int(early.sum())} message(s) stamped before 0 s")


def test_docs_say_unknown_nlos_is_written_false_in_hdf5():
    from pathlib import Path

    import physynth.io.export.hdf5 as hdf5

    doc = " ".join((Path(__file__).resolve().parents[1] / "docs" / "export.md").read_text().split())
    assert "**Unknown NLOS is written as `nlos = False`.**" in doc and 'attrs["nlos_known"] == False' in doc
    assert "nlos_known = False" in " ".join(hdf5.__doc__.split())


@pytest.mark.parametrize("damage", ["changed", "no_label"])
def test_csv_export_checks_tables_against_the_integrity_record(dataset, tmp_path, capsys, damage):
    """With an integrity record the CSV export checks the files against it and each table's columns
    (instead of reading every trace): a changed byte and a table re-recorded without a column both stop it."""
    import hashlib
    import shutil

    import pyarrow.parquet as pq

    copy = tmp_path / damage
    shutil.copytree(dataset[0], copy)
    name = "uwb/part-00000.parquet"
    f = copy / name
    if damage == "changed":
        raw = bytearray(f.read_bytes())
        raw[len(raw) // 2] ^= 0xFF
        f.write_bytes(bytes(raw))
        needle = "does not match"
    else:  # the table rewritten without a column, and its record updated to match
        pq.write_table(pq.read_table(f).drop(["true_range_m"]), f)
        meta = json.loads((copy / "dataset.json").read_text())
        rec = meta["files"][name]
        rec.update(bytes=f.stat().st_size, **{k: hashlib.sha256(f.read_bytes()).hexdigest()
                                             for k in rec if k not in ("rows", "bytes")})
        (copy / "dataset.json").write_text(json.dumps(meta))
        needle = "true_range_m"
    with pytest.raises(SystemExit) as e:
        main(["export", str(copy), "-f", "csv", "--out", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "out").exists()


def _assert_hdf5_holds_the_records(f, traces, stored_f32):
    """Every array of every trace group equals the dataset reader's record, in the record's type (float64,
    int16/int64/int8/bool for UWB) or float32 where the dataset stores float32; the attributes too."""
    for index, tr in traces:
        g = f["traces"][f"{index:08d}"]
        assert {k: g.attrs[k] for k in g.attrs if k != "trace"} == {
            k: (v if isinstance(v, (int, float, str, bool)) else json.dumps(v)) for k, v in tr.meta.items()}
        expect = {"truth/t_s": tr.truth.t_s, "truth/pos_enu_m": tr.truth.pos_enu_m,
                  "truth/vel_enu_mps": tr.truth.vel_enu_mps, "truth/quat_wxyz": tr.truth.quat_wxyz,
                  "truth/omega_body_radps": tr.truth.omega_body_radps,
                  **{f"uwb/{c}": getattr(tr.uwb, c) for c in ("t_s", "anchor", "range_m", "true_range_m", "nlos",
                                                              "burst", "reason")},
                  "anchors/pos_enu_m": tr.anchors.pos_enu_m}
        if tr.imu is not None:
            expect |= {"imu/t_s": tr.imu.t_s, **{f"imu/{c}": getattr(tr.imu, c)
                                                   for c in ("acc_mps2", "acc_body_mps2", "gyro_body_radps")}}
            assert g["imu"].attrs["frame"] == tr.imu.frame
            assert json.loads(g["imu"].attrs["frames"]) == list(tr.imu.frames)
        else:
            assert "imu" not in g
        for name, value in expect.items():
            if value is None:
                assert name not in g, name
                continue
            want = value.astype(np.float32) if name in stored_f32 else value
            got = g[name][()]
            assert got.dtype == want.dtype and got.shape == want.shape, (name, got.dtype, want.dtype)
            np.testing.assert_array_equal(got, want, err_msg=name)
        assert bool(g["uwb"].attrs["nlos_known"]) == tr.uwb.nlos_known
        assert [s.decode() for s in g["anchors/ids"][()]] == list(tr.anchors.ids)
        assert [s.decode() for s in g["anchors/names"][()]] == list(tr.anchors.names)


def test_hdf5_copies_the_stored_tables_as_the_reader_makes_records_of_them(body_dataset, tmp_path):
    """The HDF5 export copies the tables as stored (no record per trace); what it writes is what the records
    of the dataset's reader hold, type for type, for generated traces with both IMU frames and attitude."""
    h5py = pytest.importorskip("h5py")
    from physynth.io.dataset import iter_indexed_traces

    p_both = body_dataset[0]
    f32 = {"truth/vel_enu_mps", "truth/quat_wxyz", "truth/omega_body_radps", "imu/acc_mps2", "imu/acc_body_mps2",
           "imu/gyro_body_radps"}
    with h5py.File(export_dataset(p_both, tmp_path / "b.h5", "hdf5"), "r") as f:
        _assert_hdf5_holds_the_records(f, list(iter_indexed_traces(p_both)), f32)


@pytest.mark.skipif(not (HANYANG := __import__("pathlib").Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
                         / "hanyang-uwb" / "Dynamic_measurements" / "NLOS" / "Trajectory_A" / "Case_1").is_dir(),
                    reason="real Hanyang data not found")
def test_hdf5_of_an_imported_recording_holds_its_records(tmp_path):
    """An imported run (float64 throughout, NLOS unknown, anchors with names)."""
    h5py = pytest.importorskip("h5py")
    from physynth.io.dataset import iter_indexed_traces, write_dataset
    from physynth.io.importers import import_hanyang

    trace, _ = import_hanyang(HANYANG)
    path = write_dataset(tmp_path / "ds", [trace], meta={"kind": "real", "source": "hanyang-uwb"})
    with h5py.File(export_dataset(path, tmp_path / "r.h5", "hdf5"), "r") as f:
        traces = list(iter_indexed_traces(path))
        assert not traces[0][1].uwb.nlos_known
        _assert_hdf5_holds_the_records(f, traces, set())


def test_csv_tables_written_side_by_side_stop_and_fail_together(dataset, tmp_path, monkeypatch):
    """The CSV tables are written at the same time (``csv.write_csv_tables``): a table's thread stops at its
    next row group once told to, and an error on any table's thread is the export's error."""
    import threading

    from physynth.io.dataset import read_meta
    from physynth.io.export import csv as csv_export

    path, _ = dataset
    meta = read_meta(path)
    stop = threading.Event()
    stop.set()
    (tmp_path / "stopped").mkdir()
    csv_export._write_table(path, meta, tmp_path / "stopped", "imu", True, False, False, stop, None, set())
    assert (tmp_path / "stopped" / "imu.csv").stat().st_size == 0  # not a row written

    files = csv_export.table_files

    def broken(dataset, name, meta):  # the IMU table's files point nowhere: its thread fails
        return [p.with_name("missing.parquet") for p in files(dataset, name, meta)] if name == "imu" else \
            files(dataset, name, meta)

    monkeypatch.setattr(csv_export, "table_files", broken)
    with pytest.raises(OSError, match="missing.parquet"):
        csv_export.write_csv_tables(path, meta, tmp_path / "failed")


def test_csv_progress_trace_ids_match_numpy_unique():
    """The CSV export counts the traces of each row group by runs of equal ids (no sort): the same set as
    np.unique, for rows grouped by trace as written and for any other order."""
    from physynth.io.export.csv import _trace_ids

    rng = np.random.default_rng(3)
    grouped = np.repeat(np.array([4, 7, 8, 20], np.int32), [3, 1, 5, 2])
    for ids in (np.array([], np.int32), np.array([9], np.int32), grouped, rng.permutation(grouped),
                rng.integers(0, 50, 1000).astype(np.int32)):
        assert _trace_ids(ids) == set(np.unique(ids).tolist())
