"""ROS 2 bags: the NumPy CDR bytes against rosbags' own serialiser, MCAP files read back by the mcap library
and by rosbags, and the SQLite3 storage with the same messages."""

from __future__ import annotations

import collections

import numpy as np
import pytest

pytest.importorskip("rosbags")
mcap_reader = pytest.importorskip("mcap.reader")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from physynth.io.dataset import DatasetWriter, iter_stored_traces, read_dataset  # noqa: E402
from physynth.io.export import cdr, export_dataset  # noqa: E402
from physynth.io.export.rosbag2 import HEAD, BagColumns, trace_topics  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.workflows import generate_dataset  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types


def _header(ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                    frame_id=frame)


def _v(x, y, z):
    return T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


@pytest.fixture(scope="module")
def body_dataset(tmp_path_factory):
    """ENU and body-frame IMU and a truth attitude: every message type the export writes."""
    scn = load_scenario("cablecar-descending")
    scn = scn.model_copy(update={"imu_frames": ["enu-gravity-free", "body-flu"]})
    path, _ = generate_dataset(scn, 2, tmp_path_factory.mktemp("rb") / "ds", seed=9, shard_traces=1)
    return path, read_dataset(path)


@pytest.mark.parametrize("frame", ["", "a", "A1", "enu", "body", "A1234", "anchor-7", "a-long-frame-id"])
def test_cdr_layouts_match_rosbags_for_every_frame_length(frame):
    """Frame ids of every length modulo 8 move the alignment padding after the header."""
    rng = np.random.default_rng(len(frame))
    ns = np.array([0, 1, 1_700_000_000_123_456_789, 2_000_000_000])
    f = frame.encode()
    vals = rng.normal(size=(4, 4))
    cov = np.arange(9.0)
    rows = cdr.records(cdr.imu_fields(f), ns, f, orientation_x=vals[:, 0], orientation_w=vals[:, 3],
                       orientation_covariance=cov, angular_velocity_y=vals[:, 1],
                       linear_acceleration_z=vals[:, 2], linear_acceleration_covariance=-cov)
    rng_rows = cdr.records(cdr.range_fields(f), ns, f, radiation_type=2, field_of_view=2 * np.pi, min_range=0.5,
                           max_range=vals[:, 0] + 30, range=vals[:, 1] + 5)
    pt = cdr.records(cdr.point_stamped_fields(f), ns, f, point_x=vals[:, 0], point_y=vals[:, 1], point_z=vals[:, 2])
    q = cdr.records(cdr.quaternion_stamped_fields(f), ns, f, quaternion_x=vals[:, 0], quaternion_w=vals[:, 3])
    for k, t in enumerate(ns.tolist()):
        h = _header(t, frame)
        imu = T["sensor_msgs/msg/Imu"](
            header=h, orientation=T["geometry_msgs/msg/Quaternion"](x=vals[k, 0], y=0.0, z=0.0, w=vals[k, 3]),
            orientation_covariance=cov, angular_velocity=_v(0, vals[k, 1], 0), angular_velocity_covariance=np.zeros(9),
            linear_acceleration=_v(0, 0, vals[k, 2]), linear_acceleration_covariance=-cov)
        assert rows[k].tobytes() == bytes(TS.serialize_cdr(imu, imu.__msgtype__))
        rng_msg = T["sensor_msgs/msg/Range"](header=h, radiation_type=2, field_of_view=float(np.float32(2 * np.pi)),
                                             min_range=0.5, max_range=float(np.float32(vals[k, 0] + 30)),
                                             range=float(np.float32(vals[k, 1] + 5)))
        assert rng_rows[k].tobytes() == bytes(TS.serialize_cdr(rng_msg, rng_msg.__msgtype__))
        p = T["geometry_msgs/msg/PointStamped"](header=h, point=T["geometry_msgs/msg/Point"](
            x=vals[k, 0], y=vals[k, 1], z=vals[k, 2]))
        assert pt[k].tobytes() == bytes(TS.serialize_cdr(p, p.__msgtype__))
        qs = T["geometry_msgs/msg/QuaternionStamped"](header=h, quaternion=T["geometry_msgs/msg/Quaternion"](
            x=vals[k, 0], y=0.0, z=0.0, w=vals[k, 3]))
        assert q[k].tobytes() == bytes(TS.serialize_cdr(qs, qs.__msgtype__))


def test_every_topic_of_a_trace_matches_rosbags_serialiser(body_dataset):
    """Each topic's rows, rebuilt as rosbags messages from the trace's own arrays and serialised by rosbags."""
    tr = body_dataset[1].traces[1]
    topics = {t.name: t for t in trace_topics(TS, tr, {})}
    data = {name: t.messages.rows() for name, t in topics.items()}
    assert {"/imu", "/imu/body", "/truth", "/truth/orientation", "/tf_static"} <= set(topics)
    rows = np.random.default_rng(0).choice(tr.imu.t_s.size, 25, replace=False)
    no, zero = np.array([-1.0] + [0.0] * 8), np.zeros(9)
    ident = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    for k in rows.tolist():
        ns = int(np.round(tr.imu.t_s[k] * 1e9))
        a, b, g = tr.imu.acc_mps2[k], tr.imu.acc_body_mps2[k], tr.imu.gyro_body_radps[k]
        enu = T["sensor_msgs/msg/Imu"](header=_header(ns, "enu"), orientation=ident, orientation_covariance=no,
                                       angular_velocity=_v(0, 0, 0), angular_velocity_covariance=no,
                                       linear_acceleration=_v(*a), linear_acceleration_covariance=zero)
        body = T["sensor_msgs/msg/Imu"](header=_header(ns, "body"), orientation=ident, orientation_covariance=no,
                                        angular_velocity=_v(*g), angular_velocity_covariance=zero,
                                        linear_acceleration=_v(*b), linear_acceleration_covariance=zero)
        assert topics["/imu"].stamps[k] == ns
        assert data["/imu"][k, HEAD:].tobytes() == bytes(TS.serialize_cdr(enu, enu.__msgtype__))
        assert data["/imu/body"][k, HEAD:].tobytes() == bytes(TS.serialize_cdr(body, body.__msgtype__))
    for k in (rows % tr.truth.t_s.size).tolist()[:10]:
        ns = int(np.round(tr.truth.t_s[k] * 1e9))
        p = T["geometry_msgs/msg/PointStamped"](header=_header(ns, "enu"), point=T["geometry_msgs/msg/Point"](
            x=tr.truth.pos_enu_m[k, 0], y=tr.truth.pos_enu_m[k, 1], z=tr.truth.pos_enu_m[k, 2]))
        w, x, y, z = tr.truth.quat_wxyz[k]
        q = T["geometry_msgs/msg/QuaternionStamped"](header=_header(ns, "enu"),
                                                    quaternion=T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))
        assert data["/truth"][k, HEAD:].tobytes() == bytes(TS.serialize_cdr(p, p.__msgtype__))
        assert data["/truth/orientation"][k, HEAD:].tobytes() == bytes(TS.serialize_cdr(q, q.__msgtype__))
    ok = np.isfinite(tr.uwb.range_m)
    max_range = float(tr.uwb.range_m[ok].max())
    for a_idx, a_id in enumerate(tr.anchors.ids):
        sel = np.flatnonzero(ok & (tr.uwb.anchor == a_idx))
        if sel.size == 0:  # an anchor never heard: no topic
            assert f"/uwb/{a_id}" not in topics
            continue
        topic = topics[f"/uwb/{a_id}"]
        assert topic.stamps.size == sel.size
        for j in (0, sel.size // 2, sel.size - 1):
            ns = int(np.round(tr.uwb.t_s[sel[j]] * 1e9))
            m = T["sensor_msgs/msg/Range"](header=_header(ns, a_id), radiation_type=2,
                                           field_of_view=float(np.float32(2 * np.pi)), min_range=0.0,
                                           max_range=float(np.float32(max_range)),
                                           range=float(np.float32(tr.uwb.range_m[sel[j]])))
            assert data[f"/uwb/{a_id}"][j, HEAD:].tobytes() == bytes(TS.serialize_cdr(m, m.__msgtype__))


def _mcap_messages(path):
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        out = [(ch.topic, sch.name, m.log_time, bytes(m.data)) for sch, ch, m in reader.iter_messages(
            log_time_order=True)]
    return summary, out


def test_mcap_bags_read_by_mcap_and_rosbags_and_same_messages_as_sqlite3(body_dataset, tmp_path):
    from rosbags.highlevel import AnyReader

    path, ds = body_dataset
    mc = export_dataset(path, tmp_path / "mcap", "rosbag2")  # zstd-compressed chunks
    raw = export_dataset(path, tmp_path / "raw", "rosbag2", bag_storage="mcap-uncompressed")
    sq = export_dataset(path, tmp_path / "sqlite", "rosbag2", bag_storage="sqlite3")
    for i, tr in enumerate(ds.traces):
        bag = f"trace_{i:08d}"
        assert (mc / bag / f"{bag}.mcap").is_file() and (sq / bag / f"{bag}.db3").is_file()
        summary, msgs = _mcap_messages(mc / bag / f"{bag}.mcap")
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        imu_chunks = [c for c in summary.chunk_indexes if set(c.message_index_offsets) == {1}]
        assert len(imu_chunks) >= 2  # a topic longer than a chunk is cut into several (merged by the readers)
        raw_summary, raw_msgs = _mcap_messages(raw / bag / f"{bag}.mcap")
        assert {c.compression for c in raw_summary.chunk_indexes} == {""} and raw_msgs == msgs
        stamps = [m[2] for m in msgs]
        assert stamps == sorted(stamps) and stamps[0] >= 0
        assert summary.statistics.message_count == len(msgs)
        counts = collections.Counter(m[0] for m in msgs)
        assert counts["/imu"] == counts["/imu/body"] == tr.imu.t_s.size
        assert counts["/truth"] == counts["/truth/orientation"] == tr.truth.t_s.size
        assert sum(n for t, n in counts.items() if t.startswith("/uwb/")) == int(np.isfinite(tr.uwb.range_m).sum())
        by_rosbags = {}
        for folder in (mc / bag, sq / bag):
            with AnyReader([folder], default_typestore=TS) as r:
                got = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in r.messages()]
                assert [g[2] for g in got] == sorted(g[2] for g in got)
                first_imu = next(raw for c, t, raw in r.messages() if c.topic == "/imu/body")
                m = r.deserialize(first_imu, "sensor_msgs/msg/Imu")
                np.testing.assert_array_equal([m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z],
                                              tr.imu.gyro_body_radps[0])
            by_rosbags[folder.parent.name] = collections.Counter(got)
        assert by_rosbags["mcap"] == by_rosbags["sqlite"]  # the same messages, byte for byte, in both storages
        assert by_rosbags["mcap"] == collections.Counter(msgs)  # and as the mcap library reads them


def test_an_mcap_written_into_a_buffer_given_back_by_the_one_before_is_rewritten_byte_for_byte(body_dataset,
                                                                                                 tmp_path):
    """MCAP files reuse the buffers of those written before (``mcap._buffer``): every byte of the records,
    padding and record heads included, is written again, whatever the buffer held."""
    import os

    from physynth.io.export import mcap

    tr = body_dataset[1].traces[0]

    def write(name):
        channels = [mcap.Channel(t.name, t.msgtype, "", "ros2msg", {}, t.stamps, t.messages)
                    for t in trace_topics(TS, tr, {})]
        prepared = mcap.prepare_mcap(channels, compression="")
        with open(tmp_path / name, "wb") as f:
            prepared.write(f)
        return prepared.buffer, (tmp_path / name).read_bytes()

    mcap._free_of(os.getpid())[1].clear()
    first_buffer, first = write("first.mcap")
    assert any(b is first_buffer for b in mcap._free_of(os.getpid())[1])  # given back once written
    first_buffer[:] = 0xAB  # what a file before left there, as bytes no record holds
    buffer, again = write("again.mcap")
    assert buffer is first_buffer and again == first
    _, msgs = _mcap_messages(tmp_path / "again.mcap")
    assert len(msgs) == sum(t.stamps.size for t in trace_topics(TS, tr, {}))


def test_bags_from_stored_columns_equal_bags_from_records(body_dataset, tmp_path):
    """The export builds messages from the stored columns (float32 where stored so, no record built): every
    topic's bytes, stamps and left-out counts equal those built from the trace's record, with NaN fields
    and rows stamped before 0 s among them."""
    import dataclasses

    tr = body_dataset[1].traces[0]
    pos, quat, acc = tr.truth.pos_enu_m.copy(), tr.truth.quat_wxyz.copy(), tr.imu.acc_body_mps2.copy()
    pos[5:9] = np.nan
    quat[[3, 40]] = np.nan
    acc[100:104, 2] = np.nan
    delivered = np.flatnonzero(np.isfinite(tr.uwb.range_m))
    t0 = float(tr.uwb.t_s[delivered[4]])  # the first ranges and truth and IMU samples stamped before 0 s
    shifted = dataclasses.replace(
        tr, truth=dataclasses.replace(tr.truth, t_s=tr.truth.t_s - t0, pos_enu_m=pos, quat_wxyz=quat),
        imu=dataclasses.replace(tr.imu, t_s=tr.imu.t_s - t0, acc_body_mps2=acc),
        uwb=dataclasses.replace(tr.uwb, t_s=tr.uwb.t_s - t0))
    with DatasetWriter(tmp_path / "ds", compact=True) as w:  # float32 columns, as generate writes them
        w.add(shifted)
        w.add(tr)
    src = tmp_path / "ds"
    stored = list(iter_stored_traces(src))
    for record, st in zip(read_dataset(src).traces, stored, strict=True):
        skipped_r, skipped_s = {}, {}
        by_record = trace_topics(TS, record, skipped_r)
        by_columns = trace_topics(TS, BagColumns.of_stored(st, src), skipped_s)
        assert [t.name for t in by_record] == [t.name for t in by_columns]
        for a, b in zip(by_record, by_columns, strict=True):
            np.testing.assert_array_equal(a.stamps, b.stamps)
            assert a.messages.rows().tobytes() == b.messages.rows().tobytes(), a.name
        assert skipped_r == skipped_s
    assert sum(skipped_s.values()) == 0 and sum(skipped_r.values()) == 0  # the second trace: nothing left out
    first = {}
    trace_topics(TS, BagColumns.of_stored(stored[0], src), first)
    assert first["/truth"] == 4 and first["/truth/orientation"] == 2 and first["/imu/body"] == 4
    early = sum(v for k, v in first.items() if k.startswith("/uwb/") and k.endswith("(before 0 s)"))
    assert early == int(np.sum(tr.uwb.t_s[delivered] < t0)) >= 4
    assert first["/truth (before 0 s)"] == int(np.sum(tr.truth.t_s < t0)) - 4 * (tr.truth.t_s[8] < t0)


def test_a_bag_is_written_as_a_new_folder_its_files_named_after_the_bag(body_dataset, tmp_path):
    """``prepare_bag``'s writer makes the folder it is given and names the files after the bag, not after
    that folder (the MCAP export writes a temporary folder then renamed into place); SQLite3 bags, which
    rosbags names after their folder, refuse a folder named otherwise."""
    from physynth.io.export.rosbag2 import prepare_bag

    tr = body_dataset[1].traces[0]
    prepare_bag(tr, "mcap", {})(tmp_path / ".tmp-1", "trace_00000007")
    assert sorted(p.name for p in (tmp_path / ".tmp-1").iterdir()) == ["metadata.yaml", "trace_00000007.mcap"]
    meta = (tmp_path / ".tmp-1" / "metadata.yaml").read_text(encoding="utf-8")
    assert "- trace_00000007.mcap" in meta and ".tmp-1" not in meta
    summary, msgs = _mcap_messages(tmp_path / ".tmp-1" / "trace_00000007.mcap")
    assert summary.statistics.message_count == len(msgs) > 0
    with pytest.raises(ValueError, match="named after the bag"):
        prepare_bag(tr, "sqlite3", {})(tmp_path / ".tmp-2", "trace_00000007")
    assert not (tmp_path / ".tmp-2").exists()


@pytest.mark.parametrize("name", ["trace_00000000", "trace_12345678", "b", "trace_1234567890123400001",
                                  "Trace 1", "a: b"])
def test_bag_metadata_texts_are_yaml_dumps_of_the_metadata_byte_for_byte(body_dataset, name):
    """The bag's metadata texts, filled into a text dumped once per layout of topics, equal ``yaml.dump`` of
    the metadata (the /tf_static QoS text folded over lines among them); names YAML would quote too."""
    import yaml

    from physynth.io.export import rosbag2

    for tr in body_dataset[1].traces:
        topics = trace_topics(TS, tr, {})
        info = rosbag2._bag_metadata(name, "mcap", topics)
        inner, outer = rosbag2._metadata_texts(name, topics)
        assert outer == rosbag2._yaml({"rosbag2_bagfile_information": info}) and inner == rosbag2._yaml(info).strip()
        assert yaml.safe_load(outer)["rosbag2_bagfile_information"] == info
        template = rosbag2._metadata_template(tuple((t.name, t.msgtype, t.qos) for t in topics))
        assert template is not None and "trace" not in template[1]  # filled in, not dumped, for plain names
        assert "/tf_static" in outer and info["message_count"] == sum(t.stamps.size for t in topics) > 0


def test_the_stored_message_types_are_those_rosbags_makes():
    """ros2_types.json (the bags' message definitions and RIHS01 hashes, read instead of made per process):
    rosbags makes the same for every type the export writes (else: python tools/ros2_types.py)."""
    from physynth.io.export import rosbag2

    table = rosbag2._type_table()
    assert set(table) == set(rosbag2.MESSAGE_TYPES)
    for msgtype in rosbag2.MESSAGE_TYPES:
        assert rosbag2._type_info(msgtype) == rosbag2._type_info_of(msgtype), msgtype


def test_every_message_type_written_is_in_the_stored_table(body_dataset):
    from physynth.io.export import rosbag2

    written = {t.msgtype for tr in body_dataset[1].traces for t in trace_topics(TS, tr, {})}
    assert written <= set(rosbag2.MESSAGE_TYPES)
