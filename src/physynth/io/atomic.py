"""Atomic writes: a file appears complete under its name or not at all.

Every writer of PhySynth goes through here: the data is written to a hidden temporary sibling (same
folder, so the same file system) and renamed into place with :func:`os.replace`, which is atomic on
POSIX and Windows. Directories (datasets) use the same temporary name and are swapped in by
:class:`physynth.io.dataset.DatasetWriter`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

_W = TypeVar("_W", bound="ClosesOrAborts")


class ClosesOrAborts:
    """A writer used as a ``with`` block: :meth:`close` (the output swapped into place) when the block ends,
    :meth:`abort` (what was written removed) when it raises. Subclasses define both."""

    def close(self) -> object:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self: _W) -> _W:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


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


@contextmanager
def files_together(paths: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Write several files as one output (a scenario and its fit report): the block writes the yielded
    temporary siblings of ``paths``, which are renamed onto ``paths`` once it ends; if it fails (or is
    interrupted) none is renamed and every temporary is removed, so no new file appears without the others."""
    pending = [(temp_sibling(Path(p)), Path(p)) for p in paths]
    try:
        yield [tmp for tmp, _ in pending]
        for tmp, final in pending:
            os.replace(tmp, final)
    finally:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
