"""Exports of a dataset to the formats other tools read: HDF5, ROS 2 bags, plain CSV.

Each exporter streams the dataset trace by trace (:func:`physynth.io.dataset.iter_traces`), writes to
a hidden temporary sibling of the output and renames it into place when complete, so an interrupted
export leaves nothing that looks finished. HDF5 needs ``h5py`` and ROS 2 bags need ``rosbags``
(the extra ``physynth[export]``); CSV needs nothing beyond PhySynth.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ...errors import PhySynthError
from ...progress import ProgressCallback, no_progress
from ..atomic import temp_sibling
from ..dataset import iter_indexed_traces, n_traces, read_meta
from ..safety import prepare_output, register_temporary, remove_tree, swap_in, unregister_temporary

FORMATS = ("hdf5", "rosbag2", "csv")


def _require(module: str) -> None:
    try:
        __import__(module)
    except ImportError:
        raise PhySynthError(f"exporting needs {module}: install the extra physynth[export] "
                           "(pip install -e '.[export]' in the PhySynth clone)") from None


def export_dataset(dataset: str | os.PathLike, out: str | os.PathLike, fmt: str, *, overwrite: bool = False,
                   progress: ProgressCallback = no_progress, bag_storage: str = "mcap") -> Path:
    """Export ``dataset`` to ``out`` in format ``fmt`` (one of :data:`FORMATS`); returns ``out``.

    - ``hdf5``: one file, one group ``/traces/<index>`` per trace (:mod:`.hdf5`);
    - ``rosbag2``: a folder with one ROS 2 bag per trace (:mod:`.rosbag2`), MCAP storage or, with
      ``bag_storage="sqlite3"``, SQLite3;
    - ``csv``: a folder with one CSV file per table (:mod:`.csv`).

    Every format reads the dataset as every reader does (:func:`~physynth.io.dataset.iter_indexed_traces`:
    files against ``dataset.json``, columns, valid traces) before its output appears; the CSV export,
    which copies the tables row group by row group, reads it trace by trace first to check it. The
    ROS 2 export leaves out messages with a NaN field or stamped before time 0 and says how many through
    ``progress``.
    """
    if fmt not in FORMATS:
        raise PhySynthError(f"unknown export format '{fmt}' (choose one of {', '.join(FORMATS)})")
    from .rosbag2 import STORAGES

    if bag_storage not in STORAGES:
        raise PhySynthError(f"unknown bag storage '{bag_storage}' (choose one of {', '.join(STORAGES)})")
    if fmt == "hdf5":
        _require("h5py")
    elif fmt == "rosbag2":
        _require("rosbags")
    meta = read_meta(dataset)
    # the same rules as every writer (docs/reliability.md): never the input, the current folder or a
    # parent of it; replaced only when it is an export PhySynth wrote (--overwrite); locked; temporary
    # files of an interrupted export removed with a warning
    out, lock = prepare_output(out, kind=f"export-{fmt}", overwrite=overwrite, inputs=[dataset])
    try:
        return _export(Path(dataset), meta, out, fmt, progress, bag_storage)
    finally:
        lock.release()


def _checked(dataset: Path, meta: dict, message: str, total: int | None,
             progress: ProgressCallback) -> Iterator[tuple[int, Any]]:
    """The dataset's ``(index, Trace)`` pairs, read and checked as every reader does (files against
    ``dataset.json``, columns, valid records), with ``progress(message, done, total)`` after each."""
    for done, item in enumerate(iter_indexed_traces(dataset, meta), 1):
        yield item
        progress(message, done, total)


def _export(dataset: Path, meta: dict, out: Path, fmt: str, progress: ProgressCallback, storage: str) -> Path:
    total = n_traces(meta)
    tmp = temp_sibling(out)
    remove_tree(tmp)
    writer: Callable
    if fmt == "hdf5":
        from .hdf5 import write_hdf5 as writer
    elif fmt == "rosbag2":
        from .rosbag2 import write_rosbag2 as writer
    else:
        from .csv import write_csv as writer
    register_temporary(tmp)
    try:
        if fmt == "csv":  # copied table by table: first read trace by trace, checked as by the other formats
            deque(_checked(dataset, meta, "checking the dataset", total, progress), maxlen=0)
            writer(dataset, meta, tmp, progress)
        else:
            args = (storage,) if fmt == "rosbag2" else ()
            skipped = writer(_checked(dataset, meta, f"exporting to {fmt}", total, progress), meta, tmp, *args)
            _say_skipped(skipped or {}, progress)
        swap_in(tmp, out)
    except BaseException:
        remove_tree(tmp)
        raise
    finally:
        unregister_temporary(tmp)
    return out


def _say_skipped(skipped: dict[str, int], progress: ProgressCallback) -> None:
    """One progress line for the ROS 2 messages left out with a NaN field and one for those stamped
    before time 0 (counted as ``"<topic> (before 0 s)"``)."""
    early = {k.removesuffix(" (before 0 s)"): n for k, n in skipped.items() if k.endswith(" (before 0 s)")}
    nan = {k: n for k, n in skipped.items() if not k.endswith(" (before 0 s)")}
    for what, counts in (("with a NaN field", nan), ("stamped before 0 s (a ROS time is never negative)", early)):
        if counts:
            progress(f"left out {sum(counts.values())} message(s) {what}: "
                     + ", ".join(f"{topic} {n}" for topic, n in counts.items()))
