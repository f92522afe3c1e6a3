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
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__
from .._json import jsonable
from ..constants import DEFAULT_GRID_RATE_HZ, IMU_BODY_FRAME, IMU_FRAME, SCHEMA_VERSION
from ..errors import ArgumentError, DatasetError
from ..records import Anchors, Imu, Trace, Truth, Uwb, trace_iterable
from . import integrity, safety
from .atomic import temp_sibling

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq

TABLES = ("truth", "imu", "uwb", "anchors")

OPTIONAL_COLUMNS = {
    "truth": {"quat_wxyz": [f"quat_{c}" for c in "wxyz"], "omega_body_radps": [f"omega_{c}_radps" for c in "xyz"]},
    "imu": {"acc_mps2": [f"acc_{c}_mps2" for c in "enu"], "acc_body_mps2": [f"acc_{c}_mps2" for c in "xyz"],
            "gyro_body_radps": [f"gyro_{c}_radps" for c in "xyz"]},
}
"""Column groups that a trace may lack: written as nulls, read back as None (and absent in old datasets)."""

FLOAT32_COLUMNS = ("acc_e_mps2", "acc_n_mps2", "acc_u_mps2", "acc_x_mps2", "acc_y_mps2", "acc_z_mps2",
                   "gyro_x_radps", "gyro_y_radps", "gyro_z_radps", "vel_e_mps", "vel_n_mps", "vel_u_mps",
                   "quat_w", "quat_x", "quat_y", "quat_z", "omega_x_radps", "omega_y_radps", "omega_z_radps")
"""Columns that generated datasets store as float32 (``DatasetWriter(compact=True)``): IMU acceleration
and angular rate (float32 keeps 7 significant digits, about 1e-6 m/s^2 at 10 m/s^2, against a per-sample
noise of metres per second squared), truth velocity (1e-6 m/s at 10 m/s) and truth attitude (quaternion
components to 6e-8, an attitude within 1.2e-7 rad; body rates to 7 digits). Times, positions, ranges and
anchor positions stay float64: times may be epoch seconds, positions are training labels (float32 would
round them to 0.2 mm at 2 km, and their second difference, an acceleration, to metres per second
squared) and range residuals are the metric of the paper. Readers return float64."""


@functools.cache
def arrow_schemas() -> tuple[dict[str, pa.Schema], dict[str, pa.Schema]]:
    """``(SCHEMAS, SCHEMAS_COMPACT)``: the Arrow schema of every table, float64 throughout, and with
    :data:`FLOAT32_COLUMNS` as float32. Built (and pyarrow imported) on the first call."""
    import pyarrow as pa

    schemas = {
        "truth": pa.schema([("trace", pa.int32()), ("t_s", pa.float64())]
                           + [(f"pos_{c}_m", pa.float64()) for c in "enu"]
                           + [(f"vel_{c}_mps", pa.float64()) for c in "enu"]
                           + [(c, pa.float64()) for cols in OPTIONAL_COLUMNS["truth"].values() for c in cols]),
        "imu": pa.schema([("trace", pa.int32()), ("t_s", pa.float64())]
                         + [(c, pa.float64()) for cols in OPTIONAL_COLUMNS["imu"].values() for c in cols]),
        "uwb": pa.schema([("trace", pa.int32()), ("t_s", pa.float64()), ("anchor_id", pa.string()),
                          ("range_m", pa.float64()), ("true_range_m", pa.float64()), ("nlos", pa.bool_()),
                          ("burst", pa.int64()), ("reason", pa.int8())]),
        "anchors": pa.schema([("trace", pa.int32()), ("anchor_id", pa.string()), ("name", pa.string())]
                             + [(f"pos_{c}_m", pa.float64()) for c in "enu"]),
    }
    compact = {
        name: pa.schema([pa.field(f.name, pa.float32()) if f.name in FLOAT32_COLUMNS else f for f in schema])
        for name, schema in schemas.items()
    }
    return schemas, compact


def __getattr__(name: str) -> Any:
    """``SCHEMAS`` and ``SCHEMAS_COMPACT``, built on first use (:func:`arrow_schemas`)."""
    if name == "SCHEMAS":
        return arrow_schemas()[0]
    if name == "SCHEMAS_COMPACT":
        return arrow_schemas()[1]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


NULLABLE_COLUMNS = frozenset({"nlos"})
"""Columns that may be null in any dataset (``nlos``: unknown in most real recordings). Every other column
is written as Parquet REQUIRED (no definition levels to encode), except the optional groups
(:data:`OPTIONAL_COLUMNS`) of a dataset that holds all of them (``column_groups=None``), where a trace
may lack a group."""


def _schema(name: str, compact: bool, held: set[str], declared: bool) -> pa.Schema:
    """The table's schema, restricted to the optional groups ``held`` (:func:`_held_groups`). Declared
    groups (``declared``) are REQUIRED: every trace of the dataset has them."""
    import pyarrow as pa

    schema = arrow_schemas()[1 if compact else 0][name]
    optional = {c for cols in OPTIONAL_COLUMNS.get(name, {}).values() for c in cols}
    drop = {c for attr, cols in OPTIONAL_COLUMNS.get(name, {}).items() if attr not in held for c in cols}
    fields = [f.with_nullable(f.name in NULLABLE_COLUMNS or (f.name in optional and not declared))
              for f in schema if f.name not in drop]
    # the UWB anchor ids from a dictionary array (indices: the rows' anchor index), stored as Parquet
    # strings, dictionary-encoded; without the Arrow schema in the file they read back as strings
    return pa.schema([f.with_type(pa.dictionary(pa.int16(), pa.string())) if name == "uwb" and f.name == "anchor_id"
                      else f for f in fields])


def _held_groups(name: str, groups: Mapping[str, Iterable[str]] | None) -> set[str]:
    """The optional column groups of table ``name`` that a dataset declared with ``groups`` holds (all
    when None); ValueError on a group the table does not have."""
    if groups is None or name not in OPTIONAL_COLUMNS:
        return set(OPTIONAL_COLUMNS.get(name, {}))
    wanted = set(groups.get(name, ()))
    unknown = wanted - set(OPTIONAL_COLUMNS[name])
    if unknown:
        raise ValueError(f"unknown optional column groups of table {name}: {sorted(unknown)}")
    return wanted


def generated_column_groups(imu_frames: Iterable[str]) -> dict[str, list[str]]:
    """The optional column groups a generated dataset holds: the truth attitude always, the IMU streams
    of ``imu_frames`` (a scenario's ``imu_frames``)."""
    frames = set(imu_frames)
    imu = (["acc_mps2"] if IMU_FRAME in frames else []) + (
        ["acc_body_mps2", "gyro_body_radps"] if IMU_BODY_FRAME in frames else [])
    return {"truth": list(OPTIONAL_COLUMNS["truth"]), "imu": imu}


SENSOR_COLUMNS = frozenset(c for group in ("acc_mps2", "acc_body_mps2", "gyro_body_radps")
                           for c in OPTIONAL_COLUMNS["imu"][group])
"""IMU sample columns: in generated (float32) datasets written PLAIN and uncompressed, since their white
noise leaves snappy nothing to gain (4 % of their bytes, at three times the CPU time)."""


def _column_options(schema: pa.Schema, compact: bool) -> dict[str, Any]:
    """Per-column encodings and codecs of :class:`pyarrow.parquet.ParquetWriter`, chosen by measured
    bytes and CPU time (``benchmarks/bench_generate.py``; docs/scale.md "Bytes on disk"):

    - float columns: BYTE_STREAM_SPLIT + snappy (noisy floats then compress to about 20 % fewer bytes
      than plain encoding, at the same CPU time); in generated data, the float32 IMU samples PLAIN and
      uncompressed (:data:`SENSOR_COLUMNS`) and ``range_m`` PLAIN + snappy (its NaNs of undelivered
      attempts compress better unsplit);
    - ``burst`` and ``reason``: DELTA_BINARY_PACKED (runs of small integers: a tenth of the bytes of
      plain + snappy at less CPU time);
    - ``anchor_id`` and ``name``: dictionary encoding; ``trace``: plain + snappy, with statistics (the
      reader finds each trace's row groups from them).
    """
    import pyarrow as pa

    encoding, codec = {}, {}
    for f in schema:
        codec[f.name] = "snappy"
        if f.name in ("anchor_id", "name"):
            continue
        if f.name in ("burst", "reason"):
            encoding[f.name] = "DELTA_BINARY_PACKED"
        elif compact and (f.name in SENSOR_COLUMNS and pa.types.is_float32(f.type) or f.name == "range_m"):
            encoding[f.name] = "PLAIN"
            codec[f.name] = "none" if f.name in SENSOR_COLUMNS else "snappy"
        elif pa.types.is_floating(f.type):
            encoding[f.name] = "BYTE_STREAM_SPLIT"
        else:
            encoding[f.name] = "PLAIN"
    return {"compression": codec, "column_encoding": encoding, "use_dictionary": ["anchor_id", "name"],
            "write_statistics": ["trace"]}


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


@functools.cache
def _numpy_of() -> dict[pa.DataType, type]:
    """NumPy scalar type of each fixed-width Arrow type that :func:`_arrow` wraps without a copy."""
    import pyarrow as pa

    return {pa.float64(): np.float64, pa.float32(): np.float32, pa.int64(): np.int64, pa.int32(): np.int32,
            pa.int16(): np.int16, pa.int8(): np.int8}


def _arrow(values: Any, typ: pa.DataType) -> pa.Array:
    """A NumPy column as an Arrow array, zero-copy from its buffer where possible.

    (``pa.array`` on NumPy input imports pandas, 0.5 s that the writer does not need.)
    """
    import pyarrow as pa

    if isinstance(values, pa.Array):
        return values
    numpy_of = _numpy_of()
    if typ in numpy_of:
        arr = np.ascontiguousarray(values, dtype=numpy_of[typ])
        return pa.Array.from_buffers(typ, arr.shape[0], [None, pa.py_buffer(arr)])
    if typ == pa.bool_():
        arr = np.asarray(values, dtype=bool)
        return pa.Array.from_buffers(typ, arr.shape[0], [None, pa.py_buffer(np.packbits(arr, bitorder="little"))])
    if typ == pa.string():
        if isinstance(values, tuple):  # anchor ids and names: the same few strings in every trace
            try:
                return _string_array(values)
            except TypeError:  # an unhashable element
                pass
        return _build_string_array(values)
    return pa.array(values, type=typ)


def _build_string_array(values: Iterable[Any]) -> pa.Array:
    import pyarrow as pa

    data = [str(v).encode("utf-8") for v in values]
    offsets = np.concatenate([[0], np.cumsum([len(b) for b in data])]).astype(np.int32)
    return pa.Array.from_buffers(pa.string(), len(data), [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(data))])


@functools.lru_cache(maxsize=64)
def _string_array(values: tuple[Any, ...]) -> pa.Array:
    """The Arrow string array of a tuple of values, built once per tuple (Arrow arrays are immutable, so
    every trace of a scenario shares its anchor ids' and names' arrays: a third of the per-trace Python
    time of the table conversion went into rebuilding them)."""
    return _build_string_array(values)


def _table(name: str, cols: list[Any], schema: pa.Schema) -> pa.Table:
    """A table of ``schema`` (one of ``SCHEMAS``, compact or restricted by :func:`_schema`) from NumPy columns."""
    import pyarrow as pa

    n = len(cols[0])
    return pa.Table.from_arrays([pa.nulls(n, f.type) if c is None else _arrow(c, f.type)
                                 for c, f in zip(cols, schema, strict=True)], schema=schema)


def _optional(record: Any, table: str, schema: pa.Schema) -> list[np.ndarray | None]:
    """Columns of the optional groups of ``record`` that ``schema`` holds, in schema order; None (written
    as nulls) where the record lacks a group. A group the record has but the schema lacks is an error
    (it would be lost)."""
    out: list[np.ndarray | None] = []
    names = set(schema.names)
    for attr, cols in OPTIONAL_COLUMNS[table].items():
        value = getattr(record, attr)
        if cols[0] not in names:
            if value is not None:
                raise DatasetError(f"a trace has {table} columns {', '.join(cols)} that this dataset was not "
                                   "declared to hold")
            continue
        out += [None if value is None else value[:, k] for k in range(len(cols))]
    return out


def _check_declared(trace: Trace, held: Mapping[str, set[str]], declared: bool) -> None:
    """DatasetError when ``trace`` has an optional column group that the dataset does not hold
    (``held``: :func:`_held_groups` of each table), as :func:`_optional` would raise when writing it,
    or, in a dataset whose groups were ``declared``, lacks one that it holds (its columns are REQUIRED)."""
    for table, record in (("truth", trace.truth), ("imu", trace.imu)):
        for attr, cols in OPTIONAL_COLUMNS[table].items():
            has = record is not None and getattr(record, attr) is not None
            if has and attr not in held[table]:
                raise DatasetError(f"a trace has {table} columns {', '.join(cols)} that this dataset was not "
                                   "declared to hold")
            if declared and not has and attr in held[table]:
                raise DatasetError(f"a trace lacks {table} columns {', '.join(cols)} that this dataset was "
                                   "declared to hold")


def _optional_group(cols: dict[str, np.ndarray], table: str, attr: str) -> np.ndarray | None:
    """A group of optional columns read back as (N, k), or None when absent or null throughout."""
    names = OPTIONAL_COLUMNS[table][attr]
    if any(c not in cols for c in names):
        return None
    arr = np.stack([cols[c] for c in names], axis=1).astype(np.float64)
    if arr.size and np.all(np.isnan(arr)):
        return None
    return arr


def _tables_of(trace: Trace, index: int, schemas: Mapping[str, pa.Schema]) -> dict[str, pa.Table]:
    import pyarrow as pa

    tr = trace.truth
    n = tr.t_s.shape[0]
    out = {"truth": _table("truth", [np.full(n, index, np.int32), tr.t_s, *tr.pos_enu_m.T, *tr.vel_enu_mps.T,
                                     *_optional(tr, "truth", schemas["truth"])], schemas["truth"])}
    if trace.imu is not None:
        im = trace.imu
        out["imu"] = _table("imu", [np.full(im.t_s.shape[0], index, np.int32), im.t_s,
                                    *_optional(im, "imu", schemas["imu"])], schemas["imu"])
    u = trace.uwb
    nlos = (_arrow(u.nlos, pa.bool_()) if u.nlos_known else pa.nulls(len(u), pa.bool_()))
    anchor_id = pa.DictionaryArray.from_arrays(_arrow(u.anchor, pa.int16()), _arrow(trace.anchors.ids, pa.string()))
    out["uwb"] = _table("uwb", [np.full(len(u), index, np.int32), u.t_s, anchor_id, u.range_m, u.true_range_m,
                                nlos, u.burst, u.reason], schemas["uwb"])
    a = trace.anchors
    out["anchors"] = _table("anchors", [np.full(len(a), index, np.int32), a.ids, a.names, *a.pos_enu_m.T],
                            schemas["anchors"])
    return out


class DatasetWriter:
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
            import pyarrow.parquet as pq

            self._schemas = self._schemas or {name: _schema(name, self._compact, self._held[name], self._declared)
                                             for name in TABLES}
            for name in (n for n in TABLES if n not in self._writers):
                self._writers[name] = pq.ParquetWriter(
                    self.tmp / f"{name}.parquet", self._schemas[name], store_schema=False,
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
        """Write the traces added since the last row group as one row group of every table."""
        import pyarrow as pa

        writers = self._open_writers()
        self._convert()
        for name, tables in self._tables.items():
            if tables:
                table = pa.concat_tables(tables)
                writers[name].write_table(table)
                self._rows[name] += table.num_rows
            self._tables[name] = []
        self._pending = 0

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
        for w in self._writers.values():
            w.close()
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
            "files": integrity.file_records(self.tmp, {f"{name}.parquet": n for name, n in self._rows.items()}),
        }
        (self.tmp / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        safety.swap_in(self.tmp, self.path)
        safety.unregister_temporary(self.tmp)
        self._closed = True
        self._lock.release()
        return self.path

    def abort(self) -> None:
        for w in self._writers.values():
            try:
                w.close()
            except Exception:  # noqa: BLE001 - best effort clean-up of a failed write
                pass
        shutil.rmtree(self.tmp, ignore_errors=True)
        safety.unregister_temporary(self.tmp)
        self._closed = True
        self._lock.release()

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


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


def _columns(table: pa.Table, name: str, f: Path) -> dict[str, np.ndarray]:
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
            cols["nlos_known"] = ~np.asarray(col.is_null().to_numpy(zero_copy_only=False))
            cols[c] = np.asarray(col.fill_null(False).to_numpy(zero_copy_only=False), dtype=bool)
        elif c in ("anchor_id", "name"):
            enc = col.combine_chunks().dictionary_encode() if len(col) else None
            cols[c] = (np.asarray(enc.dictionary.to_pylist(), dtype=object)[enc.indices.to_numpy()]
                       if enc is not None else np.array([], dtype=object))
        else:
            if col.null_count:  # an optional group this trace does not have
                cols[c] = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)
            else:
                cols[c] = col.to_numpy().astype(np.float64) if pa.types.is_float32(col.type) else col.to_numpy()
    return cols


def _read_table(files: list[Path], name: str) -> dict[str, np.ndarray]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    parts = []
    for f in files:
        try:
            parts.append(_columns(pq.read_table(f), name, f))
        except (OSError, pa.ArrowException) as exc:
            raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None
    return {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}


def _split(cols: dict[str, np.ndarray]) -> dict[int, dict[str, np.ndarray]]:
    trace = cols["trace"]
    if trace.size == 0:
        return {}
    if trace.size == 1 or bool(np.all(trace[1:] >= trace[:-1])):  # as written: slices, no copy
        starts = np.concatenate([[0], np.flatnonzero(trace[1:] != trace[:-1]) + 1])
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


def _parquet_file(f: Path) -> pq.ParquetFile:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.ParquetFile(f)
    except (OSError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None


def _row_group(pf: pq.ParquetFile, g: int, name: str, f: Path) -> dict[str, np.ndarray]:
    import pyarrow as pa

    try:
        return _columns(pf.read_row_group(g), name, f)
    except (OSError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None


def _table_stream(path: Path, name: str, meta: Mapping[str, Any]) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """(trace index, columns) of one table, read one row group at a time, in trace order."""
    files = table_files(path, name, meta)
    if not _row_groups_sorted(files):  # not written by DatasetWriter: read it whole, once
        yield from sorted(_split(_read_table(files, name)).items())
        return
    pending: tuple[int, dict[str, np.ndarray]] | None = None
    for f in files:
        pf = _parquet_file(f)
        for g in range(pf.metadata.num_row_groups):
            groups = sorted(_split(_row_group(pf, g, name, f)).items())
            if pending is not None and groups and groups[0][0] == pending[0]:  # a trace across groups
                groups[0] = (pending[0], {c: np.concatenate([pending[1][c], v]) for c, v in groups[0][1].items()})
            elif pending is not None and groups:
                yield pending
            if groups:
                pending = groups.pop()
            yield from groups
    if pending is not None:
        yield pending


def _trace_of(idx: int, tr: dict, an: dict | None, im: dict | None, uw: dict | None,
              meta: dict[str, Any], trace_meta: dict[str, Any], path: Path) -> Trace:
    if an is None:  # an IMU-only recording (e.g. BROAD) has no anchors
        anchors = Anchors(ids=(), pos_enu_m=np.zeros((0, 3)))
    else:
        anchors = Anchors(ids=tuple(an["anchor_id"]), names=tuple(an["name"]),
                          pos_enu_m=np.stack([an[f"pos_{c}_m"] for c in "enu"], axis=1))
    truth = Truth(t_s=tr["t_s"], pos_enu_m=np.stack([tr[f"pos_{c}_m"] for c in "enu"], axis=1),
                  vel_enu_mps=np.stack([tr[f"vel_{c}_mps"] for c in "enu"], axis=1),
                  quat_wxyz=_optional_group(tr, "truth", "quat_wxyz"),
                  omega_body_radps=_optional_group(tr, "truth", "omega_body_radps"))
    imu = None
    if im is not None:
        groups = {a: _optional_group(im, "imu", a) for a in OPTIONAL_COLUMNS["imu"]}
        if all(g is None for g in groups.values()):
            raise DatasetError(f"dataset {path}: trace {idx} has IMU rows without any value")
        imu = Imu(t_s=im["t_s"], frame=meta.get("imu_frame", IMU_FRAME), **groups)
    if uw is None:
        uwb = Uwb(t_s=np.array([]), anchor=np.array([], np.int16), range_m=np.array([]))
    else:
        names, inverse = np.unique(uw["anchor_id"].astype(str), return_inverse=True)
        unknown = sorted(set(names) - set(anchors.ids))
        if unknown:
            raise DatasetError(f"dataset {path}: trace {idx} has UWB rows of unknown anchor(s) {unknown}")
        to_index = np.array([anchors.index(a) for a in names], dtype=np.int16)
        uwb = Uwb(t_s=uw["t_s"], anchor=to_index[inverse] if len(names) else np.array([], np.int16),
                  range_m=uw["range_m"], true_range_m=uw["true_range_m"], nlos=uw["nlos"],
                  burst=uw["burst"], reason=uw["reason"],
                  nlos_known=bool(uw["nlos_known"].all()) if len(uw["nlos_known"]) else False)
    m = {k: v for k, v in trace_meta.items() if k != "trace"}
    return Trace(truth=truth, uwb=uwb, anchors=anchors, imu=imu, meta=m)


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
    # integrity hook (physynth.io.integrity): sizes, row counts, hashes and trace ids against dataset.json
    integrity.check_dataset(path, meta, hashes=not integrity.environ_skip_hashes())
    streams = {name: _table_stream(path, name, meta) for name in TABLES}
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
        try:
            trace = _trace_of(idx, tr, take("anchors", idx), take("imu", idx), take("uwb", idx), meta,
                              take("meta", idx) or {}, path)
        except ValueError as exc:  # tables that read but do not make valid records (unsorted times, ...)
            raise DatasetError(f"dataset {path}: trace {idx} is invalid: {str(exc).splitlines()[0]}") from None
        yield idx, trace
    if n == 0:
        raise DatasetError(f"dataset {path} holds no traces")


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
