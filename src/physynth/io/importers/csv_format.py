"""The generic recording format: a folder of CSV (or Parquet) tables users write from their own logs.

See ``docs/recording-format.md`` for the columns, units, frames and time base. In short::

    rec_dir/
      anchors.csv   anchor_id, e_m, n_m, u_m [, name]
      uwb.csv       t_s, anchor_id, range_m [, burst]
      truth.csv     t_s, e_m, n_m, u_m [, ve_mps, vn_mps, vu_mps]
      imu.csv       t_s, acc_e_mps2, acc_n_mps2, acc_u_mps2     (optional; ENU, gravity removed)
      meta.json     any JSON object                               (optional)

Each ``.csv`` may instead be a ``.parquet`` of the same name and columns.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...errors import RecordingError
from ...models.attitude import body_rates_from_quat
from ...records import Anchors, Imu, Trace, Truth, Uwb
from ..dataset import is_csv_export
from ._common import (
    MAX_PLAUSIBLE_ACC_MEDIAN_MPS2,
    ImportReport,
    ReportBuilder,
    auto_burst_gap_s,
    check_gyro_radps,
    check_range_metres,
    check_range_scale,
    check_seconds,
    check_specific_force,
    check_time_spans,
    check_time_steps,
    check_unit_quaternions,
    checked_window_and_gap,
    drop_nan_rows,
    find_table,
    flag_implausible_ranges,
    flag_ranges,
    gap_bursts,
    integer_column,
    read_table,
    require_columns,
    sort_and_dedupe,
    to_float,
    velocity_from_position,
)

ENU = ("e", "n", "u")
MAX_GRAVITY_LEFT_MPS2 = 5.0
"""A mean vertical acceleration above this over a whole recording means gravity was not removed."""


def _refuse_dataset(rec: Path) -> None:
    """A PhySynth dataset, or the CSV export of one, is no recording (it has no recording's tables)."""
    if (rec / "dataset.json").is_file():
        raise RecordingError(f"{rec} is a PhySynth dataset{' (a CSV export)' if is_csv_export(rec) else ''}, not a "
                             "recording: the other commands read a dataset as it is; import csv reads the "
                             "tables of docs/recording-format.md")


def import_csv(rec_dir: str | os.PathLike, *, velocity_window_s: float = 0.5,
               burst_gap_s: float | None = None) -> tuple[Trace, ImportReport]:
    """Import a recording in the generic PhySynth format (docs/recording-format.md).

    Parameters
    ----------
    rec_dir
        Folder holding ``anchors``, ``uwb``, ``truth`` and optionally ``imu`` tables and ``meta.json``.
    velocity_window_s
        Smoothing window [s] of the Savitzky-Golay differentiation used when ``truth`` has no
        velocity columns.
    burst_gap_s
        A new UWB burst starts after a gap longer than this [s] (used when ``uwb`` has no ``burst``
        column). Default: half the median interval between consecutive ranges of the same anchor.

    Returns
    -------
    (Trace, ImportReport)
        Times are shifted so that the first kept truth sample is t = 0; the original time of that
        sample is ``trace.meta["time_origin_s"]``.

    Raises
    ------
    RecordingError
        One line naming the file and the problem (missing file or column, unit mistake, anchor
        without coordinates, UWB rows of an unknown anchor, tables that do not overlap in time).
    ArgumentError
        ``velocity_window_s`` or ``burst_gap_s`` is not a positive finite number.
    """
    velocity_window_s, burst_gap_s = checked_window_and_gap(velocity_window_s, burst_gap_s)
    rec = Path(rec_dir)
    if not rec.exists():
        raise RecordingError(f"recording folder {rec} does not exist")
    if not rec.is_dir():
        raise RecordingError(f"{rec} is not a folder (a recording is a folder of CSV/Parquet tables)")
    _refuse_dataset(rec)
    rep = ReportBuilder("csv", rec)

    anchors = _read_anchors(find_table(rec, "anchors", required=True), rep)
    truth_path = find_table(rec, "truth", required=True)
    t_truth, pos, vel, quat, omega = _read_truth(truth_path, rep)
    uwb_path = find_table(rec, "uwb", required=True)
    t_uwb, anchor, range_m, burst = _read_uwb(uwb_path, anchors, rep)
    imu_path = find_table(rec, "imu", required=False)
    imu_tab = _read_imu(imu_path, rep) if imu_path is not None else None
    user_meta = _read_meta(rec / "meta.json")

    t0 = float(t_truth[0])
    t_truth = t_truth - t0
    t_uwb = t_uwb - t0
    check_time_spans(uwb_path, t_uwb, truth_path, t_truth)
    _check_overlap(uwb_path, t_uwb, truth_path, t_truth)
    check_range_scale(uwb_path, t_uwb, anchor, range_m, t_truth, pos, anchors.pos_enu_m)
    range_m = flag_implausible_ranges(range_m, anchor, pos, anchors.pos_enu_m, uwb_path.name, rep)
    meta: dict[str, Any] = {
        "source": "csv",
        "recording": rec.name,
        "path": str(rec.resolve()),
        "time_origin_s": t0,
        "time_base": "t_s of the input tables minus time_origin_s (first kept truth sample at t = 0)",
        "frame": "ENU [m] as given in the recording",
    }
    if vel is None:
        vel = velocity_from_position(t_truth, pos, window_s=velocity_window_s)
        meta["truth_velocity"] = (f"Savitzky-Golay derivative of position (window {velocity_window_s} s, "
                                  "order 2)")
    else:
        meta["truth_velocity"] = "given in truth table"
    if burst is None:
        gap = burst_gap_s if burst_gap_s is not None else auto_burst_gap_s(t_uwb, anchor)
        burst = gap_bursts(t_uwb, gap)
        meta["uwb_burst"] = f"gap-based grouping, new burst after a gap > {gap:.4g} s"
    else:
        meta["uwb_burst"] = "given in uwb table"

    imu = None
    if imu_tab is not None:
        t_imu, acc, acc_body, gyro = imu_tab
        t_imu = t_imu - t0
        check_time_spans(imu_path, t_imu, truth_path, t_truth)
        _check_overlap(imu_path, t_imu, truth_path, t_truth)
        imu = Imu(t_s=t_imu, acc_mps2=acc, acc_body_mps2=acc_body, gyro_body_radps=gyro)
        meta["imu_processing"] = "as given (recording format): " + ", ".join(imu.frames)
    n_out = int(np.count_nonzero((t_uwb < t_truth[0]) | (t_uwb > t_truth[-1])))
    if n_out:
        rep.note(f"{n_out} UWB row(s) lie outside the truth time span (kept; no residual for them)")
    if user_meta is not None:
        meta["recording_meta"] = user_meta

    trace = Trace(
        truth=Truth(t_s=t_truth, pos_enu_m=pos, vel_enu_mps=vel, quat_wxyz=quat, omega_body_radps=omega),
        uwb=Uwb(t_s=t_uwb, anchor=anchor, range_m=range_m, burst=burst),
        anchors=anchors,
        imu=imu,
        meta=meta,
    )
    return trace, rep.build()


def _read_anchors(path: Path, rep: ReportBuilder) -> Anchors:
    df = read_table(path, rep, str_columns=("anchor_id", "name"))
    cols = [f"{c}_m" for c in ENU]
    require_columns(df, path, ["anchor_id", *cols])
    df = to_float(df, cols)
    ids = df["anchor_id"].astype("string").str.strip()
    if ids.isna().any() or (ids == "").any():
        raise RecordingError(f"{path}: {int((ids.isna() | (ids == '')).sum())} row(s) without anchor_id")
    df = df.assign(anchor_id=ids.astype(str))
    no_xyz = df[cols].isna().any(axis=1)
    if no_xyz.any():
        bad = ", ".join(df.loc[no_xyz, "anchor_id"].astype(str).unique()[:5])
        raise RecordingError(f"{path}: anchor(s) {bad} have no coordinates "
                             "(e_m, n_m, u_m empty or not a number)")
    exact = df.duplicated(subset=["anchor_id", *cols], keep="first")
    rep.drop(path.name, "duplicate_row", int(exact.sum()))
    df = df.loc[~exact]
    dup = df["anchor_id"].duplicated(keep=False)
    if dup.any():
        raise RecordingError(f"{path}: anchor id {df.loc[dup, 'anchor_id'].iloc[0]} appears more than once "
                             "with different coordinates")
    if df.empty:
        raise RecordingError(f"{path}: no anchors")
    names: tuple[str, ...] = ()
    if "name" in df.columns:
        nm = df["name"].astype("string").fillna("").str.strip()
        names = tuple(np.where(nm == "", df["anchor_id"], nm).tolist())
    rep.kept(path.name, len(df))
    return Anchors(ids=tuple(df["anchor_id"].tolist()), names=names, pos_enu_m=df[cols].to_numpy())


QUAT_COLS = [f"quat_{c}" for c in "wxyz"]
OMEGA_COLS = [f"omega_{c}_radps" for c in "xyz"]
BODY_ACC_COLS = [f"acc_{c}_mps2" for c in "xyz"]
GYRO_COLS = [f"gyro_{c}_radps" for c in "xyz"]


def _group(df: pd.DataFrame, path: Path, cols: list[str], what: str) -> bool:
    """Whether an all-or-none column group is present (an incomplete one is an error)."""
    has = [c in df.columns for c in cols]
    if any(has) and not all(has):
        missing = [c for c, h in zip(cols, has, strict=True) if not h]
        raise RecordingError(f"{path}: {what} columns are incomplete (missing {', '.join(missing)}); "
                             f"give all of {', '.join(cols)} or none")
    return all(has)


def _read_truth(path: Path, rep: ReportBuilder
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    df = read_table(path, rep)
    pos_cols = [f"{c}_m" for c in ENU]
    vel_cols = [f"v{c}_mps" for c in ENU]
    require_columns(df, path, ["t_s", *pos_cols], optional=vel_cols + QUAT_COLS + OMEGA_COLS)
    has_vel = [c in df.columns for c in vel_cols]
    if any(has_vel) and not all(has_vel):
        missing = [c for c, h in zip(vel_cols, has_vel, strict=True) if not h]
        raise RecordingError(f"{path}: velocity columns are incomplete (missing {', '.join(missing)}); "
                             "give all of ve_mps, vn_mps, vu_mps or none")
    has_quat = _group(df, path, QUAT_COLS, "attitude quaternion")
    has_omega = _group(df, path, OMEGA_COLS, "body angular rate")
    if has_omega and not has_quat:
        raise RecordingError(f"{path}: body angular rate columns need the attitude columns {', '.join(QUAT_COLS)}")
    num = ["t_s", *pos_cols, *(vel_cols if all(has_vel) else []), *(QUAT_COLS if has_quat else []),
           *(OMEGA_COLS if has_omega else [])]
    df = to_float(df, num)
    check_seconds(df["t_s"].to_numpy(), path, "t_s")
    check_time_steps(df["t_s"].to_numpy(), path, "t_s", "truth")
    df = drop_nan_rows(df, num, path.name, rep)
    df = sort_and_dedupe(df[num], ["t_s"], path.name, rep)
    if len(df) < 2:
        raise RecordingError(f"{path}: fewer than 2 usable truth rows")
    rep.kept(path.name, len(df))
    vel = df[vel_cols].to_numpy() if all(has_vel) else None
    quat = omega = None
    if has_quat:
        quat = check_unit_quaternions(df[QUAT_COLS].to_numpy(), path,
                                      "give quat_w, quat_x, quat_y, quat_z of the body-to-ENU rotation")
        omega = df[OMEGA_COLS].to_numpy() if has_omega else body_rates_from_quat(df["t_s"].to_numpy(), quat)
    return df["t_s"].to_numpy(), df[pos_cols].to_numpy(), vel, quat, omega


def _read_uwb(path: Path, anchors: Anchors, rep: ReportBuilder
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    df = read_table(path, rep, str_columns=("anchor_id",))
    require_columns(df, path, ["t_s", "anchor_id", "range_m"])
    has_burst = "burst" in df.columns
    if has_burst:  # integer burst ids: text and fractions are counted, not silently truncated
        df = df.assign(burst=integer_column(df["burst"], path.name, "burst", rep).astype(np.float64))
    df = to_float(df, ["t_s", "range_m", *(["burst"] if has_burst else [])])
    check_seconds(df["t_s"].to_numpy(), path, "t_s")
    check_time_steps(df["t_s"].to_numpy(), path, "t_s", "uwb")
    check_range_metres(df["range_m"].to_numpy(), path, "range_m")
    df = drop_nan_rows(df, ["t_s"], path.name, rep, reason="nan_time")
    ids = df["anchor_id"].astype("string").str.strip()
    no_id = ids.isna() | (ids == "")
    rep.drop(path.name, "missing_anchor_id", int(no_id.sum()))
    df, ids = df.loc[~no_id], ids[~no_id].astype(str)
    lookup = pd.Series(np.arange(len(anchors)), index=list(anchors.ids))
    idx = ids.map(lookup)
    if idx.isna().any():
        unknown = sorted(ids[idx.isna()].unique())
        raise RecordingError(f"{path}: {int(idx.isna().sum())} row(s) refer to anchor(s) "
                             f"{', '.join(unknown[:5])} that anchors table does not define")
    cols = ["t_s", "anchor", "range_m", *(["burst"] if has_burst else [])]
    df = df.assign(anchor=idx.astype(np.int16).to_numpy())[cols]
    df = sort_and_dedupe(df, ["t_s", "anchor"], path.name, rep)
    if df.empty:
        raise RecordingError(f"{path}: no ranging attempt left (a recording needs at least one uwb row)")
    range_m = flag_ranges(df["range_m"].to_numpy(), path.name, rep)
    rep.kept(path.name, len(df))
    burst = df["burst"].fillna(-1).to_numpy().astype(np.int64) if has_burst else None
    return df["t_s"].to_numpy(), df["anchor"].to_numpy(), range_m, burst


def _read_imu(path: Path, rep: ReportBuilder) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                                                       np.ndarray | None]:
    """(t, ENU gravity-free acc or None, body specific force or None, gyro or None)."""
    df = read_table(path, rep)
    acc_cols = [f"acc_{c}_mps2" for c in ENU]
    require_columns(df, path, ["t_s"], optional=acc_cols + BODY_ACC_COLS + GYRO_COLS)
    has_enu = _group(df, path, acc_cols, "ENU acceleration")
    has_body = _group(df, path, BODY_ACC_COLS, "body-frame specific force")
    has_gyro = _group(df, path, GYRO_COLS, "gyroscope")
    if not (has_enu or has_body or has_gyro):
        raise RecordingError(f"{path}: no IMU columns; give acc_e_mps2, acc_n_mps2, acc_u_mps2 (ENU, gravity "
                             "removed) and/or acc_x_mps2.. (body frame) and gyro_x_radps..")
    cols = [*(acc_cols if has_enu else []), *(BODY_ACC_COLS if has_body else []), *(GYRO_COLS if has_gyro else [])]
    df = to_float(df, ["t_s", *cols])
    check_seconds(df["t_s"].to_numpy(), path, "t_s")
    check_time_steps(df["t_s"].to_numpy(), path, "t_s", "imu")
    df = drop_nan_rows(df, ["t_s", *cols], path.name, rep)
    df = sort_and_dedupe(df[["t_s", *cols]], ["t_s"], path.name, rep)
    if df.empty:
        raise RecordingError(f"{path}: no usable IMU rows")
    body = df[BODY_ACC_COLS].to_numpy() if has_body else None
    gyro = df[GYRO_COLS].to_numpy() if has_gyro else None
    if body is not None:
        check_specific_force(body, path, "body specific force")
    if gyro is not None:
        check_gyro_radps(gyro, path, "gyro")
    if not has_enu:
        rep.kept(path.name, len(df))
        return df["t_s"].to_numpy(), None, body, gyro
    acc = df[acc_cols].to_numpy()
    med = float(np.median(np.linalg.norm(acc, axis=1)))
    if med > MAX_PLAUSIBLE_ACC_MEDIAN_MPS2:
        raise RecordingError(f"{path}: median |acceleration| {med:.4g} is implausible for m/s^2 "
                             "(milli-g or mm/s^2?); convert to m/s^2")
    mean_u = float(np.mean(acc[:, 2]))
    if abs(mean_u) > MAX_GRAVITY_LEFT_MPS2:
        raise RecordingError(f"{path}: acc_u_mps2 averages {mean_u:.3g} m/s^2, so gravity is not removed; "
                             "PhySynth expects gravity-free ENU acceleration")
    rep.kept(path.name, len(df))
    return df["t_s"].to_numpy(), acc, body, gyro


def _read_meta(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: cannot read file: {exc}") from None
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: must hold a JSON object")
    return meta


def _check_overlap(path: Path, t: np.ndarray, truth_path: Path, t_truth: np.ndarray) -> None:
    if t.size and not np.any((t >= t_truth[0]) & (t <= t_truth[-1])):
        raise RecordingError(
            f"{path}: times {t[0]:.6g}..{t[-1]:.6g} s do not overlap {truth_path.name} "
            f"({t_truth[0]:.6g}..{t_truth[-1]:.6g} s after the origin); "
            "are both in the same time base and in seconds?")
