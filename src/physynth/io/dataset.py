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
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .. import __version__
from .._json import jsonable
from ..constants import IMU_FRAME, SCHEMA_VERSION
from ..errors import DatasetError
from ..records import Anchors, Imu, Trace, Truth, Uwb
from . import integrity, safety
from .atomic import temp_sibling

TABLES = ("truth", "imu", "uwb", "anchors")

SCHEMAS = {
    "truth": pa.schema([("trace", pa.int32()), ("t_s", pa.float64())]
                       + [(f"pos_{c}_m", pa.float64()) for c in "enu"]
                       + [(f"vel_{c}_mps", pa.float64()) for c in "enu"]),
    "imu": pa.schema([("trace", pa.int32()), ("t_s", pa.float64())]
                     + [(f"acc_{c}_mps2", pa.float64()) for c in "enu"]),
    "uwb": pa.schema([("trace", pa.int32()), ("t_s", pa.float64()), ("anchor_id", pa.string()),
                      ("range_m", pa.float64()), ("true_range_m", pa.float64()), ("nlos", pa.bool_()),
                      ("burst", pa.int64()), ("reason", pa.int8())]),
    "anchors": pa.schema([("trace", pa.int32()), ("anchor_id", pa.string()), ("name", pa.string())]
                         + [(f"pos_{c}_m", pa.float64()) for c in "enu"]),
}

UNITS = {
    "t_s": "s", "pos_*_m": "m (ENU)", "vel_*_mps": "m/s (ENU)", "acc_*_mps2": "m/s^2",
    "range_m": "m", "true_range_m": "m",
}
FRAMES = {
    "world": "ENU (east, north, up), metres, origin as in the anchors table",
    "imu": f"{IMU_FRAME}: acceleration in the world ENU frame with gravity removed",
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
    out = {"truth": pa.Table.from_pydict(cols, schema=SCHEMAS["truth"])}

    if trace.imu is not None:
        im = trace.imu
        cols = {"trace": np.full(im.t_s.shape[0], index, np.int32), "t_s": im.t_s}
        for k, c in enumerate("enu"):
            cols[f"acc_{c}_mps2"] = im.acc_mps2[:, k]
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


class DatasetWriter:
    """Streams traces into a new dataset directory; the directory appears only on :meth:`close`.

    >>> with DatasetWriter(out, meta={"kind": "synthetic"}) as w:   # doctest: +SKIP
    ...     for trace in traces:
    ...         w.add(trace)
    """

    def __init__(self, path: str | os.PathLike, *, meta: dict[str, Any] | None = None,
                 overwrite: bool = False, row_group_traces: int = 64,
                 inputs: Sequence[str | os.PathLike] = ()) -> None:
        # safety hook (physynth.io.safety): what --overwrite may replace, inputs, lock, orphaned temp folders
        self.path, self._lock = safety.prepare_output(path, kind="dataset", overwrite=overwrite, inputs=inputs)
        self.overwrite = overwrite
        self.meta = dict(meta or {})
        self.tmp = temp_sibling(self.path)
        try:
            safety.remove_tree(self.tmp)
            self.tmp.mkdir(parents=True)
        except OSError as exc:
            self._lock.release()
            raise DatasetError(f"cannot create {self.path}: {exc.strerror}") from None
        except BaseException:
            self._lock.release()
            raise
        self._rows = {name: 0 for name in TABLES}
        self._writers = {
            name: pq.ParquetWriter(self.tmp / f"{name}.parquet", SCHEMAS[name], compression="snappy",
                                   use_dictionary=["anchor_id", "name"], write_statistics=["trace"])
            for name in TABLES
        }
        self._pending: dict[str, list[pa.Table]] = {name: [] for name in TABLES}
        self._row_group_traces = row_group_traces
        self._trace_meta: list[dict[str, Any]] = []
        self._closed = False

    def add(self, trace: Trace, index: int | None = None) -> None:
        index = len(self._trace_meta) if index is None else int(index)
        for name, table in _tables_of(trace, index).items():
            self._pending[name].append(table)
        self._trace_meta.append({"trace": index, **jsonable(trace.meta)})
        if len(self._pending["truth"]) >= self._row_group_traces:
            self._flush()

    def _flush(self) -> None:
        for name, parts in self._pending.items():
            if parts:
                table = pa.concat_tables(parts)
                self._writers[name].write_table(table)
                self._rows[name] += table.num_rows
            self._pending[name] = []

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
            "n_traces": len(self._trace_meta),
            "traces": self._trace_meta,
            # integrity hook (physynth.io.integrity): row counts and SHA-256 of every table
            "files": integrity.file_records(self.tmp, {f"{name}.parquet": n for name, n in self._rows.items()}),
        }
        (self.tmp / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
        if os.path.lexists(self.path):
            os.replace(self.path, old)
        os.replace(self.tmp, self.path)
        self._closed = True
        safety.remove_tree(old)
        self._lock.release()
        return self.path

    def abort(self) -> None:
        for w in self._writers.values():
            try:
                w.close()
            except Exception:  # noqa: BLE001 - best effort clean-up of a failed write
                pass
        shutil.rmtree(self.tmp, ignore_errors=True)
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

    ``inputs`` are the files or folders the traces were read from: the output may not be or hold one.
    """
    with DatasetWriter(path, meta=meta, overwrite=overwrite, inputs=inputs) as w:
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
    missing = [c for c in SCHEMAS[name].names if c not in table.column_names]
    if missing:
        raise DatasetError(f"{f}: missing column(s) {', '.join(missing)}")
    cols = {}
    for c in SCHEMAS[name].names:
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
    # integrity hook (physynth.io.integrity): sizes, row counts, hashes and trace ids against dataset.json
    integrity.check_dataset(path, meta, hashes=not integrity.environ_skip_hashes())
    parts = {name: _split(_read_table(path, name)) for name in TABLES}
    try:
        trace_meta = {int(m["trace"]): m for m in meta.get("traces", [])}
    except (TypeError, KeyError, ValueError):
        raise DatasetError(f"dataset {path}: dataset.json 'traces' entries have no valid 'trace' id") from None
    traces = []
    for idx in sorted(parts["truth"]):
        try:
            traces.append(_trace_of(path, meta, parts, trace_meta, idx))
        except ValueError as exc:  # tables that read but do not make valid records (unsorted times, ...)
            raise DatasetError(f"dataset {path}: trace {idx} is invalid: {str(exc).splitlines()[0]}") from None
    if not traces:
        raise DatasetError(f"dataset {path} holds no traces")
    return Dataset(meta=meta, traces=traces)


def _trace_of(path: Path, meta: dict[str, Any], parts: dict[str, dict[int, dict[str, np.ndarray]]],
              trace_meta: dict[int, dict[str, Any]], idx: int) -> Trace:
    tr, an = parts["truth"][idx], parts["anchors"].get(idx)
    if an is None:  # an IMU-only recording (e.g. BROAD) has no anchors
        anchors = Anchors(ids=(), pos_enu_m=np.zeros((0, 3)))
    else:
        anchors = Anchors(ids=tuple(an["anchor_id"]), names=tuple(an["name"]),
                          pos_enu_m=np.stack([an[f"pos_{c}_m"] for c in "enu"], axis=1))
    truth = Truth(t_s=tr["t_s"], pos_enu_m=np.stack([tr[f"pos_{c}_m"] for c in "enu"], axis=1),
                  vel_enu_mps=np.stack([tr[f"vel_{c}_mps"] for c in "enu"], axis=1))
    im = parts["imu"].get(idx)
    imu = (Imu(t_s=im["t_s"], acc_mps2=np.stack([im[f"acc_{c}_mps2"] for c in "enu"], axis=1),
               frame=meta.get("imu_frame", IMU_FRAME)) if im is not None else None)
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
    return Trace(truth=truth, uwb=uwb, anchors=anchors, imu=imu, meta=m)
