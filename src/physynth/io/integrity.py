"""Dataset integrity: row counts and SHA-256 of every file, recorded in ``dataset.json`` and checked.

:func:`file_records` is called by :class:`~physynth.io.dataset.DatasetWriter` when it closes a
dataset; the records go under ``dataset.json`` ``"files"``::

    "files": {"truth.parquet": {"rows": 123, "bytes": 4567, "sha256": "..."}, ...}

:func:`check_dataset` compares a dataset folder with its records (readers call it before reading) and
raises :class:`~physynth.errors.IntegrityError` naming the first file that disagrees;
:func:`verify_dataset` (``physynth verify``) makes the same checks and returns every problem.
Datasets written before the records existed have no ``"files"``; readers accept them, ``verify`` says
they cannot be verified. A record names every file of a dataset: readers read exactly the files it
lists (:func:`table_records`), a record that lacks a table is damage, and so, for ``verify``, is a
Parquet file in the folder that the record does not list.

pyarrow is imported by the functions that read Parquet footers or tables, not with this module.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import IntegrityError

HASH = "sha256"
_CHUNK = 1 << 20
_PART = re.compile(r"^(?P<table>[a-z_]+)/part-(?P<k>\d+)\.parquet$")


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


class TrailingHash:
    """The SHA-256 and size of a file that a native writer (pyarrow's own file) is writing, taken by
    reading back, in large reads, the bytes it appended since the last :meth:`update` (still in the page
    cache): the record of a file written once, without a second pass over it at close. The writer must
    only append (pyarrow's Parquet writer makes no other writes) and must not write while :meth:`update`
    runs (the dataset writer calls it on its writer thread, after each row group and after closing).

    A Python file object as the writer's sink took the hash as the bytes went by, but every page written
    then took the GIL from the thread making traces: the generating thread ran about 10 % slower.
    """

    def __init__(self, path: Path) -> None:
        self._f = open(path, "rb", buffering=0)  # noqa: SIM115 - closed by close()
        self._h = hashlib.sha256()
        self._buf = bytearray(_CHUNK)
        self.size = 0

    def update(self) -> None:
        """Hash the bytes appended since the last call."""
        view = memoryview(self._buf)
        while n := self._f.readinto(self._buf):
            self._h.update(view[:n])
            self.size += n

    def close(self, *, rest: bool = True) -> None:
        """Hash what was appended since the last update (unless ``rest`` is False: a write given up) and
        close the file."""
        if not self._f.closed:
            if rest:
                self.update()
            self._f.close()

    def hexdigest(self) -> str:
        return self._h.hexdigest()


def file_records(folder: Path, rows: Mapping[str, int],
                 written: Mapping[str, TrailingHash] | None = None) -> dict[str, dict[str, Any]]:
    """``{file name: {"rows", "bytes", "sha256"}}`` for the files named in ``rows`` (name -> row count);
    a file in ``written`` takes the size and hash taken while it was written (checked against its size on
    disk; read again when they differ), the others are read."""
    out = {}
    for name, n in rows.items():
        p = folder / name
        size = p.stat().st_size
        sink = (written or {}).get(name)
        digest = sink.hexdigest() if sink is not None and sink.size == size else file_sha256(p)
        out[name] = {"rows": int(n), "bytes": size, HASH: digest}
    return out


def shard_file_records(shards: Sequence[Path], tables: Iterable[str], *, single: bool) -> dict[str, dict[str, Any]]:
    """The records of the final dataset assembled from shard datasets (:mod:`physynth.io.shards`): each
    shard's own records (its files are linked or copied unchanged) under the final names
    (``truth.parquet`` for one shard, ``truth/part-00000.parquet`` ... for several)."""
    out: dict[str, dict[str, Any]] = {}
    for k, shard in enumerate(shards):
        own = json.loads((shard / "dataset.json").read_text(encoding="utf-8")).get("files") or {}
        for name in tables:
            rec = own.get(f"{name}.parquet")
            if rec is None:  # a shard written without records: hash it now
                import pyarrow.parquet as pq

                rows = pq.ParquetFile(shard / f"{name}.parquet").metadata.num_rows
                rec = file_records(shard, {f"{name}.parquet": rows})[f"{name}.parquet"]
            out[f"{name}.parquet" if single else f"{name}/part-{k:05d}.parquet"] = rec
    return out


def table_records(files: Mapping[str, Any], name: str) -> list[str]:
    """The recorded files of table ``name`` (names in ``dataset.json`` ``"files"``), in trace order:
    ``<name>.parquet``, or the parts ``<name>/part-<k>.parquet`` of a dataset assembled from shards
    (by ``k``). Empty when the record lacks the table."""
    single = [f for f in files if f == f"{name}.parquet"]
    parts = [(int(m["k"]), f) for f in files if (m := _PART.match(f)) and m["table"] == name]
    return single + [f for _, f in sorted(parts)]


def unrecorded_files(path: Path, files: Mapping[str, Any]) -> list[str]:
    """The Parquet files under the dataset folder ``path`` that its record ``files`` does not list."""
    found = (p.relative_to(path).as_posix() for p in path.rglob("*.parquet") if p.is_file())
    return sorted(f for f in found if f not in files)


@dataclass(frozen=True, slots=True)
class VerifyResult:
    """What :func:`check_dataset` or :func:`verify_dataset` checked: files, total rows and bytes (of the
    files that match their records), whether records existed, and the problems found (one line each)."""

    files: int
    rows: int
    bytes: int
    recorded: bool
    problems: tuple[str, ...] = ()


def check_dataset(path: Path, meta: Mapping[str, Any], *, hashes: bool = True) -> VerifyResult:
    """Check every recorded file of a dataset folder: present, same size, same row count (from the
    Parquet footer), same SHA-256 (when ``hashes``); and that the traces named in ``dataset.json``
    are the traces in the truth table (``truth.parquet`` or its parts ``truth/part-*.parquet``).

    Stops at the first problem (what a reader needs); :func:`verify_dataset` finds them all.

    Raises
    ------
    IntegrityError
        Naming the dataset and the first file that disagrees, and how.
    """
    totals = [0, 0]
    for problem in _problems(path, meta, hashes=hashes, totals=totals):
        raise IntegrityError(problem)
    return _result(meta, totals, ())


def verify_dataset(path: Path, meta: Mapping[str, Any], *, hashes: bool = True) -> VerifyResult:
    """The checks of :func:`check_dataset`, every one of them: each file that disagrees with its record
    is one entry of ``problems`` (a file's first disagreement only: a file of the wrong size has the
    wrong hash too), and the trace ids are checked when the truth tables themselves are intact; and
    every Parquet file in the folder that the record does not list (readers ignore it; a stray table
    file or part is a sign of a damaged or tampered dataset) is one more."""
    totals = [0, 0]
    problems = tuple(_problems(path, meta, hashes=hashes, totals=totals, strays=True))
    return _result(meta, totals, problems)


def _result(meta: Mapping[str, Any], totals: list[int], problems: tuple[str, ...]) -> VerifyResult:
    files = meta.get("files")
    return VerifyResult(files=len(files) if isinstance(files, dict) else 0, rows=totals[0], bytes=totals[1],
                        recorded=files is not None, problems=problems)


def _problems(path: Path, meta: Mapping[str, Any], *, hashes: bool, totals: list[int],
              strays: bool = False) -> Iterator[str]:
    """The problems of a dataset, one line each, lazily (the first comes before later files are checked;
    their hashes are taken ahead on other threads, and no more once the caller stops);
    ``totals`` gathers the rows and bytes of the files that match their records; ``strays``: also the
    Parquet files the record does not list."""
    from .tables import TABLES  # from io.tables, not io.dataset: io.dataset imports this module

    files = meta.get("files")
    if files is None:
        return
    if not isinstance(files, dict):
        yield f"dataset {path}: dataset.json 'files' is not a mapping"
        return
    if not files:
        yield f"dataset {path} is damaged: its integrity record (dataset.json 'files') is empty"
        return
    lacking = [t for t in TABLES if not table_records(files, t)]
    if lacking:
        yield (f"dataset {path} is damaged: its integrity record (dataset.json 'files') lacks the "
               f"table(s) {', '.join(lacking)}")
    truth = table_records(files, "truth")
    truth_intact = True
    for (name, rec), digest in zip(files.items(), _digests(path, list(files), hashes=hashes), strict=True):
        problem = _file_problem(path, name, rec, hashes=hashes, digest=digest)
        if problem is None:
            totals[0] += int(rec["rows"])
            totals[1] += int(rec["bytes"])
            continue
        truth_intact = truth_intact and name not in truth
        yield problem
    try:  # the trace ids of a damaged truth table would only repeat its damage: dataset.json alone then
        check_trace_ids(path, meta, truth if truth_intact else [])
    except IntegrityError as exc:
        yield str(exc)
    for name in unrecorded_files(path, files) if strays else ():
        if name.split("/")[0].removesuffix(".parquet") in lacking:
            continue  # said already: the record lacks that table
        yield (f"dataset {path} is damaged: it holds {name}, which its integrity record (dataset.json 'files') "
               "does not list (added after the dataset was written; readers ignore it)")


def _digest_or_none(f: Path) -> str | None:
    try:
        return file_sha256(f)
    except OSError:  # missing or unreadable: _file_problem says which
        return None


def _digests(path: Path, names: list[str], *, hashes: bool) -> Iterator[str | None]:
    """The SHA-256 of each file ``names`` (None: not asked, or not readable), in order, taken on one thread
    per core while the caller checks the files before (hashlib releases the GIL)."""
    if not hashes or len(names) < 2:
        yield from (None for _ in names)
        return
    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(min(len(names), len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                  else os.cpu_count() or 1), thread_name_prefix="physynth-sha256")
    try:
        yield from pool.map(_digest_or_none, [path / n for n in names])
    finally:
        pool.shutdown(wait=True, cancel_futures=True)  # a caller that stopped at a problem: the rest not hashed


def _file_problem(path: Path, name: str, rec: Any, *, hashes: bool, digest: str | None = None) -> str | None:
    """How the file ``name`` disagrees with its record ``rec`` (its first disagreement), or None;
    ``digest``: its SHA-256 when already taken."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    f = path / name
    if not isinstance(rec, dict) or not {"rows", "bytes", HASH} <= set(rec):
        return f"dataset {path}: dataset.json has no valid record of {name}"
    if not f.is_file():
        return f"dataset {path} is damaged: {name} is missing"
    size = f.stat().st_size
    if size != rec["bytes"]:
        return (f"dataset {path} is damaged: {name} has {size} bytes, dataset.json records {rec['bytes']} "
                "(truncated or changed after it was written)")
    if hashes and (digest or file_sha256(f)) != rec[HASH]:
        return (f"dataset {path} is damaged: {name} does not match its {HASH} in dataset.json "
                "(changed after it was written)")
    if name.endswith(".parquet"):
        try:
            n = pq.ParquetFile(f).metadata.num_rows
        except (OSError, pa.ArrowException) as exc:
            return (f"dataset {path} is damaged: {name} is not readable Parquet "
                    f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})")
        if n != rec["rows"]:
            return f"dataset {path} is damaged: {name} has {n} rows, dataset.json records {rec['rows']}"
    return None


def check_trace_ids(path: Path, meta: Mapping[str, Any], tables: Iterable[str] = ("truth.parquet",)) -> None:
    """The trace ids in ``tables`` are those of ``dataset.json`` (``n_traces`` and ``traces``)."""
    listed = meta.get("traces")
    n_traces = meta.get("n_traces")
    if listed is None and isinstance(n_traces, int) and (path / "traces").is_dir():
        return  # several shards: the per-trace list lives in traces/part-*.jsonl, checked while reading
    if not isinstance(listed, list) or not isinstance(n_traces, int):
        raise IntegrityError(f"dataset {path}: dataset.json has no valid n_traces / traces")
    try:
        ids = sorted(int(t["trace"]) for t in listed)
    except (TypeError, KeyError, ValueError):
        raise IntegrityError(f"dataset {path}: dataset.json traces entries have no valid 'trace' id") from None
    if n_traces != len(ids):
        raise IntegrityError(f"dataset {path}: dataset.json says n_traces {n_traces} but lists {len(ids)} trace(s)")
    tables = [t for t in tables if (path / t).is_file()]
    if not tables:
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    from .tables import run_starts, to_numpy  # from the buffers: pyarrow's own to_numpy would import pandas

    found: set[int] = set()
    nulls = False
    for name in tables:
        try:
            col = pq.ParquetFile(path / name).read(columns=["trace"]).column("trace")
        except (OSError, pa.ArrowException, KeyError) as exc:
            raise IntegrityError(f"dataset {path} is damaged: cannot read {name} ({type(exc).__name__})") from None
        nulls = nulls or col.null_count > 0
        rows = to_numpy(col.drop_null() if col.null_count else col)
        found.update(rows[run_starts(rows)].tolist())  # the first id of each run of equal ids
    name = tables[0] if len(tables) == 1 else f"{tables[0].split('/')[0]}/*"
    if nulls:
        raise IntegrityError(f"dataset {path} is damaged: {name} has rows without a trace id")
    present = sorted(found)
    if present != ids:
        missing = sorted(set(ids) - set(present))
        extra = sorted(set(present) - set(ids))
        what = (f"has no rows of trace(s) {missing[:5]}" if missing
                else f"has rows of unlisted trace(s) {extra[:5]}")
        raise IntegrityError(f"dataset {path} is damaged: {name} {what} (dataset.json lists {n_traces})")


def describe(result: VerifyResult) -> str:
    """One line for ``physynth verify``."""
    return f"{result.files} file(s), {result.rows} row(s), {result.bytes / 1e6:.1f} MB: sizes, row counts and " \
           f"{HASH} match dataset.json"


def environ_skip_hashes() -> bool:
    """``PHYSYNTH_SKIP_HASHES=1`` makes readers check sizes and row counts but not hashes (huge datasets)."""
    return os.environ.get("PHYSYNTH_SKIP_HASHES", "") not in ("", "0")
