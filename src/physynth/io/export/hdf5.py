"""HDF5 export (h5py): one group per trace.

Layout of the file::

    /                     attrs: dataset_json (the dataset's dataset.json, without the per-trace list)
    /traces/<index>/      attrs: every per-trace metadata entry (JSON-encoded when not a number/string)
        truth/t_s (T,) pos_enu_m (T, 3) vel_enu_mps (T, 3)
        imu/t_s (N,) acc_mps2 (N, 3)            (absent when the trace has no IMU)
        uwb/t_s anchor range_m true_range_m nlos burst reason (M,)   anchor indexes anchors/ids
            attrs: nlos_known (bool)
        anchors/ids (A,) names (A,) pos_enu_m (A, 3)

Unknown NLOS (an imported recording's) is written as ``nlos = False`` (HDF5 has no missing boolean): only
the ``uwb`` group attribute ``nlos_known = False`` says the column is no label; read it before ``nlos``.

Groups are named by the zero-padded trace index (``00000042``) so they sort in trace order. Units as in
the dataset: seconds, metres, metres per second (squared), ENU world frame. Numeric arrays keep the
values and precision of the dataset (float32 where the dataset stores float32).

The file is written part by part (:mod:`.parts`): :func:`create` with the first part's traces, then
:func:`append` with each next part's, in place, through h5py's file-object driver and an undo journal
(:mod:`physynth.io.undo`), so a part stopped half way is rolled back instead of the whole file being
rewritten: nothing is copied.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ...constants import IMU_BODY_FRAME, IMU_FRAME
from ...errors import DatasetError
from ..dataset import StoredTrace
from ..tables import OPTIONAL_COLUMNS, optional_group


def _attr(value: Any) -> Any:
    return value if isinstance(value, (int, float, str, bool)) else json.dumps(value)


def _vectors(cols: dict[str, np.ndarray], names: Iterable[str], dtype: Any) -> np.ndarray:
    return np.stack([cols[c] for c in names], axis=1).astype(dtype, copy=False)


def _uwb_columns(st: StoredTrace, path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """The UWB group's arrays in the types of the trace records (:class:`~physynth.records.Uwb`)."""
    uw = st.uwb
    if uw is None:
        empty = {"t_s": np.float64, "anchor": np.int16, "range_m": np.float64, "true_range_m": np.float64,
                 "nlos": np.bool_, "burst": np.int64, "reason": np.int8}
        return {k: np.zeros(0, dtype=d) for k, d in empty.items()}, False
    out = {"t_s": uw["t_s"].astype(np.float64, copy=False), "anchor": st.uwb_anchor(path),
           "range_m": uw["range_m"].astype(np.float64, copy=False),
           "true_range_m": uw["true_range_m"].astype(np.float64, copy=False),
           "nlos": uw["nlos"].astype(np.bool_, copy=False), "burst": uw["burst"].astype(np.int64, copy=False),
           "reason": uw["reason"].astype(np.int8, copy=False)}
    return out, bool(uw["nlos_known"].all()) if len(uw["nlos_known"]) else False


class _Objects:
    """Groups, attributes and datasets written through h5py's low-level API, as its high-level calls write
    them (``group.create_group(name)``, ``group.attrs[name] = value``, ``group[name] = array``: a contiguous
    dataset without time stamps or attribute order, created anonymous and then linked), with property lists
    and types made once instead of per object: h5py's high-level path took most of the export's time (about
    0.1 ms per object, some 40 objects per trace)."""

    def __init__(self) -> None:
        import h5py
        from h5py import h5p, h5t

        self.dcpl = h5p.create(h5p.DATASET_CREATE)
        self.dcpl.set_obj_track_times(False)
        self.dcpl.set_attr_creation_order(0)
        self.lcpl = h5p.create(h5p.LINK_CREATE)  # an ASCII name, intermediate groups allowed (h5py's own)
        self.lcpl.set_create_intermediate_group(True)
        self.lcpl.set_char_encoding(h5t.CSET_ASCII)
        self.str_dtype = h5py.string_dtype("utf-8")  # variable-length UTF-8, as h5py stores a str
        self._types: dict[Any, tuple[Any, Any]] = {}

    def _type(self, dtype: np.dtype) -> tuple[Any, Any]:
        """HDF5 types of ``dtype``: as stored (logical) and as in memory."""
        from h5py import h5t

        key = "str" if dtype.metadata and dtype.metadata.get("vlen") is str else dtype
        found = self._types.get(key)
        if found is None:
            found = self._types[key] = (h5t.py_create(dtype, logical=True), h5t.py_create(dtype))
        return found

    def group(self, parent: Any, path: str) -> Any:
        from h5py import h5g

        return h5g.create(parent, path.encode("ascii"), lcpl=self.lcpl)

    def attr(self, obj: Any, name: str, value: Any) -> None:
        from h5py import h5a, h5s

        arr = np.array(value, dtype=self.str_dtype) if isinstance(value, str) else np.asarray(value)
        stored, memory = self._type(arr.dtype)
        h5a.create(obj, name.encode("utf-8"), stored, h5s.create_simple(arr.shape)).write(arr, mtype=memory)

    def put(self, group: Any, name: str, values: np.ndarray | list[str]) -> None:
        from h5py import h5d, h5o, h5s

        arr = (np.array(values, dtype=self.str_dtype) if isinstance(values, list)
               else np.ascontiguousarray(values))
        stored, _ = self._type(arr.dtype)
        dsid = h5d.create(group, None, stored, h5s.create_simple(arr.shape), dcpl=self.dcpl)
        if arr.size:
            dsid.write(h5s.ALL, h5s.ALL, arr)
        h5o.link(dsid, group, name.encode("ascii"), lcpl=self.lcpl)


Group = tuple[str, list[tuple[str, Any]], list[tuple[str, Any]]]
"""One group of a trace: its path below ``/traces``, its attributes and its datasets in the order written
(a dataset's value is a numeric array, or a list of strings for a variable-length UTF-8 one)."""


def trace_groups(st: StoredTrace, meta: dict[str, Any], dataset: Path) -> list[Group]:
    """What :func:`append` writes of the stored trace ``st`` of ``dataset`` (whose ``dataset.json`` is
    ``meta``): each array in the type the dataset's reader gives it (float64), or float32 where the dataset
    stores float32 (velocities, attitude, IMU samples of generated datasets), copied as stored."""
    f32 = set(meta.get("float32_columns", []))
    acc_dtype = np.float32 if "acc_e_mps2" in f32 else np.float64
    vel_dtype = np.float32 if "vel_e_mps" in f32 else np.float64
    att_dtype = np.float32 if "quat_w" in f32 else np.float64
    name = f"{st.index:08d}"
    groups: list[Group] = [(name, [("trace", st.index), *((k, _attr(v)) for k, v in st.meta.items())], [])]
    tr = st.truth
    truth = [("t_s", tr["t_s"].astype(np.float64, copy=False)),
             ("pos_enu_m", _vectors(tr, ("pos_e_m", "pos_n_m", "pos_u_m"), np.float64)),
             ("vel_enu_mps", _vectors(tr, ("vel_e_mps", "vel_n_mps", "vel_u_mps"), vel_dtype))]
    for attitude in ("quat_wxyz", "omega_body_radps"):  # the truth attitude, when the trace has one
        arr = optional_group(tr, "truth", attitude, att_dtype)
        if arr is not None:
            truth.append((attitude, arr))
    groups.append((f"{name}/truth", [], truth))
    if st.imu is not None:
        sensors = {a: optional_group(st.imu, "imu", a, acc_dtype) for a in OPTIONAL_COLUMNS["imu"]}
        if all(v is None for v in sensors.values()):
            raise DatasetError(f"dataset {dataset}: trace {st.index} has IMU rows without any value")
        frame = meta.get("imu_frame", IMU_FRAME)
        frames = ((frame,) if sensors["acc_mps2"] is not None else ()) + (
            (IMU_BODY_FRAME,) if sensors["acc_body_mps2"] is not None or sensors["gyro_body_radps"] is not None
            else ())
        imu = [("t_s", st.imu["t_s"].astype(np.float64, copy=False))]
        imu += [(s, sensors[s]) for s in ("acc_mps2", "acc_body_mps2", "gyro_body_radps")  # ENU and/or body
                if sensors[s] is not None]
        groups.append((f"{name}/imu", [("frame", frame), ("frames", json.dumps(list(frames)))], imu))
    cols, nlos_known = _uwb_columns(st, dataset)
    groups.append((f"{name}/uwb", [("nlos_known", nlos_known)], list(cols.items())))
    ids = st.anchor_ids()
    an = st.anchors
    groups.append((f"{name}/anchors", [], [
        ("ids", list(ids)), ("names", list(an["name"]) if an is not None and ids else list(ids)),
        ("pos_enu_m", _vectors(an, ("pos_e_m", "pos_n_m", "pos_u_m"), np.float64) if an is not None
         else np.zeros((0, 3)))]))
    return groups


def _write(f: Any, traces: Iterable[list[Group]]) -> None:
    objects = _Objects()
    root = f["traces"].id
    for groups in traces:
        for path, attrs, datasets in groups:
            g = objects.group(root, path)
            for k, v in attrs:
                objects.attr(g, k, v)
            for name, value in datasets:
                objects.put(g, name, value)


def create(path: Path, meta: dict[str, Any], traces: Iterable[list[Group]]) -> None:
    """Write the HDF5 file ``path`` (new) with the root attributes of the dataset whose ``dataset.json`` is
    ``meta`` and the groups of ``traces`` (:func:`trace_groups`), through h5py's file-object driver, as
    :func:`append` adds to it."""
    import h5py

    with io.FileIO(path, "x+b") as fo, h5py.File(fo, "w") as f:
        f.attrs["dataset_json"] = json.dumps({k: v for k, v in meta.items() if k != "traces"})
        f.attrs["format"] = "physynth-hdf5/1"
        f.create_group("traces")
        _write(f, traces)


def append(path: Path, traces: Iterable[list[Group]], journal: Path) -> None:
    """Add the groups of ``traces`` to the HDF5 file ``path`` written by :func:`create`, the bytes it
    overwrites saved to ``journal`` (a new file) first (:class:`~physynth.io.undo.UndoFile`); an exception
    (an interrupt included) restores the file as it was. Remove the journal once the file is kept; after a
    kill, :func:`~physynth.io.undo.roll_back` restores it. The file's bytes depend only on what each call
    of :func:`create` and :func:`append` wrote, in order, not on the process or the time of the call."""
    import h5py

    from ..undo import UndoFile, roll_back

    fo = UndoFile(path, journal)
    try:
        with fo, h5py.File(fo, "a") as f:
            _write(f, traces)
    except BaseException:
        roll_back(path, journal)
        raise
