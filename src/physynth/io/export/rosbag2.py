"""ROS 2 bag export (the ``rosbags`` library; no ROS installation needed).

The output is a folder with one bag per trace, ``trace_<index>/`` (a rosbag2 folder: ``metadata.yaml``
and an SQLite3 file), because traces of a dataset share one time base and would overlap in one bag.
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
shifted, so every bag keeps the dataset's time base. :func:`write_rosbag2` returns how many it left
out per topic (``"<topic> (before 0 s)"`` for the early rows).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ...records import Trace

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


def _anchor_frames(w: Any, ts: Any, trace: Trace, hdr: Any) -> tuple[int, Any, bytes]:
    """The ``/tf_static`` record of a trace's anchor layout: (stamp, connection, CDR bytes)."""
    tf_type = "tf2_msgs/msg/TFMessage"
    TFMessage, TransformStamped = ts.types[tf_type], ts.types["geometry_msgs/msg/TransformStamped"]
    Transform, Vector3 = ts.types["geometry_msgs/msg/Transform"], ts.types["geometry_msgs/msg/Vector3"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    conn = w.add_connection("/tf_static", tf_type, typestore=ts, offered_qos_profiles=[_latched_qos()])
    transforms = [TransformStamped(header=hdr, child_frame_id=a_id, transform=Transform(
        translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)))
        for a_id, p in zip(trace.anchors.ids, trace.anchors.pos_enu_m.tolist(), strict=True)]
    ns = hdr.stamp.sec * 1_000_000_000 + hdr.stamp.nanosec
    return int(ns), conn, ts.serialize_cdr(TFMessage(transforms=transforms), tf_type)


def _header(ts: Any, ns: int, frame: str) -> Any:
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    return Header(stamp=Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame)


def _finite_rows(n: int, *arrays: np.ndarray | None) -> np.ndarray:
    """Rows whose every value in the (n, k) ``arrays`` (None: absent) is finite, as a mask."""
    ok = np.ones(n, dtype=bool)
    for a in arrays:
        if a is not None:
            ok &= np.isfinite(a).all(axis=1)
    return ok


def _kept(skipped: dict[str, int], topic: str, t_s: np.ndarray, *arrays: np.ndarray | None) -> np.ndarray:
    """The rows of a topic's message fields to write; those with a NaN (or infinite) field are counted
    in ``skipped`` (a message cannot say "unknown": e.g. an optical tracker's dropouts in a recording),
    and so, under ``"<topic> (before 0 s)"``, are the other rows stamped before time 0 (a ROS time is
    never negative)."""
    ok = _finite_rows(t_s.shape[0], *arrays)
    skipped[topic] = skipped.get(topic, 0) + int(t_s.shape[0] - ok.sum())
    early = ok & (_stamps_ns(t_s) < 0)
    key = f"{topic} (before 0 s)"
    skipped[key] = skipped.get(key, 0) + int(early.sum())
    return ok & ~early


def _imu_messages(w: Any, ts: Any, imu: Any, skipped: dict[str, int]) -> list[tuple[int, Any, bytes]]:
    """The ``/imu`` (ENU) and ``/imu/body`` (body-frame sensor) records of a trace's IMU."""
    Imu, Vector3 = ts.types["sensor_msgs/msg/Imu"], ts.types["geometry_msgs/msg/Vector3"]
    identity = ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    no_cov, zero_cov = np.array([-1.0] + [0.0] * 8), np.zeros(9)
    messages = []
    channels = [] if imu is None else [
        (topic, frame, acc, gyro) for topic, frame, acc, gyro in (
            ("/imu", "enu", imu.acc_mps2, None), ("/imu/body", "body", imu.acc_body_mps2, imu.gyro_body_radps))
        if acc is not None or gyro is not None]
    for topic, frame, acc, gyro in channels:
        conn = w.add_connection(topic, Imu.__msgtype__, typestore=ts)
        n = imu.t_s.shape[0]
        ok = _kept(skipped, topic, imu.t_s, acc, gyro)
        acc_l = np.zeros((n, 3))[ok].tolist() if acc is None else acc[ok].tolist()
        gyro_l = np.zeros((n, 3))[ok].tolist() if gyro is None else gyro[ok].tolist()
        for ns, a, g in zip(_stamps_ns(imu.t_s[ok]), acc_l, gyro_l, strict=True):
            msg = Imu(header=_header(ts, int(ns), frame), orientation=identity, orientation_covariance=no_cov,
                      angular_velocity=Vector3(x=g[0], y=g[1], z=g[2]),
                      angular_velocity_covariance=no_cov if gyro is None else zero_cov,
                      linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
                      linear_acceleration_covariance=no_cov if acc is None else zero_cov)
            messages.append((int(ns), conn, ts.serialize_cdr(msg, Imu.__msgtype__)))
    return messages


def _uwb_messages(w: Any, ts: Any, trace: Trace, skipped: dict[str, int]) -> list[tuple[int, Any, bytes]]:
    """The ``/uwb/<anchor id>`` records: one per delivered range stamped at or after time 0."""
    Range = ts.types["sensor_msgs/msg/Range"]
    u = trace.uwb
    ok = np.isfinite(u.range_m)
    max_range = float(np.max(u.range_m[ok])) if ok.any() else 0.0
    messages = []
    for a_idx, a_id in enumerate(trace.anchors.ids):
        sel = ok & (u.anchor == a_idx)
        if not sel.any():
            continue
        sel[sel] = _kept(skipped, f"/uwb/{a_id}", u.t_s[sel])
        conn = w.add_connection(f"/uwb/{a_id}", Range.__msgtype__, typestore=ts)
        for ns, r in zip(_stamps_ns(u.t_s[sel]), u.range_m[sel].tolist(), strict=True):
            msg = Range(header=_header(ts, int(ns), a_id), radiation_type=RADIO, field_of_view=float(2 * np.pi),
                        min_range=0.0, max_range=max_range, range=r)
            messages.append((int(ns), conn, ts.serialize_cdr(msg, Range.__msgtype__)))
    return messages


def _truth_messages(w: Any, ts: Any, trace: Trace, skipped: dict[str, int]) -> list[tuple[int, Any, bytes]]:
    """The ``/truth`` position records, the ``/tf_static`` anchor layout and the ``/truth/orientation``
    records of a trace (in this order of their connections)."""
    Point, PointMsg = ts.types["geometry_msgs/msg/PointStamped"], ts.types["geometry_msgs/msg/Point"]
    QuatStamped, Quaternion = ts.types["geometry_msgs/msg/QuaternionStamped"], ts.types["geometry_msgs/msg/Quaternion"]
    truth = trace.truth
    c_truth = w.add_connection("/truth", Point.__msgtype__, typestore=ts)
    ok = _kept(skipped, "/truth", truth.t_s, truth.pos_enu_m)
    messages = [(int(ns), c_truth, ts.serialize_cdr(
        Point(header=_header(ts, int(ns), "enu"), point=PointMsg(x=p[0], y=p[1], z=p[2])), Point.__msgtype__))
        for ns, p in zip(_stamps_ns(truth.t_s[ok]), truth.pos_enu_m[ok].tolist(), strict=True)]
    if len(trace.anchors):
        messages.append(_anchor_frames(w, ts, trace, _header(ts, max(0, int(_stamps_ns(truth.t_s[:1])[0])), "enu")))
    if truth.quat_wxyz is not None:
        c_att = w.add_connection("/truth/orientation", QuatStamped.__msgtype__, typestore=ts)
        ok = _kept(skipped, "/truth/orientation", truth.t_s, truth.quat_wxyz)
        for ns, q in zip(_stamps_ns(truth.t_s[ok]), truth.quat_wxyz[ok].tolist(), strict=True):
            quat = Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])  # stored scalar-first (w, x, y, z)
            msg = QuatStamped(header=_header(ts, int(ns), "enu"), quaternion=quat)
            messages.append((int(ns), c_att, ts.serialize_cdr(msg, QuatStamped.__msgtype__)))
    return messages


def write_rosbag2(traces: Iterable[tuple[int, Trace]], meta: dict[str, Any], path: Path) -> dict[str, int]:
    """Write one ROS 2 bag per trace into the new folder ``path``.

    Returns the number of messages left out per topic (topics with none left out are not named): a
    row with a NaN (or infinite) value in a message's fields is not written, since a ROS message has
    no way to say "unknown" (an imported recording's optical dropouts, for instance), nor is a row
    stamped before time 0 (counted as ``"<topic> (before 0 s)"``), since a ROS time is never negative.
    """
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    skipped: dict[str, int] = {}
    path.mkdir(parents=True)
    for index, trace in traces:
        with Writer(path / f"trace_{index:08d}", version=8) as w:
            messages = [*_imu_messages(w, ts, trace.imu, skipped), *_uwb_messages(w, ts, trace, skipped),
                        *_truth_messages(w, ts, trace, skipped)]
            messages.sort(key=lambda m: m[0])  # a bag is written in time order
            for ns, conn, data in messages:
                w.write(conn, ns, data)
    return {topic: n for topic, n in skipped.items() if n}
