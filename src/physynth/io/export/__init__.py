"""Exports of a dataset to the formats other tools read: HDF5, ROS 2 bags, plain CSV.

Each exporter streams the dataset trace by trace (:func:`physynth.io.dataset.iter_traces`), writes to
a hidden temporary sibling of the output and renames it into place when complete, so an interrupted
export leaves nothing that looks finished. HDF5 needs ``h5py`` and ROS 2 bags need ``rosbags``
(``pip install 'physynth[export]'``); CSV needs nothing beyond PhySynth.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

from ...errors import OutputExistsError, PhySynthError
from ...progress import ProgressCallback, no_progress
from ..atomic import temp_sibling
from ..dataset import iter_indexed_traces, n_traces, read_meta

FORMATS = ("hdf5", "rosbag2", "csv")


def _require(module: str) -> None:
    try:
        __import__(module)
    except ImportError:
        raise PhySynthError(f"exporting needs {module}: pip install 'physynth[export]'") from None


def export_dataset(dataset: str | os.PathLike, out: str | os.PathLike, fmt: str, *, overwrite: bool = False,
                   progress: ProgressCallback = no_progress) -> Path:
    """Export ``dataset`` to ``out`` in format ``fmt`` (one of :data:`FORMATS`); returns ``out``.

    - ``hdf5``: one file, one group ``/traces/<index>`` per trace (:mod:`.hdf5`);
    - ``rosbag2``: a folder with one ROS 2 bag per trace (:mod:`.rosbag2`);
    - ``csv``: a folder with one CSV file per table (:mod:`.csv`).
    """
    if fmt not in FORMATS:
        raise PhySynthError(f"unknown export format '{fmt}' (choose one of {', '.join(FORMATS)})")
    if fmt == "hdf5":
        _require("h5py")
    elif fmt == "rosbag2":
        _require("rosbags")
    out = Path(out)
    if out.exists() and not overwrite:
        raise OutputExistsError(out)
    meta = read_meta(dataset)
    total = n_traces(meta)
    tmp = temp_sibling(out)
    if tmp.exists():
        shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
    writer: Callable
    if fmt == "hdf5":
        from .hdf5 import write_hdf5 as writer
    elif fmt == "rosbag2":
        from .rosbag2 import write_rosbag2 as writer
    else:
        from .csv import write_csv as writer
    counter = {"done": 0}

    def traces():
        for item in iter_indexed_traces(dataset, meta):
            yield item
            counter["done"] += 1
            progress(f"exporting to {fmt}", counter["done"], total)

    try:
        if fmt == "csv":  # table by table, row group by row group: no records needed
            writer(Path(dataset), meta, tmp, progress)
        else:
            writer(traces(), meta, tmp)
        if out.exists():
            shutil.rmtree(out) if out.is_dir() else out.unlink()
        os.replace(tmp, out)
    except BaseException:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink()
        raise
    return out
