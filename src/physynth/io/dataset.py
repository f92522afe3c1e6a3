"""Datasets on disk: a directory with ``dataset.json`` and Parquet tables ``truth``, ``imu``, ``uwb``,
``anchors``, each with a ``trace`` column (DESIGN.md section 1).

Writes are atomic: everything goes to a hidden sibling directory that is renamed into place only
when every table is complete, so an interrupted job never leaves a dataset that looks finished.
:class:`DatasetWriter` streams traces in row groups, so a dataset larger than memory can be written.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .. import __version__
from .._json import jsonable
from ..constants import IMU_BODY_FRAME, IMU_FRAME, SCHEMA_VERSION
from ..errors import DatasetError, OutputExistsError
from ..records import Anchors, Imu, Trace, Truth, Uwb
from .atomic import temp_sibling

TABLES = ("truth", "imu", "uwb", "anchors")

OPTIONAL_COLUMNS = {
    "truth": {"quat_wxyz": [f"quat_{c}" for c in "wxyz"], "omega_body_radps": [f"omega_{c}_radps" for c in "xyz"]},
    "imu": {"acc_mps2": [f"acc_{c}_mps2" for c in "enu"], "acc_body_mps2": [f"acc_{c}_mps2" for c in "xyz"],
            "gyro_body_radps": [f"gyro_{c}_radps" for c in "xyz"]},
}
"""Column groups that a trace may lack: written as nulls, read back as None (and absent in old datasets)."""

SCHEMAS = {
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


def _tables_of(trace: Trace, index: int) -> dict[str, pa.Table]:
    tr = trace.truth
    n = tr.t_s.shape[0]
    cols: dict[str, Any] = {"trace": np.full(n, index, np.int32), "t_s": tr.t_s}
    for k, c in enumerate("enu"):
        cols[f"pos_{c}_m"] = tr.pos_enu_m[:, k]
    for k, c in enumerate("enu"):
        cols[f"vel_{c}_mps"] = tr.vel_enu_mps[:, k]
    _optional_columns(cols, tr, "truth", n)
    out = {"truth": pa.Table.from_pydict(cols, schema=SCHEMAS["truth"])}

    if trace.imu is not None:
        im = trace.imu
        cols = {"trace": np.full(im.t_s.shape[0], index, np.int32), "t_s": im.t_s}
        _optional_columns(cols, im, "imu", im.t_s.shape[0])
        out["imu"] = pa.Table.from_pydict(cols, schema=SCHEMAS["imu"])

    u = trace.uwb
    ids = np.asarray(trace.anchors.ids, dtype=object)
    nlos = pa.array(u.nlos, mask=None if u.nlos_known else np.ones(len(u), bool), type=pa.bool_())
    out["uwb"] = pa.Table.from_arrays(
        [pa.array(np.full(len(u), index, np.int32)), pa.array(u.t_s),
         pa.array(ids[u.anchor] if len(u) else np.array([], object), type=pa.string()),
         pa.array(u.range_m), pa.array(u.true_range_m), nlos, pa.array(u.burst), pa.array(u.reason)],
        schema=SCHEMAS["uwb"],
    )
    a = trace.anchors
    cols = {"trace": np.full(len(a), index, np.int32), "anchor_id": list(a.ids), "name": list(a.names)}
    for k, c in enumerate("enu"):
        cols[f"pos_{c}_m"] = a.pos_enu_m[:, k]
    out["anchors"] = pa.Table.from_pydict(cols, schema=SCHEMAS["anchors"])
    return out


def _optional_columns(cols: dict[str, Any], record: Any, table: str, n: int) -> None:
    """Columns of the optional groups of ``record``: values, or nulls where the record has none."""
    for attr, names in OPTIONAL_COLUMNS[table].items():
        value = getattr(record, attr)
        for k, c in enumerate(names):
            cols[c] = pa.nulls(n, pa.float64()) if value is None else value[:, k]


def _optional_group(cols: dict[str, np.ndarray], table: str, attr: str) -> np.ndarray | None:
    """A group of optional columns read back as (N, k), or None when absent or null throughout."""
    names = OPTIONAL_COLUMNS[table][attr]
    if any(c not in cols for c in names):
        return None
    arr = np.stack([cols[c] for c in names], axis=1).astype(np.float64)
    if arr.size and np.all(np.isnan(arr)):
        return None
    return arr


class DatasetWriter:
    """Streams traces into a new dataset directory; the directory appears only on :meth:`close`.

    >>> with DatasetWriter(out, meta={"kind": "synthetic"}) as w:   # doctest: +SKIP
    ...     for trace in traces:
    ...         w.add(trace)
    """

    def __init__(self, path: str | os.PathLike, *, meta: dict[str, Any] | None = None,
                 overwrite: bool = False, row_group_traces: int = 64) -> None:
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise OutputExistsError(self.path)
        if self.path.exists() and not self.path.is_dir():
            raise DatasetError(f"{self.path} exists and is not a directory")
        self.overwrite = overwrite
        self.meta = dict(meta or {})
        self.tmp = temp_sibling(self.path)
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        try:
            self.tmp.mkdir(parents=True)
        except OSError as exc:
            raise DatasetError(f"cannot create {self.path}: {exc.strerror}") from None
        self._writers = {
            name: pq.ParquetWriter(self.tmp / f"{name}.parquet", SCHEMAS[name], compression="snappy",
                                   use_dictionary=["anchor_id", "name"], write_statistics=["trace"])
            for name in TABLES
        }
        self._pending: dict[str, list[pa.Table]] = {name: [] for name in TABLES}
        self._row_group_traces = row_group_traces
        self._trace_meta: list[dict[str, Any]] = []
        self._frames: set[str] = set()
        self._attitude = False
        self._closed = False

    def add(self, trace: Trace, index: int | None = None) -> None:
        index = len(self._trace_meta) if index is None else int(index)
        for name, table in _tables_of(trace, index).items():
            self._pending[name].append(table)
        self._trace_meta.append({"trace": index, **jsonable(trace.meta)})
        if trace.imu is not None:
            self._frames.update(trace.imu.frames)
        self._attitude = self._attitude or trace.truth.has_attitude
        if len(self._pending["truth"]) >= self._row_group_traces:
            self._flush()

    def _flush(self) -> None:
        for name, parts in self._pending.items():
            if parts:
                self._writers[name].write_table(pa.concat_tables(parts))
            self._pending[name] = []

    def close(self) -> Path:
        if self._closed:
            return self.path
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
        }
        (self.tmp / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
        if self.path.exists():
            os.replace(self.path, old)
        os.replace(self.tmp, self.path)
        if old.exists():
            shutil.rmtree(old)
        self._closed = True
        return self.path

    def abort(self) -> None:
        for w in self._writers.values():
            try:
                w.close()
            except Exception:  # noqa: BLE001 - best effort clean-up of a failed write
                pass
        shutil.rmtree(self.tmp, ignore_errors=True)
        self._closed = True

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_dataset(path: str | os.PathLike, traces: Iterable[Trace], *, meta: dict[str, Any] | None = None,
                  overwrite: bool = False) -> Path:
    """Write traces as a dataset directory, atomically. Returns the path."""
    with DatasetWriter(path, meta=meta, overwrite=overwrite) as w:
        for trace in traces:
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
    return meta


def _read_table(path: Path, name: str) -> dict[str, np.ndarray]:
    f = path / f"{name}.parquet"
    if not f.is_file():
        raise DatasetError(f"dataset {path} is incomplete: {name}.parquet is missing")
    try:
        table = pq.read_table(f)
    except (OSError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read {f}: {str(exc).splitlines()[0]}") from None
    optional = {c for group in OPTIONAL_COLUMNS.get(name, {}).values() for c in group}
    if name == "imu" and not any(c in table.column_names for c in optional):
        raise DatasetError(f"{f}: no acceleration or angular-rate column")
    missing = [c for c in SCHEMAS[name].names if c not in table.column_names and c not in optional]
    if missing:
        raise DatasetError(f"{f}: missing column(s) {', '.join(missing)}")
    cols = {}
    for c in SCHEMAS[name].names:
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
            cols[c] = col.to_numpy()
    return cols


def _split(cols: dict[str, np.ndarray]) -> dict[int, dict[str, np.ndarray]]:
    trace = cols["trace"]
    if trace.size == 0:
        return {}
    order = np.argsort(trace, kind="stable")
    keys, starts = np.unique(trace[order], return_index=True)
    ends = np.append(starts[1:], trace.size)
    return {int(k): {c: v[order[s:e]] for c, v in cols.items()} for k, s, e in zip(keys, starts, ends, strict=True)}


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Read a dataset directory back into Trace records (same values as written)."""
    path = Path(path)
    meta = read_meta(path)
    parts = {name: _split(_read_table(path, name)) for name in TABLES}
    trace_meta = {int(m["trace"]): m for m in meta.get("traces", [])}
    traces = []
    for idx in sorted(parts["truth"]):
        tr, an = parts["truth"][idx], parts["anchors"].get(idx)
        if an is None:  # an IMU-only recording (e.g. BROAD) has no anchors
            anchors = Anchors(ids=(), pos_enu_m=np.zeros((0, 3)))
        else:
            anchors = Anchors(ids=tuple(an["anchor_id"]), names=tuple(an["name"]),
                              pos_enu_m=np.stack([an[f"pos_{c}_m"] for c in "enu"], axis=1))
        truth = Truth(t_s=tr["t_s"], pos_enu_m=np.stack([tr[f"pos_{c}_m"] for c in "enu"], axis=1),
                      vel_enu_mps=np.stack([tr[f"vel_{c}_mps"] for c in "enu"], axis=1),
                      quat_wxyz=_optional_group(tr, "truth", "quat_wxyz"),
                      omega_body_radps=_optional_group(tr, "truth", "omega_body_radps"))
        im = parts["imu"].get(idx)
        imu = None
        if im is not None:
            groups = {a: _optional_group(im, "imu", a) for a in OPTIONAL_COLUMNS["imu"]}
            if all(g is None for g in groups.values()):
                raise DatasetError(f"dataset {path}: trace {idx} has IMU rows without any value")
            imu = Imu(t_s=im["t_s"], frame=meta.get("imu_frame", IMU_FRAME), **groups)
        uw = parts["uwb"].get(idx)
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
        m = {k: v for k, v in trace_meta.get(idx, {}).items() if k != "trace"}
        traces.append(Trace(truth=truth, uwb=uwb, anchors=anchors, imu=imu, meta=m))
    if not traces:
        raise DatasetError(f"dataset {path} holds no traces")
    return Dataset(meta=meta, traces=traces)
