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


def write_rosbag2(traces: Iterable[tuple[int, Trace]], meta: dict[str, Any], path: Path) -> None:
    """Write one ROS 2 bag per trace into the new folder ``path``."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Imu = ts.types["sensor_msgs/msg/Imu"]
    Range = ts.types["sensor_msgs/msg/Range"]
    Point = ts.types["geometry_msgs/msg/PointStamped"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    PointMsg = ts.types["geometry_msgs/msg/Point"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    QuatStamped = ts.types["geometry_msgs/msg/QuaternionStamped"]
    no_cov = np.array([-1.0] + [0.0] * 8)
    zero_cov = np.zeros(9)
    identity = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)

    def header(ns: int, frame: str):
        return Header(stamp=Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame)

    path.mkdir(parents=True)
    for index, trace in traces:
        with Writer(path / f"trace_{index:08d}", version=8) as w:
            messages: list[tuple[int, Any, bytes]] = []
            imu = trace.imu
            channels = [] if imu is None else [
                (topic, frame, acc, gyro) for topic, frame, acc, gyro in (
                    ("/imu", "enu", imu.acc_mps2, None), ("/imu/body", "body", imu.acc_body_mps2, imu.gyro_body_radps))
                if acc is not None or gyro is not None]
            for topic, frame, acc, gyro in channels:
                conn = w.add_connection(topic, Imu.__msgtype__, typestore=ts)
                n = imu.t_s.shape[0]
                acc_l = np.zeros((n, 3)).tolist() if acc is None else acc.tolist()
                gyro_l = np.zeros((n, 3)).tolist() if gyro is None else gyro.tolist()
                for ns, a, g in zip(_stamps_ns(imu.t_s), acc_l, gyro_l, strict=True):
                    msg = Imu(header=header(int(ns), frame), orientation=identity, orientation_covariance=no_cov,
                              angular_velocity=Vector3(x=g[0], y=g[1], z=g[2]),
                              angular_velocity_covariance=no_cov if gyro is None else zero_cov,
                              linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
                              linear_acceleration_covariance=no_cov if acc is None else zero_cov)
                    messages.append((int(ns), conn, ts.serialize_cdr(msg, Imu.__msgtype__)))
            u = trace.uwb
            ok = np.isfinite(u.range_m)
            max_range = float(np.max(u.range_m[ok])) if ok.any() else 0.0
            conns = {}
            for a_idx, a_id in enumerate(trace.anchors.ids):
                sel = ok & (u.anchor == a_idx)
                if not sel.any():
                    continue
                conns[a_idx] = w.add_connection(f"/uwb/{a_id}", Range.__msgtype__, typestore=ts)
                for ns, r in zip(_stamps_ns(u.t_s[sel]), u.range_m[sel].tolist(), strict=True):
                    msg = Range(header=header(int(ns), a_id), radiation_type=RADIO, field_of_view=float(2 * np.pi),
                                min_range=0.0, max_range=max_range, range=r)
                    messages.append((int(ns), conns[a_idx], ts.serialize_cdr(msg, Range.__msgtype__)))
            c_truth = w.add_connection("/truth", Point.__msgtype__, typestore=ts)
            for ns, p in zip(_stamps_ns(trace.truth.t_s), trace.truth.pos_enu_m.tolist(), strict=True):
                msg = Point(header=header(int(ns), "enu"), point=PointMsg(x=p[0], y=p[1], z=p[2]))
                messages.append((int(ns), c_truth, ts.serialize_cdr(msg, Point.__msgtype__)))
            if len(trace.anchors):
                messages.append(_anchor_frames(w, ts, trace, header(int(_stamps_ns(trace.truth.t_s[:1])[0]), "enu")))
            if trace.truth.quat_wxyz is not None:
                c_att = w.add_connection("/truth/orientation", QuatStamped.__msgtype__, typestore=ts)
                for ns, q in zip(_stamps_ns(trace.truth.t_s), trace.truth.quat_wxyz.tolist(), strict=True):
                    quat = Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])  # stored scalar-first (w, x, y, z)
                    msg = QuatStamped(header=header(int(ns), "enu"), quaternion=quat)
                    messages.append((int(ns), c_att, ts.serialize_cdr(msg, QuatStamped.__msgtype__)))
            messages.sort(key=lambda m: m[0])  # a bag is written in time order
            for ns, conn, data in messages:
                w.write(conn, ns, data)
