"""CDR bytes of fixed-layout ROS 2 messages, a whole topic of a trace at once (NumPy, no object per message).

A message whose fields are numbers and one string of known length (the header's frame id, the same in
every message of a topic) has one byte layout for all its messages: a NumPy structured dtype with
explicit offsets. :func:`layout` computes those offsets by the rules of CDR (XCDR1, little endian, as
ROS 2 writes it): a 4-byte encapsulation header ``00 01 00 00``, then every primitive aligned to its own
size counted from the end of the encapsulation header, a string as a uint32 length (with the NUL) and
its bytes with the NUL, no padding after the last field. :func:`messages` describes a topic's messages
(the bytes they share as one template row, the fields that vary as arrays); :meth:`Messages.fill` writes
any slice of their rows into a uint8 array (the MCAP export fills each chunk on the thread that then
compresses it, while the rows are in that core's cache) and :func:`records` lays them all out at once as
an ``(n, size)`` uint8 array.

Every layout here is checked byte for byte against ``rosbags``' own serialiser (``Typestore.serialize_cdr``)
in ``tests/test_export_rosbag2.py``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ENCAPSULATION = np.frombuffer(b"\x00\x01\x00\x00", dtype=np.uint8)
"""CDR little-endian encapsulation header of every ROS 2 message."""

Field = tuple[str, str, int]
"""(name, NumPy base type like ``<f8``, count) of a message's flattened fields, in message order."""


def _header_fields(frame: bytes) -> list[Field]:
    """``std_msgs/Header``: stamp (sec int32, nanosec uint32) and the frame id string."""
    return [("sec", "<i4", 1), ("nanosec", "<u4", 1), ("frame_len", "<u4", 1), ("frame", f"S{len(frame) + 1}", 1)]


def _vec(name: str, comps: str = "xyz") -> list[Field]:
    return [(f"{name}_{c}", "<f8", 1) for c in comps]


def imu_fields(frame: bytes) -> list[Field]:
    """``sensor_msgs/msg/Imu``."""
    return [*_header_fields(frame), *_vec("orientation", "xyzw"), ("orientation_covariance", "<f8", 9),
            *_vec("angular_velocity"), ("angular_velocity_covariance", "<f8", 9),
            *_vec("linear_acceleration"), ("linear_acceleration_covariance", "<f8", 9)]


def range_fields(frame: bytes) -> list[Field]:
    """``sensor_msgs/msg/Range`` (as in Humble: no ``variance`` field)."""
    return [*_header_fields(frame), ("radiation_type", "u1", 1), ("field_of_view", "<f4", 1),
            ("min_range", "<f4", 1), ("max_range", "<f4", 1), ("range", "<f4", 1)]


def point_stamped_fields(frame: bytes) -> list[Field]:
    """``geometry_msgs/msg/PointStamped``."""
    return [*_header_fields(frame), *_vec("point")]


def quaternion_stamped_fields(frame: bytes) -> list[Field]:
    """``geometry_msgs/msg/QuaternionStamped``."""
    return [*_header_fields(frame), *_vec("quaternion", "xyzw")]


def layout(fields: Sequence[Field], reserve: int = 0) -> np.dtype:
    """The structured dtype of a message's CDR bytes (encapsulation header included): each field at its
    CDR offset (aligned to its primitive size, counted from byte 4), itemsize the end of the last field;
    with ``reserve`` bytes in front of the message (left for a container's record head)."""
    names, formats, offsets = ["encapsulation"], [("u1", (4,))], [reserve]
    pos = 0  # relative to the end of the encapsulation header
    for name, base, count in fields:
        dt = np.dtype(base)
        align = 1 if dt.kind == "S" else dt.itemsize
        pos += -pos % align
        names.append(name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(reserve + 4 + pos)
        pos += dt.itemsize * count
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": reserve + 4 + pos})


@dataclass(frozen=True)
class Messages:
    """Messages of one fixed layout, their bytes written on demand (:meth:`fill`), a slice of rows at a
    time: the MCAP export fills and compresses each chunk's rows on its own thread (:mod:`.mcap`).

    ``dtype``: :func:`layout`; ``template``: the bytes every message shares (encapsulation, frame id,
    constant fields, zero padding); ``stamps``: int64 ns; ``varying``: the fields that differ per message
    (arrays of ``n`` rows)."""

    dtype: np.dtype
    template: np.ndarray
    stamps: np.ndarray
    varying: dict[str, np.ndarray]

    @property
    def n(self) -> int:
        """Number of messages."""
        return int(self.stamps.shape[0])

    @property
    def size(self) -> int:
        """Bytes per row (reserved bytes and the message)."""
        return int(self.dtype.itemsize)

    def fill(self, rows: np.ndarray, start: int = 0, prefix: bytes = b"") -> np.ndarray:
        """Write messages ``start .. start + len(rows) - 1`` into ``rows``, a C-contiguous ``(m, size)``
        uint8 array (every byte: reserved ones zero, or ``prefix`` over the first of them), and return it."""
        m = rows.shape[0]
        template = self.template[0]
        if prefix:  # e.g. the constant part of a container's record head, written with the rest
            row = bytearray(template.tobytes())
            row[:len(prefix)] = prefix
            template = np.void(bytes(row))
        rows.reshape(-1).view(self.template.dtype)[:] = template  # raw bytes, padding included
        out = rows.reshape(-1).view(self.dtype)
        ns = self.stamps[start:start + m]
        out["sec"] = ns // 1_000_000_000
        out["nanosec"] = ns % 1_000_000_000
        for name, value in self.varying.items():
            out[name] = value[start:start + m]
        return rows

    def rows(self) -> np.ndarray:
        """All messages as one ``(n, size)`` uint8 array."""
        return self.fill(np.empty((self.n, self.size), dtype=np.uint8))


@dataclass(frozen=True)
class Prebuilt:
    """Messages already serialised, as an ``(n, size)`` uint8 array (e.g. by ``rosbags``), with the
    interface of :class:`Messages`."""

    data: np.ndarray

    @property
    def n(self) -> int:
        return int(self.data.shape[0])

    @property
    def size(self) -> int:
        return int(self.data.shape[1])

    def fill(self, rows: np.ndarray, start: int = 0, prefix: bytes = b"") -> np.ndarray:
        rows[:] = self.data[start:start + rows.shape[0]]
        rows[:, :len(prefix)] = np.frombuffer(prefix, dtype=np.uint8)
        return rows

    def rows(self) -> np.ndarray:
        return self.data


def messages(fields: Sequence[Field], stamps_ns: np.ndarray, frame: bytes, *, reserve: int = 0,
             **values: object) -> Messages:
    """``len(stamps_ns)`` messages of one layout, to be filled (:meth:`Messages.fill`) or laid out at once
    (:meth:`Messages.rows`, :func:`records`).

    ``stamps_ns`` (int64, >= 0) fill the header stamp; ``frame`` is the header's frame id (ASCII or UTF-8,
    no NUL); every other field takes ``values[name]`` (a scalar or an array of one value per message);
    fields not given are zero. ``reserve``: zero bytes in front of every row (a container's record head,
    e.g. :data:`physynth.io.export.mcap.MESSAGE_HEAD`, which the container fills in place).
    """
    dt = layout(fields, reserve)
    # the fields that are the same in every message (encapsulation, frame id, constants such as covariances)
    # go into one template row, copied into every row as raw bytes; then only the varying fields are written
    template = np.zeros(1, dtype=dt)
    template["encapsulation"] = ENCAPSULATION
    template["frame_len"] = len(frame) + 1
    template["frame"] = frame
    varying = {}
    for name, value in values.items():
        if np.ndim(value) > len(dt[name].shape):
            varying[name] = np.asarray(value)
        else:
            template[name] = value
    return Messages(dt, template.view(np.dtype((np.void, dt.itemsize))), np.asarray(stamps_ns, dtype=np.int64),
                    varying)


def records(fields: Sequence[Field], stamps_ns: np.ndarray, frame: bytes, *, reserve: int = 0,
            **values: object) -> np.ndarray:
    """The CDR bytes of ``len(stamps_ns)`` messages of one layout, as an ``(n, size)`` uint8 array
    (:func:`messages`, laid out at once)."""
    return messages(fields, stamps_ns, frame, reserve=reserve, **values).rows()
