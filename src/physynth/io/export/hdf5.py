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

from ...records import Trace


def _attr(value: Any) -> Any:
    return value if isinstance(value, (int, float, str, bool)) else json.dumps(value)


def write_hdf5(traces: Iterable[tuple[int, Trace]], meta: dict[str, Any], path: Path) -> None:
    """Write ``(index, trace)`` pairs to the HDF5 file ``path``."""
    import h5py

    f32 = set(meta.get("float32_columns", []))
    acc_dtype = np.float32 if "acc_e_mps2" in f32 else np.float64
    vel_dtype = np.float32 if "vel_e_mps" in f32 else np.float64
    str_dtype = h5py.string_dtype("utf-8")
    with h5py.File(path, "w") as f:
        f.attrs["dataset_json"] = json.dumps({k: v for k, v in meta.items() if k != "traces"})
        f.attrs["format"] = "physynth-hdf5/1"
        root = f.create_group("traces")
        for idx, trace in traces:
            g = root.create_group(f"{idx:08d}")
            g.attrs["trace"] = idx
            for k, v in trace.meta.items():
                g.attrs[k] = _attr(v)
            t = g.create_group("truth")
            t["t_s"] = trace.truth.t_s
            t["pos_enu_m"] = trace.truth.pos_enu_m
            t["vel_enu_mps"] = trace.truth.vel_enu_mps.astype(vel_dtype, copy=False)
            for name in ("quat_wxyz", "omega_body_radps"):  # the truth attitude, when the trace has one
                if getattr(trace.truth, name) is not None:
                    t[name] = getattr(trace.truth, name).astype(np.float32 if "quat_w" in f32 else np.float64, copy=False)
            if trace.imu is not None:
                i = g.create_group("imu")
                i["t_s"] = trace.imu.t_s
                i.attrs["frame"] = trace.imu.frame
                i.attrs["frames"] = json.dumps(list(trace.imu.frames))
                for name in ("acc_mps2", "acc_body_mps2", "gyro_body_radps"):  # ENU and/or body-frame sensors
                    if getattr(trace.imu, name) is not None:
                        i[name] = getattr(trace.imu, name).astype(acc_dtype, copy=False)
            u = g.create_group("uwb")
            for name in ("t_s", "anchor", "range_m", "true_range_m", "nlos", "burst", "reason"):
                u[name] = getattr(trace.uwb, name)
            u.attrs["nlos_known"] = bool(trace.uwb.nlos_known)
            a = g.create_group("anchors")
            a.create_dataset("ids", data=list(trace.anchors.ids), dtype=str_dtype)
            a.create_dataset("names", data=list(trace.anchors.names), dtype=str_dtype)
            a["pos_enu_m"] = trace.anchors.pos_enu_m
