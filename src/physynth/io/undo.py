"""A file opened for update with an undo journal: its bytes as they were when it was opened can be restored
after the process that was writing it died (SIGKILL) in the middle.

:class:`UndoFile` is a :class:`io.FileIO` whose writes (and truncations) that touch the bytes the file had
when it was opened first save those bytes, with their offset, to a journal file; writes past the original
end are only appended, so :func:`roll_back` restores the file by writing the saved bytes back (the last
saved first) and cutting the file to its original size. A journal's record is written before the bytes
it saves are overwritten, so a record cut short by a kill saved bytes that were never overwritten and is
ignored. An HDF5 file appended to in place (h5py's file-object driver: :mod:`physynth.io.export.hdf5`)
rewrites only a few kilobytes of its earlier metadata, so the journal stays small.
"""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path

_MAGIC = b"physynth-undo/1\n"
_HEADER = struct.Struct("<Q")  # the file's size when it was opened
_RECORD = struct.Struct("<QQ")  # offset, length of the saved bytes that follow


class UndoFile(io.FileIO):
    """``path`` opened for reading and writing (it must exist), its original bytes saved to ``journal``
    (a new file) before they are overwritten. Close it, then remove the journal once what was written is
    kept; :func:`roll_back` undoes it."""

    def __init__(self, path: str | os.PathLike, journal: str | os.PathLike) -> None:
        super().__init__(path, "r+b")
        try:
            self.base = os.fstat(self.fileno()).st_size
            self._journal = open(journal, "xb", buffering=0)  # noqa: SIM115 - closed with the file
        except BaseException:
            super().close()
            raise
        self._journal.write(_MAGIC + _HEADER.pack(self.base))

    def _save(self, start: int, end: int) -> None:
        """Journal the original bytes ``start .. end`` (clipped to the original size) before they change."""
        end = min(end, self.base)
        if start < end:
            old = os.pread(self.fileno(), end - start, start)
            self._journal.write(_RECORD.pack(start, len(old)) + old)  # unbuffered: in the kernel before the
            # bytes it saves are overwritten, which a kill of this process cannot undo

    def write(self, b) -> int:  # type: ignore[override]
        pos = self.tell()
        self._save(pos, pos + memoryview(b).nbytes)
        return super().write(b)

    def truncate(self, size: int | None = None) -> int:
        size = self.tell() if size is None else size
        self._save(size, self.base)
        return super().truncate(size)

    def close(self) -> None:
        try:
            super().close()
        finally:
            if hasattr(self, "_journal"):
                self._journal.close()


def roll_back(path: str | os.PathLike, journal: str | os.PathLike) -> None:
    """Restore ``path`` to its bytes when the :class:`UndoFile` that wrote ``journal`` opened it, then
    remove ``journal``. A journal without a complete header (its file was being opened) changed nothing.

    Raises
    ------
    OSError
        When ``path`` cannot be written.
    """
    data = Path(journal).read_bytes()
    head = len(_MAGIC) + _HEADER.size
    if len(data) >= head and data.startswith(_MAGIC):
        (base,) = _HEADER.unpack_from(data, len(_MAGIC))
        records = []
        at = head
        while at + _RECORD.size <= len(data):
            start, n = _RECORD.unpack_from(data, at)
            at += _RECORD.size
            if at + n > len(data):  # cut short by a kill: its bytes were not overwritten yet
                break
            records.append((start, at, n))
            at += n
        fd = os.open(path, os.O_RDWR)
        try:
            view = memoryview(data)
            for start, at, n in reversed(records):  # the oldest saved bytes of a place written last
                os.pwrite(fd, view[at:at + n], start)
            os.ftruncate(fd, base)
        finally:
            os.close(fd)
    os.unlink(journal)
