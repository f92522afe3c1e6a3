"""An export cut into parts, one per shard of the dataset: written apart (on any worker), resumable, assembled.

A dataset generated in several shards keeps each shard's rows in its own Parquet part
(``truth/part-00003.parquet`` ...) and its traces' metadata in ``traces/part-00003.jsonl``; each such part is
one part of the export. Any other dataset (one shard, or written by ``write_dataset`` or an importer) is
one part.

While an export runs, everything lives in a hidden sibling of the output, ``.<name>.partial/``:

- ``run.json``: what is exported (format, bag storage, the dataset and its ``dataset.json``'s SHA-256,
  PhySynth's version); a resumed export refuses a run that differs;
- per part ``k``, its output, renamed into place when complete: the bags ``trace_<index>/`` (rosbag2;
  each bag renamed into place as it is finished); for hdf5, its traces appended in place to the export's
  file ``appended.h5`` when the parts before it are complete (those written apart appended first; sizes
  after each part in ``appended.json``; an undo journal ``appended-<k>.undo`` while it is appended; one
  process at a time, ``appended.lock``), else its trace groups in ``part-<k>.pkl``;
  for csv, its rows appended to the tables in ``tables/`` when the parts before it are complete there
  (sizes after each part in ``tables.json``), else the folder ``part-<k>/``; then ``part-<k>.json`` (the
  messages left out, see :mod:`.rosbag2`), which marks the part complete.

:func:`assemble` turns the complete parts into the output: the bag folders as they are; the HDF5 file
with the traces of the parts written apart appended to it in order, as they would have been in place;
the CSV tables are those its first parts were appended to as they were written (:data:`APPENDED`: every
part, when they ran one after the other), the rows of parts written apart appended to them. The bytes do
not depend on which worker wrote which part.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import shutil
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ... import __version__
from ..._alloc import tune_allocator
from ...errors import DatasetError, PhySynthError
from ..atomic import atomic_write_text
from ..dataset import iter_indexed_traces, iter_stored_traces, trace_of
from ..safety import remove_tree, replacing


@dataclass(frozen=True)
class Part:
    """Part ``k`` of a dataset: its number of traces and the names of its files (``None``: every file)."""

    k: int
    n_traces: int
    files: tuple[str, ...] | None


def dataset_parts(meta: dict[str, Any]) -> list[Part]:
    """The parts of a dataset (its shards when it was assembled from several; else the whole of it)."""
    shards = meta.get("shards") if isinstance(meta.get("shards"), dict) else {}
    files = meta.get("files") if isinstance(meta.get("files"), dict) else None
    n = meta.get("n_traces")
    if shards.get("layout") != "parts" or files is None or not isinstance(n, int):
        return [Part(0, n if isinstance(n, int) else 0, None)]
    step = int(shards["shard_traces"])
    out = []
    for k in range(int(shards["n_shards"])):
        names = tuple(f for f in files if f.endswith(f"/part-{k:05d}.parquet"))
        out.append(Part(k, min(step, n - k * step), names))
    return out


def part_meta(dataset: Path, meta: dict[str, Any], part: Part) -> dict[str, Any]:
    """``dataset.json`` of the part alone: its files and its traces (what every reader checks and reads)."""
    if part.files is None:
        return meta
    traces = _part_traces(dataset, part)
    sub = {k: v for k, v in meta.items() if k != "traces_meta"}
    sub.update(files={f: meta["files"][f] for f in part.files}, traces=traces, n_traces=len(traces))
    return sub


def _part_traces(dataset: Path, part: Part) -> list[dict[str, Any]]:
    f = dataset / "traces" / f"part-{part.k:05d}.jsonl"
    try:
        return [json.loads(line) for line in f.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, ValueError) as exc:
        raise PhySynthError(f"dataset {dataset} is damaged: cannot read {f.relative_to(dataset)} ({exc})") from None


def run_record(dataset: Path, fmt: str, storage: str) -> dict[str, Any]:
    """What a resumed export must agree on."""
    digest = hashlib.sha256((dataset / "dataset.json").read_bytes()).hexdigest()
    return {"format": fmt, "bag_storage": storage if fmt == "rosbag2" else None, "dataset": str(dataset),
            "dataset_json_sha256": digest, "generator": f"physynth {__version__}"}


def marker(partial: Path, k: int) -> Path:
    return partial / f"part-{k:05d}.json"


APPENDED = "tables"
"""CSV: the folder of the export's tables holding the rows of its first parts, each part's appended as it
is written when the parts before it are complete and appended (always so when the parts run one after the
other in one process): no part then needs to be copied when the export is assembled."""
APPENDED_SIZES = "tables.json"
"""CSV: the size of each table of :data:`APPENDED` after each part appended to it (a list, part by part):
a part written again (after a stop) first cuts the tables back to the sizes after the part before it."""


def _appended(partial: Path) -> tuple[list[dict[str, int]], int]:
    """``(sizes, recorded)``: the sizes of the CSV tables after each of the parts ``0 .. m - 1`` appended to
    them, for the longest such run of parts that are complete (marked) and recorded, and the number of
    parts recorded (their rows may lie beyond those, cut off when the next part is appended)."""
    try:
        sizes = json.loads((partial / APPENDED_SIZES).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return [], 0
    if not isinstance(sizes, list) or not (partial / APPENDED).is_dir():
        return [], 0
    m = 0
    while m < len(sizes) and isinstance(sizes[m], dict) and marker(partial, m).is_file():
        m += 1
    return sizes[:m], len(sizes)


def _append_csv_part(dataset: Path, sub: dict[str, Any], k: int, partial: Path, sizes: list[dict[str, int]],
                     recorded: int, on_trace: Any) -> None:
    """Append the CSV rows of part ``k`` to the tables of :data:`APPENDED`, which hold parts ``0 .. k - 1``
    (``sizes``: their sizes after each), and record the sizes after it."""
    from .csv import write_csv_tables

    for j in range(k + 1, recorded):  # parts whose rows were appended after this one's: written again
        marker(partial, j).unlink(missing_ok=True)
    tables = partial / APPENDED
    if k == 0:
        remove_tree(tables)
        with replacing(tables) as tmp:
            write_csv_tables(dataset, sub, tmp, on_trace=on_trace, behind=True)
    else:
        for f in tables.iterdir():  # what a stopped attempt at this part left is cut off
            os.truncate(f, sizes[-1].get(f.name, 0))
        write_csv_tables(dataset, sub, tables, header=False, on_trace=on_trace, append=True, behind=True)
    sizes = [*sizes, {f.name: f.stat().st_size for f in sorted(tables.iterdir())}]
    atomic_write_text(partial / APPENDED_SIZES, json.dumps(sizes))


def export_part(dataset: str, meta: dict[str, Any], part: Part, fmt: str, partial: str, storage: str,
                on_unit: Any = None) -> dict[str, int]:
    """Write part ``part`` of the export into ``partial`` (what a worker runs); returns the ROS 2 messages
    left out per topic. A part already complete is left alone. ``on_unit()`` after each trace."""
    tune_allocator()  # as generation does: a Dask worker's glibc otherwise trims (and faults in) every bag
    dataset_p, partial_p = Path(dataset), Path(partial)
    done = marker(partial_p, part.k)
    if done.is_file():
        return json.loads(done.read_text(encoding="utf-8"))
    sub = part_meta(dataset_p, meta, part)

    def traces():
        for item in iter_indexed_traces(dataset_p, sub):
            yield item
            if on_unit is not None:
                on_unit()

    def stored():  # the traces as stored; made into records too when no integrity record vouches for them
        # the files are checked while they are read: what is written of them is kept only once the reading
        # ended without an error (a part is marked, an HDF5 part appended, after; a bag is removed below)
        record = not isinstance(sub.get("files"), dict)
        for st in iter_stored_traces(dataset_p, sub, check_alongside=True):
            if record:
                trace_of(st, sub, dataset_p)
            yield st
            if on_unit is not None:
                on_unit()

    skipped: dict[str, int] = {}
    if fmt == "rosbag2":
        from .rosbag2 import NAMED_AFTER_FOLDER, BagColumns, prepare_bag

        nested = storage in NAMED_AFTER_FOLDER

        def finish(dest: Path, write: Any) -> None:
            with replacing(dest, nested=nested) as tmp:  # the bag's files are named after dest
                write(tmp / dest.name if nested else tmp, dest.name)

        pending = None  # the bag prepared before: written once the next one's messages are built
        written: list[Path] = []
        try:
            for st in stored():  # the stored columns, as the messages take them (no record built and taken apart)
                dest = partial_p / f"trace_{st.index:08d}"
                if dest.is_dir():  # written before the run was stopped
                    continue
                write = prepare_bag(BagColumns.of_stored(st, dataset_p), storage, skipped)  # its chunks
                # compress while the next bag is built
                if pending is not None:
                    finish(*pending)
                    written.append(pending[0])
                pending = (dest, write)
        except DatasetError:  # a file of the part disagrees with its record: none of its bags is kept
            for dest in written:
                remove_tree(dest)
            raise
        if pending is not None:
            finish(*pending)
    elif fmt == "hdf5":
        from .hdf5 import trace_groups

        light = {k: v for k, v in meta.items() if k != "traces"}
        groups = (trace_groups(st, light, dataset_p) for st in stored())
        with _h5_lock(partial_p, wait=False) as held:  # taken by another worker: this part is written apart
            if held and _append_in_order(partial_p, part.k, light, groups):
                groups = None
        if groups is not None:  # appended to the file by a later part's worker, or when the export is assembled
            with replacing(apart_h5(partial_p, part.k)) as tmp, open(tmp, "wb") as fh:
                for g in groups:
                    pickle.dump(g, fh, protocol=5)
    else:
        from .csv import check_tables, write_csv_tables

        checked = check_tables(dataset_p, sub)
        if not checked:  # no integrity record: read and checked trace by trace, as by every reader
            deque(traces(), maxlen=0)
        on_trace = on_unit if checked else None
        sizes, recorded = _appended(partial_p)
        if part.k == len(sizes):  # then copied row group by row group, appended to the parts before
            _append_csv_part(dataset_p, sub, part.k, partial_p, sizes, recorded, on_trace)
        else:  # a part of its own, appended when the export is assembled
            with replacing(partial_p / f"part-{part.k:05d}") as tmp:
                write_csv_tables(dataset_p, sub, tmp, header=part.k == 0, on_trace=on_trace)
    skipped = {t: n for t, n in skipped.items() if n}
    atomic_write_text(done, json.dumps(skipped))
    return skipped


H5_FILE = "appended.h5"
"""HDF5: the export's file, holding its first parts, each appended in place as it is written when the parts
before it are in the file (always so when the parts run one after the other in one process)."""
H5_SIZES = "appended.json"
"""HDF5: the size of :data:`H5_FILE` after each part appended to it (a list, part by part): the parts it
holds. A part is appended with an undo journal (``appended-<k>.undo``, :mod:`physynth.io.undo`) that is
removed once its size is recorded; a journal of a part not recorded is rolled back (:func:`_recover_h5`)."""


def apart_h5(partial: Path, k: int) -> Path:
    """HDF5: the groups of part ``k`` written apart (one pickle per trace), appended when assembling."""
    return partial / f"part-{k:05d}.pkl"


def _journal(partial: Path, k: int) -> Path:
    return partial / f"appended-{k:05d}.undo"


def _h5_sizes(partial: Path) -> list[int]:
    try:
        sizes = json.loads((partial / H5_SIZES).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    return sizes if isinstance(sizes, list) and all(isinstance(n, int) for n in sizes) else []


def recover_h5(partial: Path) -> list[int]:
    """:func:`_recover_h5` with :data:`H5_LOCK` held (waited for)."""
    with _h5_lock(partial, wait=True):
        return _recover_h5(partial)


def _recover_h5(partial: Path) -> list[int]:
    """The sizes of :data:`H5_FILE` after each part it holds (:data:`H5_SIZES`), the file brought back to
    them first: the journal of a part not recorded (a kill in the middle of appending it) rolled back, a
    recorded part's removed; no part recorded, no file. A file that still disagrees with its record (a
    power cut), or a record that does not read, is removed with the record; a part marked complete that is
    then neither in the file nor written apart is unmarked, to be written again.
    Only with :data:`H5_LOCK` held: no other process is appending then (a part written apart has its
    pickle in place before its marker, and a pickle is removed only once its part is recorded)."""
    from ..undo import roll_back

    sizes, f = _h5_sizes(partial), partial / H5_FILE
    for journal in sorted(partial.glob("appended-*.undo"), reverse=True):
        if int(journal.stem.removeprefix("appended-")) < len(sizes):
            journal.unlink()
        else:
            roll_back(f, journal)
    if sizes and (not f.is_file() or f.stat().st_size != sizes[-1]):
        sizes = []
    if not sizes:
        (partial / H5_SIZES).unlink(missing_ok=True)
        f.unlink(missing_ok=True)
    for done in sorted(partial.glob("part-*.json"), reverse=True):  # the last first, as assembling takes them
        k = int(done.stem.removeprefix("part-"))
        if k >= len(sizes) and not apart_h5(partial, k).is_file():
            done.unlink()
    return sizes


H5_LOCK = "appended.lock"
"""HDF5: the lock of :data:`H5_FILE` (``flock``): held by the one process that appends to it, or rolls back
what a killed one appended; a worker that finds it held writes its part apart."""


@contextlib.contextmanager
def _h5_lock(partial: Path, *, wait: bool) -> Iterator[bool]:
    """Hold :data:`H5_LOCK` for the block, yielding True; without ``wait``, False at once when another
    process holds it. Where ``flock`` does not exist (not POSIX), True only when ``wait`` (the export's
    own process, once no part runs)."""
    try:
        import fcntl
    except ImportError:
        yield wait
        return
    fd = os.open(partial / H5_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            held = True
        except BlockingIOError:
            held = False
        yield held
    finally:
        os.close(fd)  # the lock goes with it (and with the process, should it be killed)


def _append_in_order(partial: Path, k: int, meta: dict[str, Any], groups: Any) -> bool:
    """With :data:`H5_LOCK` held: when every part before part ``k`` is complete, append those written apart
    to :data:`H5_FILE`, in order, then part ``k``'s ``groups`` in place, and return True; else False
    (nothing written). Part ``k`` already in the file (stopped before its marker): True."""
    sizes = _recover_h5(partial)  # the lock held: what a killed process left half appended is rolled back
    if k < len(sizes):
        return True
    if not all(marker(partial, j).is_file() for j in range(len(sizes), k)):
        return False
    for j in range(len(sizes), k):  # complete, written apart while the file was busy: taken in now
        _append_h5_part(partial, j, meta, _pickled(apart_h5(partial, j)), sizes)
        apart_h5(partial, j).unlink()
    _append_h5_part(partial, k, meta, groups, sizes)
    return True


def _append_h5_part(partial: Path, k: int, meta: dict[str, Any], groups: Any, sizes: list[int]) -> None:
    """Write the trace groups of part ``k`` into :data:`H5_FILE` (which holds parts ``0 .. k - 1``, of
    ``sizes``; part 0 creates it) and record its size after them."""
    from ..undo import roll_back
    from .hdf5 import append, create

    f = partial / H5_FILE
    if k == 0:
        f.unlink(missing_ok=True)  # left by a killed attempt at it
        try:
            create(f, meta, groups)
        except BaseException:
            f.unlink(missing_ok=True)
            raise
    else:
        if _journal(partial, k).exists():  # a killed attempt at this part (its task run again)
            roll_back(f, _journal(partial, k))
        append(f, groups, _journal(partial, k))
    sizes.append(f.stat().st_size)
    atomic_write_text(partial / H5_SIZES, json.dumps(sizes))
    _journal(partial, k).unlink(missing_ok=True)
    _behind(f, sizes)


def _behind(f: Path, sizes: list[int]) -> None:
    """Write :data:`H5_FILE` behind (:class:`~physynth.io.pagecache.WriteBehind`, its pieces the parts moved
    :func:`~physynth.io.pagecache.cache_allowance` bytes back from the file's end): the parts appended
    before the last two are then on disk and out of the cache (HDF5 rewrites a few kilobytes of them in
    place, read back from disk once per part); the newest bytes stay in the cache."""
    from .. import pagecache

    keep = pagecache.cache_allowance()
    marks = [max(0, n - keep) for n in [0, 0, *sizes]]
    if marks[-1] > marks[-3]:
        fd = os.open(f, os.O_RDONLY)
        try:
            pagecache.WriteBehind(fd, marks[-3], marks[-2]).advance(marks[-1])
        finally:
            os.close(fd)


def _pickled(path: Path) -> Any:
    with open(path, "rb") as fh:
        while True:
            try:
                yield pickle.load(fh)
            except EOFError:
                return


def written_apart(fmt: str, partial: Path) -> int:
    """How many complete parts in ``partial`` were written apart (HDF5 pickles, CSV folders): what assembling
    appends to the output; 0 for bags, which are moved as they are."""
    if fmt == "hdf5":
        return sum(1 for _ in partial.glob("part-*.pkl"))
    if fmt == "csv":
        return sum(1 for f in partial.glob("part-*") if f.is_dir())
    return 0


def _consume(partial: Path, part: Part, take: Any) -> None:
    """``take()`` a complete part's output away (moved into the output, or removed once copied), its
    marker removed first: an export stopped while assembling then redoes that part when resumed."""
    marker(partial, part.k).unlink()
    take()


def assemble(fmt: str, dataset: Path, meta: dict[str, Any], partial: Path, parts: list[Part], tmp: Path) -> None:
    """Build the finished output at ``tmp`` (a new path) from the complete parts in ``partial``."""
    if fmt == "rosbag2":
        for k in range(len(parts)):
            marker(partial, k).unlink()
        (partial / "run.json").unlink()
        os.replace(partial, tmp)
        return
    if fmt == "hdf5":
        light = {k: v for k, v in meta.items() if k != "traces"}
        with _h5_lock(partial, wait=True):
            sizes = _recover_h5(partial)
            for p in parts[len(sizes):]:  # the parts written apart, in order
                if not apart_h5(partial, p.k).is_file():
                    raise PhySynthError(f"the unfinished export in {partial} lacks part {p.k}: overwrite to start "
                                        "over")
                _append_h5_part(partial, p.k, light, _pickled(apart_h5(partial, p.k)), sizes)
                apart_h5(partial, p.k).unlink()
            for p in reversed(parts):  # the file holds every part: taken, they are written again if stopped here
                marker(partial, p.k).unlink()
            (partial / H5_SIZES).unlink()
            os.replace(partial / H5_FILE, tmp)
        return
    from .csv import finish_csv

    folders = [partial / f"part-{p.k:05d}" for p in parts]
    sizes, _ = _appended(partial)
    m = max(1, len(sizes))  # the parts whose rows the tables hold (or the first part's own folder)
    if sizes:
        for f in (partial / APPENDED).iterdir():  # what a stopped attempt at the next part left is cut off
            os.truncate(f, sizes[-1].get(f.name, 0))
    for p in reversed(parts[1:m]):  # their rows are in the tables, taken with the first part's; the last
        _consume(partial, p, lambda: None)  # marker goes first, so a stop leaves parts 0 .. j to resume on
    _consume(partial, parts[0], lambda: os.replace(partial / APPENDED if sizes else folders[0], tmp))
    tables = sorted(f.name for f in tmp.iterdir())
    for p, folder in zip(parts[m:], folders[m:], strict=True):  # the others' rows appended to them
        for table in tables:
            append_file(folder / table, tmp / table)
        _consume(partial, p, lambda folder=folder: shutil.rmtree(folder))
    finish_csv(dataset, meta, tmp)


def append_file(src: Path, out: Path) -> None:
    """Append the file ``src`` to the file ``out``: copied by the kernel (``os.copy_file_range``: about
    twice as fast as through Python's buffers here), through Python where the file system cannot."""
    with open(src, "rb") as fs, open(out, "r+b") as fo:
        start = fo.seek(0, os.SEEK_END)
        size = os.fstat(fs.fileno()).st_size
        done = 0
        try:
            while done < size:
                n = os.copy_file_range(fs.fileno(), fo.fileno(), size - done, done, start + done)
                if n == 0:
                    break
                done += n
        except (AttributeError, OSError):  # not Linux, or not between these files: through Python
            fo.truncate(start)
            fo.seek(start)
            fs.seek(0)
            shutil.copyfileobj(fs, fo, 1 << 20)
            return
        if done != size:
            raise OSError(f"{out}: appended {done} of the {size} bytes of {src}")
