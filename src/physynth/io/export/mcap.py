"""An MCAP file written from whole topics at once (NumPy): the message records built chunk by chunk.

The Python MCAP writers (``mcap``'s and the one inside ``rosbags``) take one call per message, 4 us
each here (2026-12-05, 2-core machine): with ~66,000 messages in a default trace that alone is 5x the time
of generating the trace. :func:`prepare_mcap` takes each channel's messages as a description of their
CDR bytes (:class:`.cdr.Messages`) and one int64 array of stamps and lays out the records with NumPy, one
chunk per task on a pool of threads: the chunk's rows filled and their record heads written in the
thread's scratch buffer, then compressed while they are in that core's cache (a chunk built in a buffer
of the whole file, cold since the file before, took twice the CPU time); uncompressed, into one buffer of
the whole file, given back for the next file once written (fresh memory is faulted in page by page):

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
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
CHUNK_BYTES = 2 << 20
"""Message bytes per chunk (readers load one chunk at a time; ROS 2 writes 768 KiB, rosbags 1 MiB). Each chunk
is a task of the pool, and its threads take turns at the GIL between NumPy calls: with 1 MiB chunks a
1,000-trace export spent about a tenth more time per bag (2026-12-06, 2-core machine)."""

_MSG_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                      ("log_time", "<u8"), ("publish_time", "<u8")])  # packed: 31 bytes
MESSAGE_HEAD = _MSG_HEAD.itemsize
"""Bytes of a message record before the message itself: :class:`Channel` rows reserve them."""


@dataclass(frozen=True)
class Channel:
    """One topic: its name, message type (schema), schema text and encoding, its metadata, and its
    messages (``stamps`` int64 ns, sorted; ``messages`` writes their rows on demand: ``.n`` rows of
    ``.size`` bytes, ``.fill(rows, start)`` writes rows ``start ..`` into a C-contiguous uint8 array, as
    :class:`physynth.io.export.cdr.Messages`: :data:`MESSAGE_HEAD` bytes that :func:`prepare_mcap` fills
    in place, then the message's bytes)."""

    topic: str
    schema_name: str
    schema_text: str
    schema_encoding: str
    metadata: dict[str, str]
    stamps: np.ndarray
    messages: Any


def _s(text: str | bytes) -> bytes:
    b = text.encode("utf-8") if isinstance(text, str) else text
    return struct.pack("<I", len(b)) + b


def _map(entries: dict[str, str]) -> bytes:
    body = b"".join(_s(k) + _s(v) for k, v in entries.items())
    return struct.pack("<I", len(body)) + body


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


_TIMES = MESSAGE_HEAD - 16
"""Offset of a message record's log and publish times (after op, length, channel and sequence)."""


def _head_prefix(width: int, cid: int) -> bytes:
    """The constant part of the record heads of a channel's messages (rows of ``width`` bytes): op,
    length, channel and sequence (0), the bytes before the log and publish times."""
    head = np.zeros(1, dtype=_MSG_HEAD)
    head["op"], head["length"], head["channel"] = 0x05, width - 9, cid
    return head.tobytes()[:_TIMES]


def _chunk(messages: Any, rows: np.ndarray | None, start: int, end: int, cid: int, stamps: np.ndarray,
           compression: str) -> tuple[list[bytes | memoryview], int]:
    """One chunk (what a thread of :func:`_pool` makes): rows ``start .. end - 1`` of a channel's messages
    written into ``rows`` (a slice of the channel's records; None: this thread's scratch buffer) with their
    record heads (the constant part with the messages' shared bytes, then the times), compressed or not,
    and laid out as the chunk record followed by its message index record. Returns those bytes (one piece
    when compressed, else the chunk's head, its records as they lie in ``rows`` and the index) and the
    length of the chunk's (compressed) records. Built and compressed while in the core's cache; the caller
    only writes."""
    width, n = messages.size, end - start
    if rows is None:  # compressed: built in this thread's scratch buffer, in its core's cache since the last chunk
        rows = _scratch(n * width).reshape(n, width)
    messages.fill(rows, start, prefix=_head_prefix(width, cid))
    times = np.dtype({"names": ["t"], "formats": ["V16"], "offsets": [_TIMES], "itemsize": width})
    stamps = np.asarray(stamps, dtype="<u8")
    rows.reshape(-1).view(times)["t"] = np.repeat(stamps, 2).view("V16")
    packed = _compressor(compression)(rows.data) if compression else rows.data
    n_packed = packed.nbytes if isinstance(packed, memoryview) else len(packed)
    head = (struct.pack("<BQ", 0x06, 8 * 3 + 4 + 4 + len(compression) + 8 + n_packed)
            + struct.pack("<QQQI", int(stamps[0]), int(stamps[-1]), n * width, 0) + _s(compression)
            + struct.pack("<Q", n_packed))
    pairs = np.empty((n, 2), dtype="<u8")  # the message index: (log time, offset in the chunk's records)
    pairs[:, 0] = stamps
    pairs[:, 1] = np.arange(0, n * width, width, dtype=np.uint64)
    index = struct.pack("<BQHI", 0x07, 2 + 4 + pairs.nbytes, cid, pairs.nbytes) + pairs.tobytes()
    if compression:  # one piece: the caller makes one write per chunk
        return [b"".join((head, packed, index))], n_packed
    return [head, packed, index], n_packed


@functools.cache
def _local_of(pid: int) -> threading.local:  # noqa: ARG001 (a forked worker: its own)
    return threading.local()


def _scratch(nbytes: int) -> np.ndarray:
    """This thread's scratch buffer (the records of the chunk it compresses), ``nbytes`` of it."""
    local = _local_of(os.getpid())
    buf = getattr(local, "scratch", None)
    if buf is None or buf.nbytes < nbytes:
        buf = local.scratch = np.empty(max(nbytes, CHUNK_BYTES + (1 << 16)), dtype=np.uint8)
    return buf[:nbytes]


ZSTD_LEVEL = 1
"""zstd level of compressed chunks: ROS 2's MCAP storage writes level 1 by default."""
ZSTD_HASH_LOG, ZSTD_MIN_MATCH = 7, 7
"""zstd's match finder sized for message records (level 1 otherwise): a hash table of 2^7 entries and
matches of at least 7 bytes. Records of one layout repeat every few hundred bytes, so a small table finds
the same matches: a default trace's chunks compress about a fifth faster than with level 1's own table
(2^14 entries, matches of 6 bytes), and 3-4 % smaller (with and without the body-frame IMU); same format."""


def _zstd() -> Any:
    try:
        from compression import zstd  # Python 3.14
    except ImportError:
        from backports import zstd  # what rosbags installs before 3.14
    return zstd


def _zstd_compressor() -> Callable[[bytes | memoryview], bytes]:
    """zstd compression of one chunk into one frame, with one compression context per thread (made once:
    creating one per chunk cost 5 %)."""
    zstd = _zstd()
    opt = zstd.CompressionParameter
    options = {opt.compression_level: ZSTD_LEVEL, opt.hash_log: ZSTD_HASH_LOG, opt.min_match: ZSTD_MIN_MATCH}
    local = threading.local()

    def compress(data: bytes | memoryview) -> bytes:
        c = getattr(local, "compressor", None)
        if c is None:
            c = local.compressor = zstd.ZstdCompressor(options=options)
        try:
            return c.compress(data, mode=zstd.ZstdCompressor.FLUSH_FRAME)
        except BaseException:
            local.compressor = None  # a frame left unfinished: the next chunk starts a new context
            raise

    return compress


@functools.cache
def _compressor(compression: str) -> Callable[[bytes | memoryview], bytes]:
    """The chunk compressor of ``compression`` ("", "zstd" at level 1, or "lz4"), made once per process."""
    if compression == "":
        return bytes
    if compression == "zstd":
        return _zstd_compressor()
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


KEEP_BUFFERS = 2
"""Buffers of written uncompressed files kept for the next files (per process): the files in flight at once
(one being filled while the one before is written)."""


@functools.cache
def _free_of(pid: int) -> tuple[threading.Lock, list[np.ndarray]]:  # noqa: ARG001 (a forked worker: its own)
    return threading.Lock(), []


def _buffer(nbytes: int) -> np.ndarray:
    """A uint8 buffer of at least ``nbytes``: one a file written before gave back (:func:`_give_back`) or a
    new one, a quarter larger (the next traces may be longer). Fresh memory is faulted in by the kernel page
    by page (about 2 ms for a default trace's 17 MB), reused memory is not."""
    lock, free = _free_of(os.getpid())
    with lock:
        for i, b in enumerate(free):
            if b.nbytes >= nbytes:
                return free.pop(i)
    return np.empty(nbytes + nbytes // 4, dtype=np.uint8)


def _give_back(buffer: np.ndarray) -> None:
    lock, free = _free_of(os.getpid())
    with lock:
        free.append(buffer)
        free.sort(key=lambda b: b.nbytes)  # the smallest that fits is taken first
        del free[:-KEEP_BUFFERS]


def prepare_mcap(channels: Sequence[Channel], *, profile: str = "ros2", library: str = "physynth",
                 metadata: dict[str, dict[str, str]] | None = None, compression: str = "") -> PreparedMcap:
    """Lay out an MCAP file of ``channels`` (ids 1, 2, ... in order) and start building and compressing its
    chunks on the threads of :func:`_pool`; :meth:`PreparedMcap.write` writes it once they are done. The
    caller may prepare the next file meanwhile (what the ROS 2 export does: one bag's chunks are built while
    the next trace's messages are described). ``metadata``: named metadata records (name -> map); ``compression``: of
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
    widths = [ch.messages.size for ch in channels]
    stamps = [np.asarray(ch.stamps, dtype=np.int64) for ch in channels]
    pieces = []  # (first stamp, channel index, first row, end row)
    for k, ch in enumerate(channels):
        n, step = ch.messages.n, max(1, CHUNK_BYTES // widths[k])
        pieces += [(int(stamps[k][a]), k, a, min(a + step, n)) for a in range(0, n, step)]
    pieces.sort()
    if compression:
        _compressor(compression)  # an unknown compression fails here, not on a thread
    buffer, rows = None, [None] * len(channels)
    if not compression:  # the records are written as they are: every channel's, in one buffer until then
        sizes = [ch.messages.n * w for ch, w in zip(channels, widths, strict=True)]
        buffer = _buffer(sum(sizes))
        ends = np.cumsum([0, *sizes]).tolist()
        rows = [buffer[ends[k]:ends[k + 1]].reshape(-1, widths[k]) for k in range(len(channels))]
    packs = [_pool().submit(_chunk, channels[k].messages, None if rows[k] is None else rows[k][a:b], a, b, k + 1,
                            stamps[k][a:b], compression) for _, k, a, b in pieces]
    return PreparedMcap(profile, library, metadata or {}, compression, len(schemas), schema_recs, channel_recs,
                        buffer, widths, stamps, pieces, packs)


@dataclass
class PreparedMcap:
    """An MCAP file laid out by :func:`prepare_mcap`: its chunks being built (futures); uncompressed, in
    ``buffer``, given back for the next file once written."""

    profile: str
    library: str
    metadata: dict[str, dict[str, str]]
    compression: str
    n_schemas: int
    schema_recs: list[bytes]
    channel_recs: list[bytes]
    buffer: np.ndarray | None
    widths: list[int]
    stamps: list[np.ndarray]
    pieces: list[tuple[int, int, int, int]]
    packs: list[Future]

    def write(self, f: BinaryIO) -> dict[int, int]:
        """Write the file to the open binary file ``f`` (waiting for each chunk's compression as it comes
        to it); returns the message count of each channel id."""
        compression, widths, stamps = self.compression, self.widths, self.stamps
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
        for (t0, k, a, b), pack in zip(self.pieces, self.packs, strict=True):
            pieces, n_packed = pack.result()
            chunk_start = pos
            for piece in pieces:
                put(piece)
            chunk_len = 9 + 8 * 3 + 4 + 4 + len(compression) + 8 + n_packed  # the chunk record, then its index
            chunk_end = chunk_start + chunk_len
            chunk_indexes.append(_record(0x08, struct.pack("<QQQQ", t0, int(stamps[k][b - 1]), chunk_start,
                                                           chunk_len)
                                         + struct.pack("<I", 10) + struct.pack("<HQ", k + 1, chunk_end)
                                         + struct.pack("<Q", pos - chunk_end) + _s(compression)
                                         + struct.pack("<QQ", n_packed, (b - a) * widths[k])))
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
        self.packs = []  # every chunk written: the buffer is free for the next file
        if self.buffer is not None:
            _give_back(self.buffer)
        return counts
