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
"""

from __future__ import annotations

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


class _Arrays:
    """Numeric datasets written through h5py's low-level API: what ``group[name] = array`` does (a
    contiguous dataset without time stamps or attribute order, created anonymous and then linked), with
    its property lists made once instead of per dataset (h5py's high-level path took most of the export's
    time per trace: 17 datasets per trace, about 0.1 ms each)."""

    def __init__(self) -> None:
        from h5py import h5p, h5t

        self.dcpl = h5p.create(h5p.DATASET_CREATE)
        self.dcpl.set_obj_track_times(False)
        self.dcpl.set_attr_creation_order(0)
        self.lcpl = h5p.create(h5p.LINK_CREATE)  # an ASCII name, intermediate groups allowed (h5py's own)
        self.lcpl.set_create_intermediate_group(True)
        self.lcpl.set_char_encoding(h5t.CSET_ASCII)
        self._types: dict[np.dtype, Any] = {}

    def put(self, group: Any, name: str, values: np.ndarray) -> None:
        from h5py import h5d, h5o, h5s, h5t

        arr = np.ascontiguousarray(values)
        tid = self._types.get(arr.dtype)
        if tid is None:
            tid = self._types[arr.dtype] = h5t.py_create(arr.dtype, logical=True)
        dsid = h5d.create(group.id, None, tid, h5s.create_simple(arr.shape), dcpl=self.dcpl)
        if arr.size:
            dsid.write(h5s.ALL, h5s.ALL, arr)
        h5o.link(dsid, group.id, name.encode("ascii"), lcpl=self.lcpl)


def write_hdf5(traces: Iterable[StoredTrace], meta: dict[str, Any], path: Path, dataset: Path) -> None:
    """Write the stored traces of ``dataset`` (:func:`~physynth.io.dataset.iter_stored_traces`) to the HDF5
    file ``path``: each array in the type the dataset's reader gives it (float64), or float32 where the
    dataset stores float32 (velocities, attitude, IMU samples of generated datasets), copied as stored."""
    import h5py

    f32 = set(meta.get("float32_columns", []))
    acc_dtype = np.float32 if "acc_e_mps2" in f32 else np.float64
    vel_dtype = np.float32 if "vel_e_mps" in f32 else np.float64
    att_dtype = np.float32 if "quat_w" in f32 else np.float64
    str_dtype = h5py.string_dtype("utf-8")
    arrays = _Arrays()
    put = arrays.put
    with h5py.File(path, "w") as f:
        f.attrs["dataset_json"] = json.dumps({k: v for k, v in meta.items() if k != "traces"})
        f.attrs["format"] = "physynth-hdf5/1"
        root = f.create_group("traces")
        for st in traces:
            g = root.create_group(f"{st.index:08d}")
            g.attrs["trace"] = st.index
            for k, v in st.meta.items():
                g.attrs[k] = _attr(v)
            tr = st.truth
            t = g.create_group("truth")
            put(t, "t_s", tr["t_s"].astype(np.float64, copy=False))
            put(t, "pos_enu_m", _vectors(tr, ("pos_e_m", "pos_n_m", "pos_u_m"), np.float64))
            put(t, "vel_enu_mps", _vectors(tr, ("vel_e_mps", "vel_n_mps", "vel_u_mps"), vel_dtype))
            for name in ("quat_wxyz", "omega_body_radps"):  # the truth attitude, when the trace has one
                arr = optional_group(tr, "truth", name, att_dtype)
                if arr is not None:
                    put(t, name, arr)
            if st.imu is not None:
                groups = {a: optional_group(st.imu, "imu", a, acc_dtype) for a in OPTIONAL_COLUMNS["imu"]}
                if all(v is None for v in groups.values()):
                    raise DatasetError(f"dataset {dataset}: trace {st.index} has IMU rows without any value")
                frame = meta.get("imu_frame", IMU_FRAME)
                frames = ((frame,) if groups["acc_mps2"] is not None else ()) + (
                    (IMU_BODY_FRAME,) if groups["acc_body_mps2"] is not None or groups["gyro_body_radps"] is not None
                    else ())
                i = g.create_group("imu")
                put(i, "t_s", st.imu["t_s"].astype(np.float64, copy=False))
                i.attrs["frame"] = frame
                i.attrs["frames"] = json.dumps(list(frames))
                for name in ("acc_mps2", "acc_body_mps2", "gyro_body_radps"):  # ENU and/or body-frame sensors
                    if groups[name] is not None:
                        put(i, name, groups[name])
            u = g.create_group("uwb")
            cols, nlos_known = _uwb_columns(st, dataset)
            for name, arr in cols.items():
                put(u, name, arr)
            u.attrs["nlos_known"] = nlos_known
            a = g.create_group("anchors")
            ids = st.anchor_ids()
            a.create_dataset("ids", data=list(ids), dtype=str_dtype)
            an = st.anchors
            a.create_dataset("names", data=list(an["name"]) if an is not None and ids else list(ids), dtype=str_dtype)
            put(a, "pos_enu_m", _vectors(an, ("pos_e_m", "pos_n_m", "pos_u_m"), np.float64) if an is not None
                else np.zeros((0, 3)))
