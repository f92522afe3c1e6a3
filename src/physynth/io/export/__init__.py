"""Exports of a dataset to the formats other tools read: HDF5, ROS 2 bags, plain CSV.

Each export is cut into parts, one per shard of the dataset (:mod:`.parts`), written into a hidden
sibling of the output that is renamed into place when every part is complete, so an interrupted export
leaves nothing that looks finished and can be resumed; the parts may run on several workers (``run``:
:func:`physynth.workflows.export_dataset` passes the workers of ``generate``), with the same bytes for any
number of workers. HDF5 needs ``h5py``, ROS 2 bags need ``rosbags`` and CSV needs ``polars`` (the extra
``physynth[export]`` installs them).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ...errors import PhySynthError
from ...progress import ProgressCallback, no_progress
from ..atomic import atomic_write_text, temp_sibling
from ..dataset import n_traces, read_meta
from ..safety import prepare_output, register_temporary, remove_tree, swap_in, unregister_temporary
from .parts import Part, assemble, dataset_parts, export_part, marker, recover_h5, run_record, written_apart

FORMATS = ("hdf5", "rosbag2", "csv")

Runner = Callable[..., list[Any]]
"""``run(fn, tasks, sizes, progress)``: ``[fn(*task) for task in tasks]`` in task order, somewhere
(:func:`physynth.parallel.run_tasks`); ``progress(done)`` with the units (traces) done so far."""


def _require(module: str) -> None:
    try:
        __import__(module)
    except ImportError:
        raise PhySynthError(f"exporting needs {module}: install the extra physynth[export] "
                           "(pip install -e '.[export]' in the PhySynth clone)") from None


def _in_process(fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], sizes: Sequence[int],
                progress: Callable[[int], None]) -> list[Any]:
    done = 0

    def unit() -> None:
        nonlocal done
        done += 1
        progress(done)

    return [fn(*task, on_unit=unit) for task in tasks]


def partial_dir(out: Path) -> Path:
    """The hidden folder of an unfinished export to ``out``."""
    return out.with_name(f".{out.name}.partial")


def export_dataset(dataset: str | os.PathLike, out: str | os.PathLike, fmt: str, *, overwrite: bool = False,
                   progress: ProgressCallback = no_progress, bag_storage: str = "mcap", resume: bool = False,
                   run: Runner | None = None) -> Path:
    """Export ``dataset`` to ``out`` in format ``fmt`` (one of :data:`FORMATS`); returns ``out``.

    - ``hdf5``: one file, one group ``/traces/<index>`` per trace (:mod:`.hdf5`);
    - ``rosbag2``: a folder with one ROS 2 bag per trace (:mod:`.rosbag2`), MCAP storage or, with
      ``bag_storage="sqlite3"``, SQLite3;
    - ``csv``: a folder with one CSV file per table (:mod:`.csv`).

    Every format checks the dataset before its output appears: ROS 2 bags read it as every reader does
    (:func:`~physynth.io.dataset.iter_indexed_traces`: files against ``dataset.json``, columns, valid
    traces); HDF5 and CSV, which copy the tables as stored, check the files against the integrity record
    (:func:`~physynth.io.dataset.iter_stored_traces`; CSV also each table's columns, :func:`.csv.check_tables`)
    and, for a dataset without one, make every trace's record too. The ROS 2 export
    leaves out messages with a NaN field or stamped before time 0 and says how many through ``progress``.
    ``resume``: complete an unfinished (killed) export of the same dataset to ``out``, keeping its complete
    parts. ``run``: where the parts run (:data:`Runner`; default: one after the other in this process).
    """
    if fmt not in FORMATS:
        raise PhySynthError(f"unknown export format '{fmt}' (choose one of {', '.join(FORMATS)})")
    from .rosbag2 import STORAGES

    if bag_storage not in STORAGES:
        raise PhySynthError(f"unknown bag storage '{bag_storage}' (choose one of {', '.join(STORAGES)})")
    if resume and overwrite:
        raise PhySynthError("resume and overwrite exclude each other: resume completes an unfinished export, "
                            "overwrite discards it; ask for one")
    if fmt == "hdf5":
        _require("h5py")
    elif fmt == "rosbag2":
        _require("rosbags")
    else:
        _require("polars")
    meta = read_meta(dataset)
    # the same rules as every writer (docs/reliability.md): never the input, the current folder or a
    # parent of it; replaced only when it is an export PhySynth wrote (overwrite); locked; temporary
    # files of an interrupted export removed with a warning
    out, lock = prepare_output(out, kind=f"export-{fmt}", overwrite=overwrite, inputs=[dataset])
    try:
        return _export(Path(dataset).resolve(), meta, out, fmt, progress, bag_storage, resume, overwrite,
                       run or _in_process)
    finally:
        lock.release()


def _prepare_partial(out: Path, record: dict[str, Any], resume: bool, overwrite: bool) -> Path:
    partial = partial_dir(out)
    if partial.exists() and not resume:
        if not overwrite:
            raise PhySynthError(f"an unfinished export to {out} exists ({partial}); resume it or overwrite to "
                                "start over")
        remove_tree(partial)
    if partial.exists():
        try:
            old = json.loads((partial / "run.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = None
        if old != record:
            diff = sorted(k for k in record if not isinstance(old, dict) or old.get(k) != record[k])
            raise PhySynthError(f"cannot resume the export to {out}: the unfinished one differs in "
                                f"{', '.join(diff) or 'run.json'}")
        for junk in partial.glob(".*.tmp-*"):  # a part or bag being written when the export was stopped
            remove_tree(junk)
        if record["format"] == "hdf5":  # a part being appended to the file in place: rolled back
            recover_h5(partial)
    else:
        partial.mkdir()
        atomic_write_text(partial / "run.json", json.dumps(record, indent=1))
    return partial


def _export(dataset: Path, meta: dict, out: Path, fmt: str, progress: ProgressCallback, storage: str,
            resume: bool, overwrite: bool, run: Runner) -> Path:
    total = n_traces(meta)
    parts = dataset_parts(meta)
    partial = _prepare_partial(out, run_record(dataset, fmt, storage), resume, overwrite)
    complete = {p.k for p in parts if marker(partial, p.k).is_file()}
    if complete:
        progress(f"resuming: {len(complete)} of {len(parts)} part(s) already complete")
    todo: list[Part] = [p for p in parts if p.k not in complete]
    already = sum(p.n_traces for p in parts if p.k in complete)
    message = f"exporting to {fmt}"
    progress(message, already, total)
    light = {k: v for k, v in meta.items() if k != "traces"} if len(parts) > 1 else meta
    try:
        run(export_part, [(str(dataset), light, p, fmt, str(partial), storage) for p in todo],
            [p.n_traces for p in todo], lambda done: progress(message, already + done, total))
        # a CSV part written again cuts off the rows of any part appended after it, which is then unmarked
        # (io.export.parts: never so after a stop, whose markers go from the last; written again here)
        again = [p for p in parts if not marker(partial, p.k).is_file()]
        if again:
            run(export_part, [(str(dataset), light, p, fmt, str(partial), storage) for p in again],
                [p.n_traces for p in again], lambda done: None)
    except Exception:  # not an interruption: an interrupted export stays resumable
        if not any(marker(partial, p.k).is_file() for p in parts):
            remove_tree(partial)
        raise
    skipped: dict[str, int] = {}
    for p in parts:
        for topic, n in json.loads(marker(partial, p.k).read_text(encoding="utf-8")).items():
            skipped[topic] = skipped.get(topic, 0) + n
    tmp = temp_sibling(out)
    remove_tree(tmp)
    register_temporary(tmp)
    try:
        apart = written_apart(fmt, partial)
        if apart:
            progress(f"appending the {apart} part(s) written apart")
        assemble(fmt, dataset, meta, partial, parts, tmp)
        swap_in(tmp, out)
    except BaseException:
        remove_tree(tmp)
        raise
    finally:
        unregister_temporary(tmp)
    remove_tree(partial)
    _say_skipped(skipped, progress)
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
