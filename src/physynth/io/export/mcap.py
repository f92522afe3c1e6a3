"""An MCAP file written from whole topics at once (NumPy): every message record built in one array.

The Python MCAP writers (``mcap``'s and the one inside ``rosbags``) take one call per message, 4 us
each here (2026-12-05, 2-core machine): with ~66,000 messages in a default trace that alone is 5x the time
of generating the trace. :func:`prepare_mcap` takes each channel's messages as one ``(n, size)`` uint8
array of CDR bytes (:mod:`.cdr`) and one int64 array of stamps and lays out the records with NumPy:

- the header, then the schemas and channels (in the data section, before the first chunk);
- chunks of about :data:`CHUNK_BYTES` of one channel's message records each (a slice of that channel's
  records, in time order), compressed or not (zstd, lz4), each followed by its message index; chunks in
  the order of their first stamps (they overlap in time: readers merge them by the indexes);
- a ``rosbag2`` metadata record (the bag's ``metadata.yaml`` text, as ROS 2's MCAP storage writes it);
- the summary: schemas, channels, statistics, chunk indexes, metadata index and summary offsets, then
  the footer. CRCs are 0 ("not computed", allowed by the specification).

The file is read back by the ``mcap`` library and by ``rosbags`` in ``tests/test_export_rosbag2.py``.
Format: https://mcap.dev/spec (version 0).
"""

from __future__ import annotations

import functools
import os
import struct
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
CHUNK_BYTES = 1 << 20
"""Message bytes per chunk (as rosbags and ROS 2 write: readers load one chunk at a time)."""

_MSG_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                      ("log_time", "<u8"), ("publish_time", "<u8")])  # packed: 31 bytes
MESSAGE_HEAD = _MSG_HEAD.itemsize
"""Bytes of a message record before the message itself: :class:`Channel` rows reserve them."""


@dataclass(frozen=True)
class Channel:
    """One topic: its name, message type (schema), schema text and encoding, its metadata, and its
    messages (``stamps`` int64 ns, sorted; ``data`` an ``(n, MESSAGE_HEAD + size)`` C-contiguous uint8
    array, one row per message: :data:`MESSAGE_HEAD` bytes that :func:`prepare_mcap` fills in place, then
    the message's bytes)."""

    topic: str
    schema_name: str
    schema_text: str
    schema_encoding: str
    metadata: dict[str, str]
    stamps: np.ndarray
    data: np.ndarray


def _s(text: str | bytes) -> bytes:
    b = text.encode("utf-8") if isinstance(text, str) else text
    return struct.pack("<I", len(b)) + b


def _map(entries: dict[str, str]) -> bytes:
    body = b"".join(_s(k) + _s(v) for k, v in entries.items())
    return struct.pack("<I", len(body)) + body


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _message_rows(ch: Channel, cid: int) -> np.ndarray:
    """The channel's message records: its rows (:data:`MESSAGE_HEAD` bytes reserved in front of each
    message's bytes) with the record heads filled in place (the constant part in one 2-D copy, then the
    log and publish times)."""
    n, width = ch.data.shape
    head = np.zeros(1, dtype=_MSG_HEAD)
    head["op"], head["length"], head["channel"] = 0x05, width - 9, cid
    const = _MSG_HEAD.fields["log_time"][1]  # op, length, channel and sequence: the bytes before the times
    ch.data[:, :const] = head.view(np.uint8)[:const]
    times = np.repeat(np.asarray(ch.stamps, dtype="<u8"), 2).view(np.uint8).reshape(n, 16)
    ch.data[:, const:MESSAGE_HEAD] = times
    return ch.data


def _compressor(compression: str) -> Callable[[bytes], bytes]:
    """The chunk compressor of ``compression`` ("", "zstd" at level 1, or "lz4")."""
    if compression == "":
        return bytes
    if compression == "zstd":
        try:
            from compression import zstd  # Python 3.14
        except ImportError:
            from backports import zstd  # what rosbags installs before 3.14
        return lambda data: zstd.compress(data, 1)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress
    raise ValueError(f"unknown MCAP chunk compression '{compression}' (choose '', 'zstd' or 'lz4')")


@functools.cache
def _pool_of(pid: int) -> ThreadPoolExecutor:  # noqa: ARG001 (a forked worker makes its own)
    return ThreadPoolExecutor(max(1, len(os.sched_getaffinity(0))), thread_name_prefix="physynth-mcap")


def _pool() -> ThreadPoolExecutor:
    """Threads that compress chunks (zstd and lz4 release the GIL): one per core this process may use."""
    return _pool_of(os.getpid())


def prepare_mcap(channels: Sequence[Channel], *, profile: str = "ros2", library: str = "physynth",
                 metadata: dict[str, dict[str, str]] | None = None, compression: str = "") -> PreparedMcap:
    """Lay out an MCAP file of ``channels`` (ids 1, 2, ... in order) and start compressing its chunks on
    the threads of :func:`_pool`; :meth:`PreparedMcap.write` writes it once they are done. The caller may
    prepare the next file meanwhile (what the ROS 2 export does: one bag's chunks compress while the next
    trace's messages are built). ``metadata``: named metadata records (name -> map); ``compression``: of
    every chunk ("" none, "zstd" at level 1, "lz4").

    Each chunk holds consecutive messages of one channel (in time order, about :data:`CHUNK_BYTES`), so
    that its bytes are a slice of the channel's records; the chunks are written in the order of their
    first stamps. Chunks of different channels overlap in time, as the format allows: readers in log-time
    order (``ros2 bag play``, Foxglove, ``rosbags``, ``mcap``) merge them through the chunk and message
    indexes.
    """
    schemas: dict[str, int] = {}
    schema_recs, channel_recs = [], []
    for cid, ch in enumerate(channels, 1):
        if ch.schema_name not in schemas:
            schemas[ch.schema_name] = len(schemas) + 1
            schema_recs.append(_record(0x03, struct.pack("<H", schemas[ch.schema_name]) + _s(ch.schema_name)
                                       + _s(ch.schema_encoding) + _s(ch.schema_text)))
        channel_recs.append(_record(0x04, struct.pack("<HH", cid, schemas[ch.schema_name]) + _s(ch.topic)
                                    + _s("cdr") + _map(ch.metadata)))
    rows = [_message_rows(ch, cid) for cid, ch in enumerate(channels, 1)]
    stamps = [np.asarray(ch.stamps, dtype=np.int64) for ch in channels]
    pieces = []  # (first stamp, channel index, first row, end row)
    for k, r in enumerate(rows):
        step = max(1, CHUNK_BYTES // r.shape[1])
        pieces += [(int(stamps[k][a]), k, a, min(a + step, r.shape[0])) for a in range(0, r.shape[0], step)]
    pieces.sort()
    bodies = [rows[k][a:b].data for _, k, a, b in pieces]
    packs: list[Future | memoryview] = (
        [_pool().submit(_compressor(compression), body) for body in bodies] if compression else list(bodies))
    return PreparedMcap(profile, library, metadata or {}, compression, len(schemas), schema_recs, channel_recs,
                        rows, stamps, pieces, bodies, packs)


@dataclass
class PreparedMcap:
    """An MCAP file laid out by :func:`prepare_mcap`, its chunks compressing (futures) or not."""

    profile: str
    library: str
    metadata: dict[str, dict[str, str]]
    compression: str
    n_schemas: int
    schema_recs: list[bytes]
    channel_recs: list[bytes]
    rows: list[np.ndarray]
    stamps: list[np.ndarray]
    pieces: list[tuple[int, int, int, int]]
    bodies: list[memoryview]
    packs: list[Future | memoryview]

    def write(self, f: BinaryIO) -> dict[int, int]:
        """Write the file to the open binary file ``f`` (waiting for each chunk's compression as it comes
        to it); returns the message count of each channel id."""
        compression, rows, stamps = self.compression, self.rows, self.stamps
        pos = 0

        def put(b: bytes | memoryview) -> None:
            nonlocal pos
            f.write(b)
            pos += b.nbytes if isinstance(b, memoryview) else len(b)

        put(MAGIC)
        put(_record(0x01, _s(self.profile) + _s(self.library)))
        for r in (*self.schema_recs, *self.channel_recs):
            put(r)
        chunk_indexes = []
        for (t0, k, a, b), body, pack in zip(self.pieces, self.bodies, self.packs, strict=True):
            packed = pack.result() if isinstance(pack, Future) else pack
            size = body.nbytes
            n_packed = packed.nbytes if isinstance(packed, memoryview) else len(packed)
            t1 = int(stamps[k][b - 1])
            chunk_start = pos
            put(struct.pack("<BQ", 0x06, 8 * 3 + 4 + 4 + len(compression) + 8 + n_packed))
            put(struct.pack("<QQQI", t0, t1, size, 0) + _s(compression) + struct.pack("<Q", n_packed))
            put(packed)
            chunk_end = pos
            pairs = np.empty((b - a, 2), dtype="<u8")
            pairs[:, 0] = stamps[k][a:b]
            pairs[:, 1] = np.arange(b - a, dtype=np.uint64) * np.uint64(rows[k].shape[1])
            put(_record(0x07, struct.pack("<HI", k + 1, pairs.nbytes) + pairs.tobytes()))
            chunk_indexes.append(_record(0x08, struct.pack("<QQQQ", t0, t1, chunk_start, chunk_end - chunk_start)
                                         + struct.pack("<I", 10) + struct.pack("<HQ", k + 1, chunk_end)
                                         + struct.pack("<Q", pos - chunk_end) + _s(compression)
                                         + struct.pack("<QQ", n_packed, size)))
        meta_index = []
        for name, entries in self.metadata.items():
            start = pos
            put(_record(0x0C, _s(name) + _map(entries)))
            meta_index.append(_record(0x0D, struct.pack("<QQ", start, pos - start) + _s(name)))
        put(_record(0x0F, struct.pack("<I", 0)))  # data end
        summary_start = pos
        groups = []
        for op, recs in ((0x03, self.schema_recs), (0x04, self.channel_recs), (0x08, chunk_indexes),
                         (0x0D, meta_index)):
            if recs:
                start = pos
                for r in recs:
                    put(r)
                groups.append((op, start, pos - start))
        counts = {cid: int(s.size) for cid, s in enumerate(stamps, 1)}
        nonempty = [s for s in stamps if s.size]
        t_min = min(int(s[0]) for s in nonempty) if nonempty else 0
        t_max = max(int(s[-1]) for s in nonempty) if nonempty else 0
        cnt = b"".join(struct.pack("<HQ", cid, n) for cid, n in counts.items())
        start = pos
        put(_record(0x0B, struct.pack("<QHIIII", sum(counts.values()), self.n_schemas, len(self.channel_recs), 0,
                                      len(meta_index), len(chunk_indexes))
                    + struct.pack("<QQI", t_min, t_max, len(cnt)) + cnt))
        groups.append((0x0B, start, pos - start))
        offset_start = pos
        for op, start, length in groups:
            put(_record(0x0E, struct.pack("<BQQ", op, start, length)))
        put(_record(0x02, struct.pack("<QQI", summary_start, offset_start, 0)))
        put(MAGIC)
        return counts
