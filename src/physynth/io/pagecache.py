"""Bulk outputs written behind: the kernel asked to write them out now and to drop them from its cache.

An export or a generation streams gigabytes that nothing reads back soon (a 1,000-trace CSV export is
3.8 GB). Left to the kernel, they pile up as dirty pages in the page cache until its background writeback
starts (by default at a tenth of memory), and writing slows down as they do: on the 2-core test machine, files written
in 64 kB pieces went at 2.4 GB/s for the first 650 MB, then at 0.35-0.6 GB/s. Asking, after each piece,
that the piece be written out now and the piece before it (written out by then) be dropped
(``posix_fadvise(..., POSIX_FADV_DONTNEED)``, which starts the writeback of dirty pages and frees clean
ones) kept the same writes at 1.4-1.5 GB/s. Where the call does not exist (not on Linux or other POSIX
systems), nothing is asked. The bytes written are the same either way; only the cache differs.
"""

from __future__ import annotations

import os


def write_behind(fd: int, start: int = 0, length: int = 0) -> None:
    """Ask the kernel to write ``length`` bytes of the open file ``fd`` from ``start`` (0: to its end) to
    disk now and to drop those already written from its cache. Errors are ignored: this is advice."""
    advise = getattr(os, "posix_fadvise", None)
    if advise is None:
        return
    try:
        advise(fd, start, length, os.POSIX_FADV_DONTNEED)
    except OSError:  # a file system or a file (a pipe) that takes no advice
        pass


class WriteBehind:
    """Write-behind of a file being appended piece by piece: :meth:`advance` after each piece starts its
    writeback and drops the piece before it (out of the cache once written)."""

    def __init__(self, fd: int, start: int = 0, piece: int | None = None) -> None:
        """``start``: where the piece before the last one starts; ``piece``: where the last one starts (the
        caller's own record of the pieces so far, for a file appended to by one process after another;
        None: ``start``, a file without pieces yet)."""
        self.fd = fd
        self._before = start  # start of the piece before the last one
        self._piece = start if piece is None else piece  # start of the last one

    def advance(self, end: int) -> None:
        """The file now ends at ``end``: the piece before the last one is dropped, the last one written out."""
        if end > self._before:
            write_behind(self.fd, self._before, end - self._before)
        self._before, self._piece = self._piece, end


def cache_allowance(proc: str = "/proc", cgroups: str = "/sys/fs/cgroup") -> int:
    """Bytes of a file being written that may stay in the page cache before writing them behind pays: where
    Linux starts its own background writeback (``vm.dirty_background_bytes``, or
    ``vm.dirty_background_ratio`` percent, 10 by default, of the memory this process may use:
    :func:`memory_bytes`); at twice that it makes writers wait. A file that stays below it is left to the
    kernel: written out after the command ends, where writing it behind would make the command wait for the
    disk (a 2 GB HDF5 export took 12 % longer so). ``proc`` and ``cgroups``: where the kernel shows them."""
    background = _read_int(f"{proc}/sys/vm/dirty_background_bytes")
    if background:
        return background
    ratio = _read_int(f"{proc}/sys/vm/dirty_background_ratio")
    return memory_bytes(proc, cgroups) * (10 if ratio is None else ratio) // 100


def memory_bytes(proc: str = "/proc", cgroups: str = "/sys/fs/cgroup") -> int:
    """The memory this process may use: the machine's physical memory, or the memory limit of its control
    group where lower (a container's: cgroup v2 ``memory.max`` or v1 ``memory.limit_in_bytes``, the
    lowest on the way from the process's group up to the root). Not POSIX: 1 << 62 (nothing is asked)."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return 1 << 62
    try:
        with open(f"{proc}/self/cgroup", encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except OSError:  # not Linux
        return total
    for line in lines:  # "0::/path" (v2), "4:memory:/path" (v1)
        _, controllers, path = line.split(":", 2) if line.count(":") >= 2 else ("", "-", "")
        if controllers == "":
            where = [(f"{cgroups}{sub}", "memory.max") for sub in ("", "/unified")]
        elif "memory" in controllers.split(","):
            where = [(f"{cgroups}/memory", "memory.limit_in_bytes")]
        else:
            continue
        parts = [p for p in path.split("/") if p]
        for root, name in where:
            for depth in range(len(parts), -1, -1):
                limit = _read_int(os.path.join(root, *parts[:depth], name))
                if limit:
                    total = min(total, limit)
    return total


def _read_int(path: str) -> int | None:
    """The whole number a kernel file holds, or None ("max", unreadable, absent)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return int(fh.read().strip())
    except (OSError, ValueError):
        return None
