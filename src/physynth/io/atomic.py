"""Atomic writes: a file appears complete under its name or not at all.

Every writer of PhySynth goes through here: the data is written to a hidden temporary sibling (same
folder, so the same file system) and renamed into place with :func:`os.replace`, which is atomic on
POSIX and Windows. Directories (datasets) use the same temporary name and are swapped in by
:class:`physynth.io.dataset.DatasetWriter`.
"""

from __future__ import annotations

import os
from pathlib import Path


def temp_sibling(path: Path) -> Path:
    """The hidden temporary name used while ``path`` is being written: ``.<name>.tmp-<pid>``."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write a file atomically (temporary name in the same folder, then rename)."""
    path = Path(path)
    tmp = temp_sibling(path)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write a UTF-8 text file atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))
