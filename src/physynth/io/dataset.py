"""Datasets on disk: a directory with ``dataset.json`` and Parquet tables ``truth``, ``imu``, ``uwb``,
``anchors``, each with a ``trace`` column (docs/data-and-metrics.md).

Writes are atomic: everything goes to a hidden sibling directory that is renamed into place only
when every table is complete, so an interrupted job never leaves a dataset that looks finished.
:class:`DatasetWriter` streams traces in row groups, so a dataset larger than memory can be written.

pyarrow is imported when a table is first written or read, not with this module: ``physynth generate``
has its first trace before it pays for pyarrow. :data:`SCHEMAS` and :data:`SCHEMAS_COMPACT` are built
on first use (:func:`arrow_schemas`).
"""

from __future__ import annotations

import datetime as _dt
import functools
import itertools
import json
import math
import os
import shutil
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__
from .._json import jsonable
from ..constants import DEFAULT_GRID_RATE_HZ, IMU_BODY_FRAME, IMU_FRAME, SCHEMA_VERSION
from ..errors import ArgumentError, DatasetError, IntegrityError
from ..records import Anchors, Imu, Trace, Truth, Uwb, trace_iterable
from . import integrity, safety
from .atomic import ClosesOrAborts, temp_sibling
from .tables import (  # the tables' Arrow side, named here as before
    FLOAT32_COLUMNS,
    OPTIONAL_COLUMNS,
    TABLES,
    _check_declared,
    _column_options,
    _held_groups,
    _schema,
    _tables_of,
    arrow_schemas,
    optional_group,
    run_starts,
    to_numpy,
    valid_mask,
)
from .tables import NULLABLE_COLUMNS as NULLABLE_COLUMNS
from .tables import SENSOR_COLUMNS as SENSOR_COLUMNS
from .tables import (
    generated_column_groups as generated_column_groups,
)

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq


def __getattr__(name: str) -> Any:
    """``SCHEMAS`` and ``SCHEMAS_COMPACT``, built on first use (:func:`arrow_schemas`)."""
    if name == "SCHEMAS":
        return arrow_schemas()[0]
    if name == "SCHEMAS_COMPACT":
        return arrow_schemas()[1]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


UNITS = {
    "t_s": "s", "pos_*_m": "m (ENU)", "vel_*_mps": "m/s (ENU)", "acc_[enu]_mps2": "m/s^2 (ENU, gravity removed)",
    "acc_[xyz]_mps2": "m/s^2 (body FLU, specific force incl. gravity)", "gyro_[xyz]_radps": "rad/s (body FLU)",
    "quat_[wxyz]": "unit quaternion body (FLU) -> ENU, Hamilton, scalar first",
    "omega_[xyz]_radps": "rad/s (body angular velocity, body frame, constant over [t_k, t_k+1))",
    "range_m": "m", "true_range_m": "m",
}
FRAMES = {
    "world": "ENU (east, north, up), metres, origin as in the anchors table",
    "imu": f"{IMU_FRAME}: acceleration in the world ENU frame with gravity removed",
    "imu_body": f"{IMU_BODY_FRAME}: specific force (gravity included) and angular rate in the sensor body frame, "
                "x forward, y left, z up",
    "body": "FLU (x forward, y left, z up); truth quat_* rotates body vectors into ENU",
}
REASONS = {"0": "ok", "1": "dropout", "2": "outage", "3": "no link (range/visibility)", "4": "invalid"}


def _write_group(writers: Mapping[str, pq.ParquetWriter], group: Mapping[str, pa.Table],
                 hashes: Mapping[str, integrity.TrailingHash]) -> None:
    for name, table in group.items():
        writers[name].write_table(table)
        if name in hashes:
            hashes[name].update()


class DatasetWriter(ClosesOrAborts):
    """Streams traces into a new dataset directory; the directory appears only on :meth:`close`.

    >>> with DatasetWriter(out, meta={"kind": "synthetic"}) as w:   # doctest: +SKIP
    ...     for trace in traces:
    ...         w.add(trace)

    ``compact``: store :data:`FLOAT32_COLUMNS` as float32 (generated data). ``column_groups``: the
    optional column groups (:data:`OPTIONAL_COLUMNS`, by record attribute) the dataset holds, per table,
    e.g. :func:`generated_column_groups`; None holds them all, with nulls where a trace lacks a group.
    Naming them saves writing (and reading) columns of nulls and writes them as Parquet REQUIRED columns
    (no definition levels: about a quarter less encoding time); a trace that has a group the dataset does
    not hold, or lacks one it holds, raises :class:`DatasetError` (in :meth:`add`) rather than lose it.

    :meth:`add` keeps the trace it is given as it is and converts the one before to Arrow tables (so
    at most one trace waits unconverted); a row group is written when it holds ``row_group_traces``
    traces or the writer closes. The Parquet files are opened, and pyarrow imported, by the first
    conversion: the first trace is added (and a caller can report it) before pyarrow is imported.
    """

    hash_while_writing = True
    """The SHA-256 of each table taken as it is written, row group by row group, by the thread that writes
    it (:class:`~physynth.io.integrity.TrailingHash`; False: by reading the file again at close, as before
    2026-12-05; ``benchmarks/bench_parquet_write.py`` measures both)."""
    write_in_thread = True
    """Row groups encoded and written in a writer thread while the caller makes the next traces (pyarrow
    and hashlib release the GIL), False: in the caller's thread, as before 2026-12-05."""

    def __init__(self, path: str | os.PathLike, *, meta: dict[str, Any] | None = None,
                 overwrite: bool = False, row_group_traces: int = 64, compact: bool = False,
                 inputs: Sequence[str | os.PathLike] = (),
                 column_groups: Mapping[str, Iterable[str]] | None = None) -> None:
        # safety hook (physynth.io.safety): what --overwrite may replace, inputs, lock, orphaned temp folders
        self.path, self._lock = safety.prepare_output(path, kind="dataset", overwrite=overwrite, inputs=inputs)
        self.overwrite = overwrite
        self.meta = dict(meta or {})
        self.tmp = temp_sibling(self.path)
        try:
            safety.remove_tree(self.tmp)
            self.tmp.mkdir(parents=True)
            safety.register_temporary(self.tmp)
        except OSError as exc:
            self._lock.release()
            raise DatasetError(f"cannot create {self.path}: {exc.strerror}") from None
        except BaseException:
            self._lock.release()
            raise
        self._rows = {name: 0 for name in TABLES}
        self._held = {name: _held_groups(name, column_groups) for name in TABLES}
        self._declared = column_groups is not None
        self._compact = compact
        self._schemas: dict[str, pa.Schema] = {}
        self._writers: dict[str, pq.ParquetWriter] = {}  # opened by _open_writers
        self._sinks: dict[str, Any] = {}  # pyarrow's own files (no Python call per page written)
        self._hashes: dict[str, integrity.TrailingHash] = {}
        self._thread: Any = None  # the writer thread (a one-thread pool), started by the first row group
        self._writing: Any = None  # the future of the row group being written
        self._unconverted: tuple[Trace, int] | None = None  # the last trace added, converted by the next add
        self._tables: dict[str, list[pa.Table]] = {name: [] for name in TABLES}  # the row group being filled
        self._pending = 0  # traces of the row group being filled
        self._row_group_traces = row_group_traces
        self._trace_meta: list[dict[str, Any]] = []
        self._frames: set[str] = set()
        self._attitude = False
        self._closed = False
        self.compact = compact  # float32 for FLOAT32_COLUMNS (generated data)
        if compact:
            self.meta.setdefault("float32_columns", list(FLOAT32_COLUMNS))

    def add(self, trace: Trace, index: int | None = None) -> None:
        safety.check_interrupted()  # a signal whose exception was swallowed (physynth.io.safety)
        index = len(self._trace_meta) if index is None else int(index)
        _check_declared(trace, self._held, self._declared)
        self._convert()  # the previous trace
        self._unconverted = (trace, index)
        self._pending += 1
        self._trace_meta.append({"trace": index, **jsonable(trace.meta)})
        if trace.imu is not None:
            self._frames.update(trace.imu.frames)
        self._attitude = self._attitude or trace.truth.has_attitude
        if self._pending >= self._row_group_traces:
            self._flush()

    def _open_writers(self) -> dict[str, pq.ParquetWriter]:
        """The Parquet writers of the tables, opened on the first call (the first conversion, or close)."""
        if len(self._writers) < len(TABLES):
            import pyarrow as pa
            import pyarrow.parquet as pq

            self._schemas = self._schemas or {name: _schema(name, self._compact, self._held[name], self._declared)
                                             for name in TABLES}
            for name in (n for n in TABLES if n not in self._writers):
                path = self.tmp / f"{name}.parquet"
                self._sinks[name] = pa.OSFile(str(path), "wb")
                if self.hash_while_writing:  # integrity hook: the SHA-256 taken as it is written
                    self._hashes[name] = integrity.TrailingHash(path)
                self._writers[name] = pq.ParquetWriter(
                    self._sinks[name], self._schemas[name], store_schema=False,
                    **_column_options(self._schemas[name], self._compact))
        return self._writers

    def _convert(self) -> None:
        """Convert the trace waiting unconverted, if any, to Arrow tables of the row group being filled."""
        if self._unconverted is not None:
            self._open_writers()
            (trace, index), self._unconverted = self._unconverted, None
            for name, table in _tables_of(trace, index, self._schemas).items():
                self._tables[name].append(table)

    def _flush(self) -> None:
        """Write the traces added since the last row group as one row group of every table: in a writer
        thread (:attr:`write_in_thread`) while the caller makes the next traces; at most one row group
        waits to be written (the one before is finished first), so memory stays two row groups."""
        import pyarrow as pa

        writers = self._open_writers()
        self._convert()
        group = {}
        for name, tables in self._tables.items():
            if tables:
                group[name] = pa.concat_tables(tables)
                self._rows[name] += group[name].num_rows
            self._tables[name] = []
        self._pending = 0
        self._wait()
        if not group:
            return
        if not self.write_in_thread:
            _write_group(writers, group, self._hashes)
            return
        if self._thread is None:
            from concurrent.futures import ThreadPoolExecutor

            self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="physynth-parquet")
        self._writing = self._thread.submit(_write_group, writers, group, self._hashes)

    def _wait(self) -> None:
        """Wait for the row group being written in the writer thread (re-raising its error)."""
        if self._writing is not None:
            writing, self._writing = self._writing, None
            writing.result()

    def close(self) -> Path:
        """Finish every table, write ``dataset.json`` and swap the dataset into place.

        On any failure (or interruption) the temporary folder is removed and nothing appears.
        """
        if self._closed:
            return self.path
        try:
            return self._close()
        except BaseException:
            self.abort()
            raise

    def _close(self) -> Path:
        self._flush()
        self._wait()
        self._stop_thread()
        for name, w in self._writers.items():
            w.close()
            self._sinks[name].close()
            if name in self._hashes:
                self._hashes[name].close()  # the footer hashed too
        meta = {
            "schema_version": SCHEMA_VERSION,
            "generator": {"name": "physynth", "version": __version__},
            "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "units": UNITS,
            "frames": FRAMES,
            "uwb_reason_codes": REASONS,
            **jsonable(self.meta),
            "imu_frames": [f for f in (IMU_FRAME, IMU_BODY_FRAME) if f in self._frames],
            "truth_attitude": self._attitude,
            "n_traces": len(self._trace_meta),
            "traces": self._trace_meta,
            # integrity hook (physynth.io.integrity): row counts and SHA-256 of every table
            "files": integrity.file_records(self.tmp, {f"{name}.parquet": n for name, n in self._rows.items()},
                                            {f"{name}.parquet": h for name, h in self._hashes.items()}),
        }
        (self.tmp / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        safety.swap_in(self.tmp, self.path)
        safety.unregister_temporary(self.tmp)
        self._closed = True
        self._lock.release()
        return self.path

    def _stop_thread(self) -> None:
        if self._thread is not None:
            self._thread.shutdown(wait=True)
            self._thread = None

    def abort(self) -> None:
        try:
            self._wait()
        except Exception:  # noqa: BLE001 - failing already: the row group being written is discarded
            pass
        self._stop_thread()
        for w in (*self._writers.values(), *self._sinks.values()):
            try:
                w.close()
            except Exception:  # noqa: BLE001 - best effort clean-up of a failed write
                pass
        for h in self._hashes.values():
            h.close(rest=False)
        shutil.rmtree(self.tmp, ignore_errors=True)
        safety.unregister_temporary(self.tmp)
        self._closed = True
        self._lock.release()


def write_dataset(path: str | os.PathLike, traces: Iterable[Trace], *, meta: dict[str, Any] | None = None,
                  overwrite: bool = False, inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """Write traces as a dataset directory, atomically. Returns the path.

    ``traces`` is an iterable of at least one :class:`Trace` (a list, a generator; for one trace,
    ``[trace]``). ``inputs`` are the files or folders the traces were read from: the output may not be
    or hold one.

    Raises
    ------
    ArgumentError
        ``traces`` is a single Trace, or holds none (nothing is written: a dataset without traces could
        not be read back).
    """
    stream = iter(trace_iterable(traces))
    first = next(stream, None)
    if first is None:
        raise ArgumentError(f"no traces to write to {path}: a dataset holds at least one trace")
    with DatasetWriter(path, meta=meta, overwrite=overwrite, inputs=inputs) as w:
        for trace in itertools.chain([first], stream):
            w.add(trace)
    return Path(path)


@dataclass(frozen=True, slots=True)
class Dataset:
    """A dataset read back: its ``dataset.json`` and its traces."""

    meta: dict[str, Any]
    traces: list[Trace]

    def __len__(self) -> int:
        return len(self.traces)

    def __iter__(self) -> Iterator[Trace]:
        return iter(self.traces)


def read_meta(path: str | os.PathLike) -> dict[str, Any]:
    """The ``dataset.json`` of a dataset directory."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"dataset {path} does not exist")
    if not path.is_dir():
        raise DatasetError(f"{path} is not a dataset directory")
    meta_file = path / "dataset.json"
    if not meta_file.is_file():
        raise DatasetError(f"{path} is not a PhySynth dataset (no dataset.json)")
    try:
        meta = json.loads(meta_file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"cannot read {meta_file}: {exc}") from None
    if not isinstance(meta, dict) or meta.get("schema_version") != SCHEMA_VERSION:
        raise DatasetError(f"{meta_file}: unsupported schema_version {meta.get('schema_version')!r}"
                           if isinstance(meta, dict) else f"{meta_file}: not a JSON object")
    if is_csv_export(path):
        raise DatasetError(f"{path} is a CSV export of a PhySynth dataset, not a dataset: its tables are CSV "
                           "files for other tools; use the dataset it was exported from")
    return meta


def is_csv_export(path: Path) -> bool:
    """True for a folder written by the CSV export (:mod:`physynth.io.export.csv`): ``truth.csv`` beside
    ``dataset.json`` (copied from the dataset) and no Parquet truth table."""
    return ((path / "truth.csv").is_file() and not (path / "truth.parquet").exists()
            and not (path / "truth").is_dir())


def table_files(path: Path, name: str, meta: Mapping[str, Any] | None = None) -> list[Path]:
    """The Parquet files of table ``name``, in trace order: exactly those that the integrity record of
    ``dataset.json`` (``meta``, read when None) lists (:func:`physynth.io.integrity.table_records`), so
    that a stray file in the folder is never read; in a dataset without a record (an older PhySynth),
    ``<name>.parquet``, or the parts ``<name>/part-*.parquet`` of a dataset generated in shards."""
    files = (read_meta(path) if meta is None else meta).get("files")
    if isinstance(files, dict):
        recorded = integrity.table_records(files, name)
        if not recorded:
            raise DatasetError(f"dataset {path} is damaged: its integrity record (dataset.json 'files') lacks "
                               f"the table {name}")
        return [path / f for f in recorded]
    single = path / f"{name}.parquet"
    if single.is_file():
        return [single]
    parts = sorted((path / name).glob("part-*.parquet")) if (path / name).is_dir() else []
    if not parts:
        raise DatasetError(f"dataset {path} is incomplete: {name}.parquet is missing")
    return parts


class AnchorCodes:
    """Anchor ids as small integers, the same for every row group a reader reads (each row group's
    dictionary of ``uwb.anchor_id`` is mapped onto it): a trace's rows then find their anchor by an
    array lookup, and a trace cut across row groups joins its codes as they are."""

    def __init__(self) -> None:
        self.ids: list[str] = []
        self._code: dict[str, int] = {}

    def codes(self, ids: Sequence[str], indices: np.ndarray) -> np.ndarray:
        """The codes of ``ids[indices]`` (a dictionary and its indices)."""
        lut = np.array([self._code.setdefault(a, len(self._code)) for a in ids], dtype=np.int32)
        self.ids = list(self._code)
        return lut[indices] if len(ids) else np.zeros(len(indices), np.int32)

    def to_index(self, codes: np.ndarray, anchor_ids: Sequence[str]) -> np.ndarray:
        """Each code's position in ``anchor_ids`` (a trace's anchors; -1 where not among them)."""
        lut = np.full(len(self._code), -1, dtype=np.int16)
        for i, a in enumerate(anchor_ids):
            if a in self._code:
                lut[self._code[a]] = i
        return lut[codes]


def _columns(table: pa.Table, name: str, f: Path, codes: AnchorCodes) -> dict[str, np.ndarray]:
    """The columns of one table read from ``f``, as stored (float32 stays float32; null floats read as
    NaN, in float64); the UWB ``anchor_id`` as ``codes`` (``anchor_code``)."""
    import pyarrow as pa

    names = arrow_schemas()[0][name].names
    optional = {c for group in OPTIONAL_COLUMNS.get(name, {}).values() for c in group}
    if name == "imu" and not any(c in table.column_names for c in optional):
        raise DatasetError(f"{f}: no acceleration or angular-rate column")
    missing = [c for c in names if c not in table.column_names and c not in optional]
    if missing:
        raise DatasetError(f"{f}: missing column(s) {', '.join(missing)}")
    cols = {}
    for c in names:
        if c not in table.column_names:
            continue
        col = table.column(c)
        if c == "nlos":
            cols["nlos_known"] = valid_mask(col)
            cols[c] = to_numpy(col)  # unknown (null) reads False
        elif c in ("anchor_id", "name") and name != "uwb":  # a few strings per trace
            cols[c] = np.asarray(col.to_pylist(), dtype=object).reshape(-1)
        elif c == "anchor_id":  # read as a dictionary (:func:`_parquet_file`), as it is stored
            arr = col.combine_chunks()
            enc = (arr if pa.types.is_dictionary(arr.type) else arr.dictionary_encode()) if len(col) else None
            cols["anchor_code"] = (np.array([], dtype=np.int32) if enc is None
                                   else codes.codes(enc.dictionary.to_pylist(), to_numpy(enc.indices)))
        else:  # null (an optional group this trace does not have) reads as NaN
            cols[c] = to_numpy(col)
    return cols


def _read_table(files: list[Path], name: str, codes: AnchorCodes) -> dict[str, np.ndarray]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    parts = []
    for f in files:
        try:
            parts.append(_columns(pq.read_table(f), name, f, codes))
        except (OSError, pa.ArrowException) as exc:
            raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None
    return {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}


def _split(cols: dict[str, np.ndarray]) -> dict[int, dict[str, np.ndarray]]:
    trace = cols["trace"]
    if trace.size == 0:
        return {}
    if trace.size == 1 or bool(np.all(trace[1:] >= trace[:-1])):  # as written: slices, no copy
        starts = run_starts(trace)
        ends = np.append(starts[1:], trace.size)
        return {int(trace[s]): {c: v[s:e] for c, v in cols.items()} for s, e in zip(starts, ends, strict=True)}
    order = np.argsort(trace, kind="stable")
    keys, starts = np.unique(trace[order], return_index=True)
    ends = np.append(starts[1:], trace.size)
    return {int(k): {c: v[order[s:e]] for c, v in cols.items()} for k, s, e in zip(keys, starts, ends, strict=True)}


def _row_groups_sorted(files: list[Path]) -> bool:
    """True when the row groups of ``files``, in order, hold non-decreasing trace indices (statistics)."""
    last = -1
    for f in files:
        md = _parquet_file(f).metadata
        col = md.schema.names.index("trace") if "trace" in md.schema.names else -1
        for g in range(md.num_row_groups):
            if md.row_group(g).num_rows == 0:
                continue
            st = md.row_group(g).column(col).statistics if col >= 0 else None
            if st is None or not st.has_min_max or st.min < last:
                return False
            last = st.max
    return True


def _parquet_file(f: Path, dictionary: Sequence[str] = ()) -> pq.ParquetFile:
    """``f`` opened, its ``dictionary`` columns to be read as Arrow dictionaries (the UWB anchor ids, stored
    dictionary-encoded: read so, they need no encoding again, which would import pyarrow.compute)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.ParquetFile(f, read_dictionary=list(dictionary) or None)
    except (OSError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None


def _row_group(pf: pq.ParquetFile, g: int, name: str, f: Path, codes: AnchorCodes) -> dict[str, np.ndarray]:
    import pyarrow as pa

    try:
        return _columns(pf.read_row_group(g), name, f, codes)
    except (OSError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None


@functools.cache
def _reader_of(pid: int) -> ThreadPoolExecutor:  # noqa: ARG001 (a forked worker makes its own)
    return ThreadPoolExecutor(1, thread_name_prefix="physynth-read")


def read_ahead(fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
    """``fn(item)`` of each item in order, the next one computed on a reader thread (one per process,
    shared by every stream, so calls never overlap) while the caller works on the current one: Parquet
    decodes without the GIL, so a reader's decoding overlaps the export's writing."""
    pool = _reader_of(os.getpid())
    it = iter(items)
    try:
        first = next(it)
    except StopIteration:
        return
    ahead = pool.submit(fn, first)
    for item in it:
        current = ahead.result()
        ahead = pool.submit(fn, item)
        yield current
    yield ahead.result()


def _table_stream(path: Path, name: str, meta: Mapping[str, Any],
                  codes: AnchorCodes) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """(trace index, columns) of one table, read one row group at a time, in trace order."""
    files = table_files(path, name, meta)
    if not _row_groups_sorted(files):  # not written by DatasetWriter: read it whole, once
        yield from sorted(_split(_read_table(files, name, codes)).items())
        return
    pending: tuple[int, dict[str, np.ndarray]] | None = None
    dictionary = ("anchor_id",) if name == "uwb" else ()
    where = ((pf, g, f) for f in files for pf in (_parquet_file(f, dictionary),)
             for g in range(pf.metadata.num_row_groups))
    for cols in read_ahead(lambda w: _row_group(w[0], w[1], name, w[2], codes), where):
        groups = sorted(_split(cols).items())
        if pending is not None and groups and groups[0][0] == pending[0]:  # a trace across groups
            groups[0] = (pending[0], {c: np.concatenate([pending[1][c], v]) for c, v in groups[0][1].items()})
        elif pending is not None and groups:
            yield pending
        if groups:
            pending = groups.pop()
        yield from groups
    if pending is not None:
        yield pending


@dataclass(frozen=True, slots=True)
class StoredTrace:
    """One trace of a dataset as its tables store it: per table its columns (:func:`iter_stored_traces`),
    None where the table has no row of the trace; ``uwb["anchor_code"]`` the anchors as ``codes``."""

    index: int
    truth: dict[str, np.ndarray]
    anchors: dict[str, np.ndarray] | None
    imu: dict[str, np.ndarray] | None
    uwb: dict[str, np.ndarray] | None
    meta: dict[str, Any]
    codes: AnchorCodes

    def anchor_ids(self) -> tuple[str, ...]:
        return () if self.anchors is None else tuple(self.anchors["anchor_id"])

    def uwb_anchor(self, path: Path) -> np.ndarray:
        """The UWB rows' anchors as indexes into :meth:`anchor_ids` (int16)."""
        if self.uwb is None:
            return np.array([], np.int16)
        index = self.codes.to_index(self.uwb["anchor_code"], self.anchor_ids())
        if index.size and index.min() < 0:
            unknown = sorted({self.codes.ids[c] for c in np.unique(self.uwb["anchor_code"][index < 0]).tolist()})
            raise DatasetError(f"dataset {path}: trace {self.index} has UWB rows of unknown anchor(s) {unknown}")
        return index


def _trace_of(st: StoredTrace, meta: dict[str, Any], path: Path) -> Trace:
    idx, tr, an, im, uw = st.index, st.truth, st.anchors, st.imu, st.uwb
    if an is None:  # an IMU-only recording (e.g. BROAD) has no anchors
        anchors = Anchors(ids=(), pos_enu_m=np.zeros((0, 3)))
    else:
        anchors = Anchors(ids=tuple(an["anchor_id"]), names=tuple(an["name"]),
                          pos_enu_m=np.stack([an[f"pos_{c}_m"] for c in "enu"], axis=1))
    truth = Truth(t_s=tr["t_s"], pos_enu_m=np.stack([tr[f"pos_{c}_m"] for c in "enu"], axis=1),
                  vel_enu_mps=np.stack([tr[f"vel_{c}_mps"] for c in "enu"], axis=1),
                  quat_wxyz=optional_group(tr, "truth", "quat_wxyz"),
                  omega_body_radps=optional_group(tr, "truth", "omega_body_radps"))
    imu = None
    if im is not None:
        groups = {a: optional_group(im, "imu", a) for a in OPTIONAL_COLUMNS["imu"]}
        if all(g is None for g in groups.values()):
            raise DatasetError(f"dataset {path}: trace {idx} has IMU rows without any value")
        imu = Imu(t_s=im["t_s"], frame=meta.get("imu_frame", IMU_FRAME), **groups)
    if uw is None:
        uwb = Uwb(t_s=np.array([]), anchor=np.array([], np.int16), range_m=np.array([]))
    else:
        uwb = Uwb(t_s=uw["t_s"], anchor=st.uwb_anchor(path),
                  range_m=uw["range_m"], true_range_m=uw["true_range_m"], nlos=uw["nlos"],
                  burst=uw["burst"], reason=uw["reason"],
                  nlos_known=bool(uw["nlos_known"].all()) if len(uw["nlos_known"]) else False)
    return Trace(truth=truth, uwb=uwb, anchors=anchors, imu=imu, meta=st.meta)


def iter_traces(path: str | os.PathLike, meta: dict[str, Any] | None = None) -> Iterator[Trace]:
    """The traces of a dataset directory, one at a time, in trace order (:func:`iter_indexed_traces`)."""
    for _, trace in iter_indexed_traces(path, meta):
        yield trace


def iter_indexed_traces(path: str | os.PathLike, meta: dict[str, Any] | None = None) -> Iterator[tuple[int, Trace]]:
    """``(trace index, Trace)`` of a dataset directory, one at a time, in trace order.

    Every table is read one row group at a time (a row group holds a few dozen traces), so memory
    does not grow with the number of traces. ``meta`` is the dataset's ``dataset.json`` when already
    read (:func:`read_meta`).
    """
    path = Path(path)
    meta = read_meta(path) if meta is None else meta
    for st in iter_stored_traces(path, meta):
        yield st.index, trace_of(st, meta, path)


def trace_of(st: StoredTrace, meta: dict[str, Any], path: Path) -> Trace:
    """The record of a stored trace of the dataset at ``path`` (whose ``dataset.json`` is ``meta``).

    Raises
    ------
    DatasetError
        When its tables read but do not make a valid record (unsorted times, unknown anchors, ...).
    """
    try:
        return _trace_of(st, meta, path)
    except ValueError as exc:
        raise DatasetError(f"dataset {path}: trace {st.index} is invalid: {str(exc).splitlines()[0]}") from None


CHECK_THREAD = "physynth-check"
"""The name (prefix) of the thread that checks a dataset while it is read (``iter_stored_traces(...,
check_alongside=True)``)."""


def iter_stored_traces(path: str | os.PathLike, meta: dict[str, Any] | None = None, *,
                       check_alongside: bool = False) -> Iterator[StoredTrace]:
    """The traces of a dataset directory as stored (:class:`StoredTrace`), one at a time, in trace order,
    by default once its files are checked against ``dataset.json`` (sizes, row counts, hashes, trace ids): what
    :func:`iter_indexed_traces` makes records of, and what an export copies without making them.

    ``check_alongside``: the files are checked (:func:`~physynth.io.integrity.check_dataset`) on a thread of
    their own (:data:`CHECK_THREAD`), started before the first trace is read, while the traces are read and
    yielded. Traces may then be yielded before the check is done: the caller must not publish anything
    until the iterator is exhausted without error. The check's :class:`~physynth.errors.IntegrityError`
    is raised after the last trace (before the iterator ends) and, when reading fails (a damaged file that
    pyarrow cannot read), instead of the reading error. A caller that stops early (closes the iterator,
    or drops it after a ``break``) waits for the check to end there, and is not told what it found.
    """
    path = Path(path)
    meta = read_meta(path) if meta is None else meta
    # integrity hook (physynth.io.integrity): sizes, row counts, hashes and trace ids against dataset.json
    hashes = not integrity.environ_skip_hashes()
    if not check_alongside:
        integrity.check_dataset(path, meta, hashes=hashes)
        n = yield from _stored_traces(path, meta)
    else:
        n = yield from _checked_alongside(_stored_traces(path, meta),
                                          lambda: integrity.check_dataset(path, meta, hashes=hashes))
    if n == 0:
        raise DatasetError(f"dataset {path} holds no traces")


def _checked_alongside(reading: Generator[StoredTrace, None, int],
                       check: Callable[[], Any]) -> Generator[StoredTrace, None, int]:
    """The items of ``reading``, while ``check()`` runs on a thread (:data:`CHECK_THREAD`); returns how many.
    The check's IntegrityError is raised after the last item, and instead of an error of ``reading``."""
    pool = ThreadPoolExecutor(1, thread_name_prefix=CHECK_THREAD)
    try:
        checked = pool.submit(check)
        pool.shutdown(wait=False)  # its thread ends with the check, even if this generator is never closed
        n = 0
        while True:
            try:
                st = next(reading)
            except StopIteration:
                break
            except Exception:
                if isinstance(checked.exception(), IntegrityError):  # waits: the damage explains the failure
                    raise checked.exception() from None
                raise
            n += 1
            yield st
        checked.result()  # waits; raises what the check found
        return n
    finally:
        reading.close()
        pool.shutdown(wait=True)  # a caller that stopped early: the check's thread has ended when it goes on


def _stored_traces(path: Path, meta: dict[str, Any]) -> Generator[StoredTrace, None, int]:
    """The traces of :func:`iter_stored_traces`, read without a check; returns how many."""
    codes = AnchorCodes()
    streams = {name: _table_stream(path, name, meta, codes) for name in TABLES}
    streams["meta"] = iter_trace_meta(path, meta)
    heads: dict[str, tuple[int, dict] | None] = {name: next(streams[name], None) for name in streams if name != "truth"}

    def take(name: str, idx: int) -> dict | None:
        while heads[name] is not None and heads[name][0] < idx:  # rows of a trace without truth: skipped
            heads[name] = next(streams[name], None)
        head = heads[name]
        if head is not None and head[0] == idx:
            heads[name] = next(streams[name], None)
            return head[1]
        return None

    n = 0
    for idx, tr in streams["truth"]:
        n += 1
        trace_meta = {k: v for k, v in (take("meta", idx) or {}).items() if k != "trace"}
        yield StoredTrace(idx, tr, take("anchors", idx), take("imu", idx), take("uwb", idx), trace_meta, codes)
    return n


TRACE_META_PARTS = "traces/part-*.jsonl"
"""Where a dataset of several shards keeps its per-trace metadata: one JSON object per line and trace, in
trace order (``dataset.json`` then has no ``traces`` list, so it stays small for any number of traces)."""


def iter_trace_meta(path: str | os.PathLike, meta: dict[str, Any] | None = None) -> Iterator[tuple[int, dict]]:
    """``(trace index, per-trace metadata)`` of a dataset, in trace order, one at a time.

    From the ``traces`` list of ``dataset.json``, or from the ``traces/part-*.jsonl`` files of a
    dataset generated in several shards (:data:`TRACE_META_PARTS`).
    """
    path = Path(path)
    meta = read_meta(path) if meta is None else meta
    if "traces" in meta:
        try:
            listed = sorted(((int(m["trace"]), m) for m in meta["traces"]), key=lambda x: x[0])
        except (TypeError, KeyError, ValueError):
            raise DatasetError(f"dataset {path}: dataset.json 'traces' entries have no valid 'trace' id") from None
        yield from listed
        return
    for f in sorted(path.glob(TRACE_META_PARTS)):
        try:
            with f.open(encoding="utf-8") as fh:
                for line in fh:
                    if line.strip():
                        m = json.loads(line)
                        yield int(m["trace"]), m
        except (OSError, ValueError, KeyError) as exc:
            raise DatasetError(f"cannot read {f}: {exc}") from None


def n_traces(meta: dict[str, Any]) -> int | None:
    """Number of traces recorded in a dataset's ``dataset.json`` (None when it does not say)."""
    n = meta.get("n_traces")
    return int(n) if isinstance(n, int) else None


def recorded_grid_rate_hz(meta: dict[str, Any]) -> float:
    """The evaluation grid rate [Hz] a dataset records: its scenario's ``grid_rate_hz`` (written by the
    generator), or :data:`~physynth.constants.DEFAULT_GRID_RATE_HZ` when it records none (an imported
    recording) or not a positive finite number."""
    scenario = meta.get("scenario")
    rate = scenario.get("grid_rate_hz") if isinstance(scenario, dict) else None
    if isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate) and rate > 0:
        return float(rate)
    return DEFAULT_GRID_RATE_HZ


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Read a whole dataset directory back into Trace records (same values as written).

    Holds every trace in memory; :func:`iter_traces` streams them instead.
    """
    path = Path(path)
    meta = read_meta(path)
    traces = list(iter_traces(path, meta))
    if not traces:
        raise DatasetError(f"dataset {path} holds no traces")
    return Dataset(meta=meta, traces=traces)
