"""ROS 2 bag export (the ``rosbags`` library; no ROS installation needed).

The output is a folder with one bag per trace, ``trace_<index>/`` (a rosbag2 folder: ``metadata.yaml``
and an MCAP file ``trace_<index>.mcap``, or with ``storage="sqlite3"`` an SQLite3 file), because traces
of a dataset share one time base and would overlap in one bag. MCAP is what ROS 2 writes by default since
Iron and what Foxglove opens natively.

The messages of a topic are serialised all at once (:mod:`.cdr`: one NumPy structured array per topic,
no Python object per message) and the MCAP file is laid out with NumPy too (:mod:`.mcap`); the SQLite3
storage takes the same bytes through ``rosbags``' writer, one call per message (about 4 us each).
Topics, all with header stamps equal to the sample time (``t_s`` in nanoseconds, rounded) and the
receive timestamp of the bag record equal to the header stamp:

- ``/imu`` (``sensor_msgs/msg/Imu``), frame ``enu``: ``linear_acceleration`` in the dataset's IMU
  frame (ENU, gravity removed); no orientation or angular velocity (their covariance[0] is -1, the
  ROS convention for "not provided"); only when the dataset holds the ENU channel;
- ``/imu/body`` (``sensor_msgs/msg/Imu``), frame ``body``: the body-frame sensor as a strapdown IMU
  driver publishes it: ``linear_acceleration`` the specific force (gravity included, FLU axes),
  ``angular_velocity`` the gyroscope, no orientation (covariance[0] -1; either measurement too when
  the dataset lacks it); only when the dataset holds the body-frame IMU;
- ``/uwb/<anchor id>`` (``sensor_msgs/msg/Range``), frame ``<anchor id>``: one message per delivered
  UWB range (attempts without a range are not measurements and are left out); ``radiation_type`` 2
  stands for radio (the message defines 0 ultrasound and 1 infrared only), ``min_range`` 0,
  ``max_range`` the largest range of the trace, field of view 2 pi;
- ``/truth`` (``geometry_msgs/msg/PointStamped``), frame ``enu``: the ground-truth position;
- ``/truth/orientation`` (``geometry_msgs/msg/QuaternionStamped``), frame ``enu``: the ground-truth
  attitude (body to ENU), when the truth has one;
- ``/tf_static`` (``tf2_msgs/msg/TFMessage``, offered with transient-local durability as ROS 2 latches
  it): one message at the trace's first truth stamp with a transform ``enu`` -> ``<anchor id>`` per
  anchor (translation its position, no rotation): where the frames of the ``/uwb`` ranges are. Each
  bag holds its own trace's layout (traces of a ``variation`` section each have their own).

A row with a NaN (or infinite) value in a message's fields (an imported recording's optical dropouts,
for instance) has no message: ROS messages cannot say "unknown". Nor has a row stamped before time 0
(an imported recording's few UWB ranges before its first truth sample, for instance): a ROS time is
never negative (``rclcpp::Time`` throws), and the other rows keep their stamps rather than being
shifted, so every bag keeps the dataset's time base. :func:`prepare_bag` counts how many it leaves
out per topic (``"<topic> (before 0 s)"`` for the early rows).
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...records import Trace
from ..dataset import StoredTrace
from ..pagecache import write_behind
from ..tables import OPTIONAL_COLUMNS
from . import cdr
from .mcap import MESSAGE_HEAD

RADIO = 2
"""``radiation_type`` used for UWB (sensor_msgs/Range defines ULTRASOUND=0 and INFRARED=1 only)."""


def _stamps_ns(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.int64)


def _latched_qos() -> Any:
    """The QoS ROS 2 offers ``/tf_static`` with: reliable, transient local, keep last 1."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(sec=0, nsec=0)
    return Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
               durability=QosDurability.TRANSIENT_LOCAL, deadline=never, lifespan=never,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=never,
               avoid_ros_namespace_conventions=False)



STORAGES = ("mcap", "mcap-uncompressed", "sqlite3")
"""Storage formats of the bags; the first is the default: MCAP with zstd-compressed chunks (level 1; a
default trace's bag 2.5 MB instead of 16 MB), MCAP without
compression, SQLite3."""

MCAP_COMPRESSION = {"mcap": "zstd", "mcap-uncompressed": ""}

NAMED_AFTER_FOLDER = frozenset({"sqlite3"})
"""Storages whose files ``rosbags`` names after the bag's folder: written in a folder named as the bag (inside
a temporary one); the MCAP bags are written as a temporary folder renamed into place (a folder made and
removed less per bag: 2-3 ms on the 2-core machine's disk)."""

BAG_VERSION = 8
"""rosbag2 metadata version written (as ``rosbags``' writer: ROS 2 Iron and later)."""

HEAD = MESSAGE_HEAD
"""Bytes reserved in front of each message's CDR bytes: an MCAP message record's head, filled in place
by the MCAP writer (:mod:`.mcap`)."""

ZERO_COV, NO_COV = np.zeros(9), np.array([-1.0] + [0.0] * 8)


@dataclass(frozen=True)
class Topic:
    """One topic of a bag: name, message type, offered QoS profiles, and its messages (stamps in ns;
    ``messages`` lays out their rows on demand, :class:`.cdr.Messages`: :data:`HEAD` bytes reserved for the
    MCAP record head, then the message's CDR bytes)."""

    name: str
    msgtype: str
    qos: tuple[Any, ...]
    stamps: np.ndarray
    messages: cdr.Messages | cdr.Prebuilt


Columns = Sequence[np.ndarray]
"""The components of a vector quantity, one 1-D array each (x, y, z or w, x, y, z): what a dataset stores,
and column views of a record's (n, k) arrays."""


def _finite_rows(*groups: Columns | None) -> np.ndarray | None:
    """Rows whose every value in the column ``groups`` (None: absent) is finite, as a mask; None when all
    are (the usual case, found with one pass over each column)."""
    ok = None
    for cols in groups:
        for a in cols or ():
            finite = np.isfinite(a)
            if not finite.all():
                ok = finite if ok is None else ok & finite
    return ok


def _kept(skipped: dict[str, int], topic: str, t_s: np.ndarray,
          *groups: Columns | None) -> tuple[np.ndarray | slice, np.ndarray]:
    """The rows of a topic's message fields to write (a mask, or ``slice(None)`` when all are), and their
    stamps in ns; those with a NaN (or infinite) field are counted in ``skipped`` (a message cannot say
    "unknown": e.g. an optical tracker's dropouts in a recording), and so, under ``"<topic> (before 0 s)"``,
    are the other rows stamped before time 0 (a ROS time is never negative)."""
    n = t_s.shape[0]
    ns = _stamps_ns(t_s)
    finite = _finite_rows(*groups)
    skipped[topic] = skipped.get(topic, 0) + (0 if finite is None else int(n - finite.sum()))
    early = ns < 0
    if finite is not None:
        early &= finite
    key = f"{topic} (before 0 s)"
    skipped[key] = skipped.get(key, 0) + int(early.sum())
    if finite is None and not early.any():
        return slice(None), ns
    ok = ~early if finite is None else finite & ~early
    return ok, ns[ok]


@dataclass(frozen=True)
class BagColumns:
    """What a trace's bag is made of, as columns: a :class:`~physynth.records.Trace`'s arrays seen column
    by column (:meth:`of_trace`), or a stored trace's columns as the dataset holds them (:meth:`of_stored`,
    no record built: an export of a dataset whose integrity record vouches for it). Optional groups are
    None where the trace lacks them."""

    imu_t_s: np.ndarray | None
    imu_acc: Columns | None  # the ENU channel
    imu_acc_body: Columns | None
    imu_gyro_body: Columns | None
    uwb_t_s: np.ndarray
    uwb_anchor: np.ndarray  # indexes into anchor_ids
    uwb_range_m: np.ndarray
    anchor_ids: tuple[str, ...]
    anchor_pos: Columns  # e, n, u
    truth_t_s: np.ndarray
    truth_pos: Columns
    truth_quat: Columns | None  # w, x, y, z

    @classmethod
    def of_trace(cls, trace: Trace) -> BagColumns:
        def cols(a: np.ndarray | None) -> Columns | None:
            return None if a is None else [a[:, k] for k in range(a.shape[1])]

        im, u, a, tr = trace.imu, trace.uwb, trace.anchors, trace.truth
        return cls(None if im is None else im.t_s, None if im is None else cols(im.acc_mps2),
                   None if im is None else cols(im.acc_body_mps2), None if im is None else cols(im.gyro_body_radps),
                   u.t_s, u.anchor, u.range_m, tuple(a.ids), cols(a.pos_enu_m), tr.t_s, cols(tr.pos_enu_m),
                   cols(tr.quat_wxyz))

    @classmethod
    def of_stored(cls, st: StoredTrace, path: Path) -> BagColumns:
        def group(cols: dict[str, np.ndarray] | None, table: str, attr: str) -> Columns | None:
            names = OPTIONAL_COLUMNS[table][attr]  # as a record reads them: None when absent or all NaN
            if cols is None or any(c not in cols for c in names):
                return None
            out = [cols[c] for c in names]
            return None if out[0].size and all(np.isnan(c).all() for c in out) else out

        im, u, an, tr = st.imu, st.uwb, st.anchors, st.truth
        ids = st.anchor_ids()
        pos = [an[f"pos_{c}_m"] for c in "enu"] if an is not None else [np.zeros(0)] * 3
        return cls(None if im is None else im["t_s"], group(im, "imu", "acc_mps2"), group(im, "imu", "acc_body_mps2"),
                   group(im, "imu", "gyro_body_radps"),
                   np.array([]) if u is None else u["t_s"], st.uwb_anchor(path),
                   np.array([]) if u is None else u["range_m"], ids, pos, tr["t_s"],
                   [tr[f"pos_{c}_m"] for c in "enu"], group(tr, "truth", "quat_wxyz"))


def _imu_topics(b: BagColumns, skipped: dict[str, int]) -> list[Topic]:
    """``/imu`` (ENU) and ``/imu/body`` (body-frame sensor) of a trace's IMU."""
    out = []
    channels = [] if b.imu_t_s is None else [
        (topic, frame, acc, gyro) for topic, frame, acc, gyro in (
            ("/imu", "enu", b.imu_acc, None), ("/imu/body", "body", b.imu_acc_body, b.imu_gyro_body))
        if acc is not None or gyro is not None]
    for topic, frame, acc, gyro in channels:
        ok, ns = _kept(skipped, topic, b.imu_t_s, acc, gyro)
        values: dict[str, Any] = {"orientation_w": 1.0, "orientation_covariance": NO_COV,
                                  "angular_velocity_covariance": NO_COV if gyro is None else ZERO_COV,
                                  "linear_acceleration_covariance": NO_COV if acc is None else ZERO_COV}
        for name, cols in (("linear_acceleration", acc), ("angular_velocity", gyro)):
            if cols is not None:
                values.update({f"{name}_{c}": col[ok] for col, c in zip(cols, "xyz", strict=True)})
        f = frame.encode()
        msgs = cdr.messages(cdr.imu_fields(f), ns, f, reserve=HEAD, **values)
        out.append(Topic(topic, "sensor_msgs/msg/Imu", (), ns, msgs))
    return out


def _uwb_topics(b: BagColumns, skipped: dict[str, int]) -> list[Topic]:
    """``/uwb/<anchor id>``: one message per delivered range stamped at or after time 0."""
    ok = np.isfinite(b.uwb_range_m)
    max_range = float(np.max(b.uwb_range_m[ok])) if ok.any() else 0.0
    out = []
    for a_idx, a_id in enumerate(b.anchor_ids):
        sel = ok & (b.uwb_anchor == a_idx)
        if not sel.any():
            continue
        rows, ns = _kept(skipped, f"/uwb/{a_id}", b.uwb_t_s[sel])
        if isinstance(rows, np.ndarray):
            sel[sel] = rows
        f = a_id.encode()
        out.append(Topic(f"/uwb/{a_id}", "sensor_msgs/msg/Range", (), ns, cdr.messages(
            cdr.range_fields(f), ns, f, reserve=HEAD, radiation_type=RADIO, field_of_view=2 * np.pi,
            max_range=max_range, range=b.uwb_range_m[sel])))
    return out


def _anchor_frames(ts: Any, b: BagColumns, ns: int) -> Topic:
    """``/tf_static``: one message with a transform ``enu`` -> ``<anchor id>`` per anchor (one message per
    trace, so serialised by ``rosbags``)."""
    tf_type = "tf2_msgs/msg/TFMessage"
    TFMessage, TransformStamped = ts.types[tf_type], ts.types["geometry_msgs/msg/TransformStamped"]
    Transform, Vector3 = ts.types["geometry_msgs/msg/Transform"], ts.types["geometry_msgs/msg/Vector3"]
    Quaternion, Header = ts.types["geometry_msgs/msg/Quaternion"], ts.types["std_msgs/msg/Header"]
    hdr = Header(stamp=ts.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                 frame_id="enu")
    pos = np.stack(b.anchor_pos, axis=1).astype(np.float64).tolist()
    transforms = [TransformStamped(header=hdr, child_frame_id=a_id, transform=Transform(
        translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)))
        for a_id, p in zip(b.anchor_ids, pos, strict=True)]
    data = np.frombuffer(bytes(HEAD) + bytes(ts.serialize_cdr(TFMessage(transforms=transforms), tf_type)), np.uint8)
    return Topic("/tf_static", tf_type, (_latched_qos(),), np.array([ns], np.int64), cdr.Prebuilt(data[None, :].copy()))


def _truth_topics(ts: Any, b: BagColumns, skipped: dict[str, int]) -> list[Topic]:
    """``/truth`` positions, the ``/tf_static`` anchor layout and ``/truth/orientation`` (in this order)."""
    ok, ns = _kept(skipped, "/truth", b.truth_t_s, b.truth_pos)
    out = [Topic("/truth", "geometry_msgs/msg/PointStamped", (), ns, cdr.messages(
        cdr.point_stamped_fields(b"enu"), ns, b"enu", reserve=HEAD,
        **{f"point_{c}": col[ok] for col, c in zip(b.truth_pos, "xyz", strict=True)}))]
    if b.anchor_ids:
        out.append(_anchor_frames(ts, b, max(0, int(_stamps_ns(b.truth_t_s[:1])[0]))))
    if b.truth_quat is not None:
        ok, ns = _kept(skipped, "/truth/orientation", b.truth_t_s, b.truth_quat)
        out.append(Topic("/truth/orientation", "geometry_msgs/msg/QuaternionStamped", (), ns, cdr.messages(
            cdr.quaternion_stamped_fields(b"enu"), ns, b"enu", reserve=HEAD,  # stored scalar-first (w, x, y, z)
            **{f"quaternion_{c}": col[ok] for col, c in zip(b.truth_quat, "wxyz", strict=True)})))
    return out


def trace_topics(ts: Any, trace: Trace | BagColumns, skipped: dict[str, int]) -> list[Topic]:
    """Every topic of a trace's bag (a record, or its :class:`BagColumns`), in the order of their
    connections; rows left out are counted in ``skipped``."""
    b = trace if isinstance(trace, BagColumns) else BagColumns.of_trace(trace)
    return [*_imu_topics(b, skipped), *_uwb_topics(b, skipped), *_truth_topics(ts, b, skipped)]


def _bag_numbers(topics: list[Topic]) -> list[int]:
    """The numbers of a bag's metadata: start and duration (ns), message count, then each topic's."""
    stamps = [t.stamps for t in topics if t.stamps.size]
    start = int(min(s[0] for s in stamps)) if stamps else 0
    duration = max(0, int(max(s.max() for s in stamps)) - start) if stamps else 0
    counts = [int(t.stamps.size) for t in topics]
    return [start, duration, sum(counts), *counts]


def _bag_metadata(name: str, storage: str, topics: list[Topic], numbers: Sequence[int] | None = None) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a bag (what ``rosbags``' writer puts in ``metadata.yaml``);
    ``numbers``: those of :func:`_bag_numbers` (by default the topics')."""
    start, duration, count, *counts = _bag_numbers(topics) if numbers is None else numbers
    fname = f"{name}.{'db3' if storage == 'sqlite3' else 'mcap'}"
    return {"version": BAG_VERSION, "storage_identifier": "sqlite3" if storage == "sqlite3" else "mcap",
            "relative_file_paths": [fname],
            "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.msgtype, "serialization_format": "cdr",
                                    "offered_qos_profiles": _qos_text(t.qos),
                                    "type_description_hash": _type_info(t.msgtype)[1]},
                 "message_count": n} for t, n in zip(topics, counts, strict=True)],
            "compression_format": "", "compression_mode": "",
            "files": [{"path": fname, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": None, "ros_distro": "rosbags"}


def _yaml(data: Any) -> str:
    import yaml

    return yaml.dump(data, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), default_flow_style=False)


_NAME_MARK = "physynthbagname"
_NUMBER_MARK = 1_234_567_890_123_400_000
"""Marks standing for a bag's name and numbers (mark + k for number k: 19 digits each) in the texts of
:func:`_metadata_template`, replaced in one pass (:data:`_MARKS`)."""
_MARKS = re.compile(rf"{_NAME_MARK}|{_NUMBER_MARK // 1000}\d{{3}}")
_PLAIN_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")


@functools.lru_cache(maxsize=64)
def _metadata_template(topics: tuple[tuple[str, str, tuple[Any, ...]], ...]) -> tuple[str, str] | None:
    """The texts of :func:`_metadata_texts` for bags of ``topics`` (name, type, QoS of each), marks in place of
    the name and numbers; None when a mark does not appear where, and only where, it stands."""
    if 3 + len(topics) > 1000:  # more numbers than marks
        return None
    stub = [Topic(n, m, q, np.zeros(0, np.int64), cdr.Prebuilt(np.zeros((0, 0), np.uint8))) for n, m, q in topics]
    marks = [_NUMBER_MARK + k for k in range(3 + len(topics))]
    info = _bag_metadata(_NAME_MARK, "mcap", stub, marks)
    texts = _yaml(info).strip(), _yaml({"rosbag2_bagfile_information": info})
    uses = [2, 2, 2, *[1] * len(topics)]  # start and duration: the bag's and its file's; so the count
    for text in texts:
        if text.count(_NAME_MARK) != 2 or any(text.count(str(m)) != u for m, u in zip(marks, uses, strict=True)) \
                or len(_MARKS.findall(text)) != 2 + sum(uses):
            return None
    return texts


def _metadata_texts(name: str, topics: list[Topic]) -> tuple[str, str]:
    """An MCAP bag's metadata as the ``rosbag2`` metadata record holds it and as ``metadata.yaml`` (the same
    dictionary under ``rosbag2_bagfile_information``): ``yaml.dump`` of :func:`_bag_metadata`, byte for byte.
    Dumped once per layout of topics, with marks for the name and numbers then replaced (PyYAML's
    representer, pure Python, took about 1 ms per bag on the main thread, which the chunk threads wait on
    for the GIL)."""
    numbers = _bag_numbers(topics)
    template = _metadata_template(tuple((t.name, t.msgtype, t.qos) for t in topics)) if _PLAIN_NAME.match(name) \
        else None
    if template is None:  # a name YAML would quote (or marks that did not come out as planned)
        info = _bag_metadata(name, "mcap", topics, numbers)
        return _yaml(info).strip(), _yaml({"rosbag2_bagfile_information": info})
    values = {str(_NUMBER_MARK + k): str(n) for k, n in enumerate(numbers)} | {_NAME_MARK: name}
    inner, outer = (_MARKS.sub(lambda m: values[m.group()], text) for text in template)
    return inner, outer


MESSAGE_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/msg/Range", "geometry_msgs/msg/PointStamped",
                 "geometry_msgs/msg/QuaternionStamped", "tf2_msgs/msg/TFMessage")
"""The message types of the bags."""


@functools.cache
def _type_table() -> dict[str, dict[str, str]]:
    """``ros2_types.json`` beside this module: the definition and RIHS01 hash of each of
    :data:`MESSAGE_TYPES`, as ``rosbags`` makes them (``tools/ros2_types.py`` writes the file; the tests make
    them again and compare)."""
    try:
        return json.loads((Path(__file__).with_name("ros2_types.json")).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


@functools.lru_cache(maxsize=64)
def _type_info(msgtype: str) -> tuple[str, str]:
    """(message definition text, RIHS01 hash) of a message type of ROS 2 Humble: from :func:`_type_table`
    (``rosbags`` takes about 0.1 s to make those of a bag's five types), else made by ``rosbags``."""
    known = _type_table().get(msgtype)
    if known is not None:
        return known["msgdef"], known["rihs01"]
    return _type_info_of(msgtype)


def _type_info_of(msgtype: str) -> tuple[str, str]:
    """(message definition text, RIHS01 hash) of a message type, made by ``rosbags`` from its Humble type store."""
    ts = _typestore()
    return ts.generate_msgdef(msgtype, ros_version=2)[0], ts.hash_rihs01(msgtype)


@functools.lru_cache(maxsize=8)
def _qos_text(qos: tuple[Any, ...]) -> str:
    from rosbags.rosbag2.metadata import dump_qos_v8

    return dump_qos_v8(list(qos))


@functools.cache
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _mcap_bag(topics: list[Topic], compression: str) -> Callable[[Path, str], None]:
    """Lay out the MCAP bag of ``topics`` (its chunks start compressing on other threads); returns the
    function that writes it as a new folder."""
    from .mcap import Channel, prepare_mcap

    channels = [Channel(t.name, t.msgtype, _type_info(t.msgtype)[0], "ros2msg",
                        {"offered_qos_profiles": _qos_text(t.qos)}, t.stamps, t.messages) for t in topics]
    serialized = {"serialized_metadata": ""}  # filled in when the bag's name is known
    prepared = prepare_mcap(channels, library="physynth", compression=compression,
                            metadata={"rosbag2": serialized})

    def write(folder: Path, name: str) -> None:
        serialized["serialized_metadata"], yaml_text = _metadata_texts(name, topics)  # they name the bag's file
        folder.mkdir()
        with open(folder / f"{name}.mcap", "xb") as f:
            prepared.write(f)
            f.flush()
            write_behind(f.fileno())  # the bag written out now, not piled up in the page cache (io.pagecache)
        (folder / "metadata.yaml").write_text(yaml_text, encoding="utf-8")

    return write


def _write_sqlite3_bag(folder: Path, name: str, topics: list[Topic]) -> None:
    """The same bytes through ``rosbags``' writer (SQLite3 storage), one call per message in time order.
    ``rosbags`` names the file after the folder: ``folder``'s name must be ``name``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    if folder.name != name:
        raise ValueError(f"a SQLite3 bag's folder is named after the bag: {folder.name!r} is not {name!r}")

    with Writer(folder, version=BAG_VERSION, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = [w.add_connection(t.name, t.msgtype, typestore=_typestore(),
                                  offered_qos_profiles=list(t.qos)) for t in topics]
        stamps = np.concatenate([t.stamps for t in topics])
        which = np.repeat(np.arange(len(topics)), [t.stamps.size for t in topics])
        row = np.concatenate([np.arange(t.stamps.size) for t in topics])
        data = [t.messages.rows() for t in topics]
        for k in np.argsort(stamps, kind="stable").tolist():  # a bag is written in time order
            w.write(conns[which[k]], int(stamps[k]), data[which[k]][row[k], HEAD:].tobytes())


def prepare_bag(trace: Trace | BagColumns, storage: str, skipped: dict[str, int]) -> Callable[[Path, str], None]:
    """Build the messages of one trace's bag (a record, or its :class:`BagColumns`; ``storage``: one of
    :data:`STORAGES`) and, for compressed MCAP, start compressing its chunks on other threads; returns the
    function ``write(folder, name)`` that writes the bag as the new folder ``folder``, its files named after
    ``name`` (for SQLite3, which ``rosbags`` names after the folder: :data:`NAMED_AFTER_FOLDER`, the folder's
    own name). Messages left out are counted in ``skipped``."""
    topics = trace_topics(_typestore(), trace, skipped)
    if storage == "sqlite3":
        return functools.partial(_write_sqlite3_bag, topics=topics)
    return _mcap_bag(topics, MCAP_COMPRESSION[storage])
