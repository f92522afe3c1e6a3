"""The Arrow side of a dataset's tables: schemas, column encodings and a trace's tables to write.

What :class:`physynth.io.dataset.DatasetWriter` writes and :mod:`physynth.io.dataset` reads back: the tables
and their columns (:data:`TABLES`, :data:`OPTIONAL_COLUMNS`, :data:`FLOAT32_COLUMNS`), their Arrow schemas
(:func:`arrow_schemas`), the Parquet encodings of each column (:func:`_column_options`) and the conversion
of a trace's NumPy arrays to Arrow tables (:func:`_tables_of`), zero-copy where a column already has its
stored type and layout. pyarrow is imported on first use.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..constants import IMU_BODY_FRAME, IMU_FRAME
from ..errors import DatasetError
from ..records import Trace

if TYPE_CHECKING:
    import pyarrow as pa


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


def optional_group(cols: dict[str, np.ndarray], table: str, attr: str, dtype: Any = np.float64) -> np.ndarray | None:
    """A group of optional columns read back as (N, k) in ``dtype``, or None when absent or null throughout
    (what the reader's records and the HDF5 export take)."""
    names = OPTIONAL_COLUMNS[table][attr]
    if any(c not in cols for c in names):
        return None
    arr = np.stack([cols[c] for c in names], axis=1).astype(dtype, copy=False)
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


def run_starts(values: np.ndarray) -> np.ndarray:
    """Indexes where a run of equal values starts (0 first; empty for no values): rows grouped by trace
    give one run per trace, found in one pass, no sort."""
    if values.size == 0:
        return np.zeros(0, dtype=np.intp)
    return np.concatenate([[0], np.flatnonzero(values[1:] != values[:-1]) + 1])


def valid_mask(col: Any) -> np.ndarray:
    """Which values of an Arrow column (array or chunked array) are not null, as a NumPy bool array, read
    from its validity bitmap (``col.is_valid()`` would import pyarrow.compute, 30 ms of a reader's start)."""
    import pyarrow as pa

    arr = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    n, off = len(arr), arr.offset
    validity = arr.buffers()[0] if arr.buffers() else None
    if not arr.null_count or validity is None:
        return np.full(n, not arr.null_count)
    return np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little", count=off + n)[off:].astype(bool)


def to_numpy(col: Any, dtype: Any = None) -> np.ndarray:
    """A fixed-width or boolean Arrow column (array or chunked array) as a NumPy array, read from its
    buffers: pyarrow's own ``to_numpy`` imports pandas (half a second) on first use, which a reader does
    not need. Nulls read as NaN (floats; as False for booleans, :func:`valid_mask` for the mask);
    ``dtype``: the result's type (default: the column's)."""
    import pyarrow as pa

    arr = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    n, off = len(arr), arr.offset
    data = arr.buffers()[1]
    if pa.types.is_boolean(arr.type):
        bits = np.frombuffer(data, dtype=np.uint8) if data is not None else np.zeros(0, np.uint8)
        out = np.unpackbits(bits, bitorder="little", count=off + n)[off:].astype(bool)
        if arr.null_count:
            out &= valid_mask(arr)
        return out if dtype is None else out.astype(dtype)
    np_type = _numpy_of().get(arr.type)
    if np_type is None:
        return np.asarray(arr.to_pylist(), dtype=dtype)
    out = np.frombuffer(data, dtype=np_type, count=n, offset=off * np.dtype(np_type).itemsize)
    if dtype is not None or arr.null_count:
        out = out.astype(np.float64 if dtype is None else dtype)
    if arr.null_count:
        out[~valid_mask(arr)] = np.nan
    return out
