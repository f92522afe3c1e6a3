"""Importer of the Hanyang outdoor UWB dataset (DOI 10.5281/zenodo.15226105, Apache-2.0).

Loader facts (``data/hanyang-uwb/SOURCE.md``):

- one dynamic run per folder ``Dynamic_measurements/{LOS,NLOS}/Trajectory_X/Case_N`` with one
  ``A<id>.csv`` per anchor (``field.stamp`` ns, ``field.id``, ``field.x/y/z`` anchor position [m],
  ``field.distanceFromTag`` [m]) and ``trajectory.csv`` (``timestamp`` ns written as a float,
  ``x, y, z`` [m] of the RTK-GNSS tag path in the anchor frame);
- the tag antenna sits ``1.0 m`` above the trajectory ``z`` (the dataset authors' evaluation does the
  same); the local anchor frame is taken as ENU with E = x, N = y, U = z;
- the UWB stamps lag the GNSS stamps by about 0.15-0.20 s. This importer does **not** correct the
  lag (calibration estimates it); it is recorded in ``trace.meta`` as not applied;
- the static range sweeps ``Static_measurements/{LOS,NLOS}/height_<h>cm/<d>m.csv`` hold truncated,
  empty and summary rows; :func:`import_hanyang_static` reads them with a count of skipped rows.

Input files are never modified.
"""

from __future__ import annotations

import copy
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..._args import check_number
from ...errors import RecordingError
from ...records import TRUTH_UNTRUSTED_KEY, Anchors, Trace, Truth, Uwb
from ._common import (
    ImportReport,
    ReportBuilder,
    check_range_metres,
    check_range_scale,
    checked_window_and_gap,
    count_coerced_cells,
    drop_nan_rows,
    flag_implausible_ranges,
    flag_ranges,
    gap_bursts,
    max_gap_per_anchor_s,
    per_anchor_rate_hz,
    read_table,
    require_columns,
    sort_and_dedupe,
    to_float,
    velocity_from_position,
)

TAG_HEIGHT_OFFSET_M = 1.0
"""Height of the tag antenna above the trajectory ``z`` [m] (SOURCE.md; the authors' evaluation)."""
BURST_GAP_S = 0.05
"""Gap that starts a new ranging burst [s]: half the 10 Hz period. Within a burst the four anchors are
ranged within ~35 ms (the late rows of a late burst ~31 ms after their slot: `uwb.late_burst_prob`),
between bursts the gap is >= ~65 ms."""
LAG_NOTE = ("UWB field.stamp lags the GNSS trajectory timestamps by about 0.15-0.20 s "
            "(measured on the published runs); not corrected here, calibration estimates it")
CITATION = ("Hanyang University ADIP lab, Comprehensive outdoor UWB dataset, DOI 10.5281/zenodo.15226105 "
            "(Apache-2.0)")
_ANCHOR_FILE = re.compile(r"^A(\d+)\.csv$")
_UWB_COLS = ("field.stamp", "field.id", "field.x", "field.y", "field.z", "field.distanceFromTag")
RTK_FIXED_STATUS = 2
"""``field.status.status`` of an RTK-fixed solution in ``gnss.csv`` (sensor_msgs/NavSatStatus GBAS_FIX)."""
TRUSTED_POSITION_VAR_M2 = 1e-3
"""Largest horizontal position variance [m^2] of ``gnss.csv`` (``field.position_covariance0`` and ``4``) at
which the truth is trusted: a 3.2 cm std. Fixed solutions report 2e-4 m^2 (1.4 cm); without the fix it
reaches 0.01-6 m^2."""
RANGE_SCALE_LIMITS_HANYANG = (0.5, 2.0)
"""Median ratio of an anchor's ranges to its distances from the RTK truth outside which a unit is wrong (the
published runs: 1.001-1.006 per anchor; anchor coordinates in cm put an anchor near the origin 100 times
farther, which the generic limits of the CSV format do not see)."""
_GNSS_COLS = ("field.header.stamp", "field.status.status", "field.position_covariance0",
              "field.position_covariance4")
_STATIC_HEIGHT_TAG_M = 1.0
"""Tag (receiver) height in the static sweeps [m], per the authors' ``ranging_error_analysis.py``."""


def import_hanyang(run_dir: str | os.PathLike, *, tag_height_offset_m: float = TAG_HEIGHT_OFFSET_M,
                   burst_gap_s: float = BURST_GAP_S, velocity_window_s: float = 1.0,
                   crop_to_uwb: bool = False) -> tuple[Trace, ImportReport]:
    """Import one dynamic run (``.../Trajectory_A/Case_N``) of the Hanyang UWB dataset as a Trace.

    Parameters
    ----------
    run_dir
        Folder with ``A<id>.csv`` per anchor and ``trajectory.csv``.
    tag_height_offset_m
        Added to the trajectory ``z`` to get the tag antenna height [m] (1.0 m per SOURCE.md); finite.
    burst_gap_s
        A new ranging burst starts after a gap longer than this between consecutive UWB rows [s]; > 0.
    velocity_window_s
        Savitzky-Golay window [s] of the truth velocity (the ~8 Hz RTK track has no velocity); > 0.
    crop_to_uwb
        Drop (and count) truth samples after the last UWB measurement, e.g. where the UWB logging
        stopped before the GNSS logging (NLOS Case_1: ~55 s). Off by default.

    Returns
    -------
    (Trace, ImportReport)
        ENU = anchor frame (E = x, N = y, U = z) [m]; t = 0 at the first truth sample, whose Unix time
        is ``trace.meta["time_origin_unix_s"]``. Anchor ids are ``"A<id>"`` in numeric order. The
        UWB/GNSS time lag is not corrected (``trace.meta["uwb_time_lag_applied"]`` is False).

    Raises
    ------
    ArgumentError
        A parameter is not a finite number, or ``burst_gap_s`` or ``velocity_window_s`` is not positive.
    RecordingError
        The run cannot be imported (missing files or columns, no overlap of UWB and truth).
    """
    tag_height_offset_m = check_number(tag_height_offset_m, "tag_height_offset_m", unit="m")
    velocity_window_s, burst_gap_s = checked_window_and_gap(velocity_window_s, burst_gap_s)
    run = Path(run_dir)
    files, traj = _run_files(run)
    rep = ReportBuilder("hanyang", run)

    ts_ns, pos = _read_trajectory(traj, rep)
    origin_ns = int(ts_ns[0])
    t_truth = (ts_ns - float(origin_ns)) * 1e-9
    pos[:, 2] += tag_height_offset_m

    ids, anchor_pos, t_uwb, anchor, range_m = _read_uwb(run, files, origin_ns, rep)
    if not np.any((t_uwb >= t_truth[0]) & (t_uwb <= t_truth[-1])):
        raise RecordingError(f"{run}: UWB stamps do not overlap the trajectory.csv time span")
    range_m = _check_ranges_against_truth(files, t_uwb, anchor, range_m, t_truth, pos, np.array(anchor_pos), rep)

    if crop_to_uwb:
        after = t_truth > t_uwb[-1]
        rep.drop(traj.name, "after_last_uwb", int(after.sum()))
        t_truth, pos = t_truth[~after], pos[~after]
    rep.kept(traj.name, t_truth.size)
    vel = velocity_from_position(t_truth, pos, window_s=velocity_window_s, max_gap_s=1.0)
    burst = gap_bursts(t_uwb, burst_gap_s)
    rates, gaps = _note_uwb_coverage(rep, t_truth, t_uwb, anchor, range_m, burst, ids, burst_gap_s)

    meta = _run_meta(run, origin_ns, tag_height_offset_m=tag_height_offset_m, burst_gap_s=burst_gap_s,
                     velocity_window_s=velocity_window_s, crop_to_uwb=crop_to_uwb, rates=rates, gaps=gaps)
    meta.update(_truth_quality(run / "gnss.csv", origin_ns, float(t_truth[-1]), rep))
    trace = Trace(
        truth=Truth(t_s=t_truth, pos_enu_m=pos, vel_enu_mps=vel),
        uwb=Uwb(t_s=t_uwb, anchor=anchor, range_m=range_m, burst=burst),
        anchors=Anchors(ids=tuple(ids), pos_enu_m=np.array(anchor_pos)),
        meta=meta,
    )
    return trace, rep.build()


def _run_files(run: Path) -> tuple[list[Path], Path]:
    """The ``A<id>.csv`` files of a dynamic run (in numeric anchor order) and its ``trajectory.csv``."""
    if not run.exists():
        raise RecordingError(f"Hanyang run folder {run} does not exist")
    if not run.is_dir():
        raise RecordingError(f"{run} is not a folder (expected a .../Trajectory_X/Case_N folder)")
    files = sorted((f for f in run.iterdir() if _ANCHOR_FILE.match(f.name)),
                   key=lambda f: int(_ANCHOR_FILE.match(f.name).group(1)))  # type: ignore[union-attr]
    if not files:
        raise RecordingError(f"{run}: no A<id>.csv anchor files (is this a Trajectory_X/Case_N folder?)")
    traj = run / "trajectory.csv"
    if not traj.is_file():
        raise RecordingError(f"{run}: missing file trajectory.csv")
    return files, traj


def _read_uwb(run: Path, files: list[Path], origin_ns: int, rep: ReportBuilder
              ) -> tuple[list[str], list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Anchor ids and positions, and the UWB rows of all anchor files merged in time order.

    Returns ``(ids, anchor_pos, t_uwb, anchor, range_m)``; ``anchor`` indexes ``ids``.
    """
    ids, anchor_pos, parts = [], [], []
    for k, f in enumerate(files):  # one pass per anchor file
        aid = int(_ANCHOR_FILE.match(f.name).group(1))  # type: ignore[union-attr]
        xyz, t, r = _read_anchor_file(f, aid, origin_ns, rep)
        ids.append(f"A{aid}")
        anchor_pos.append(xyz)
        parts.append(pd.DataFrame({"t_s": t, "anchor": np.full(t.size, k, np.int16), "range_m": r}))
    uwb = pd.concat(parts, ignore_index=True).sort_values(["t_s", "anchor"], kind="stable")
    t_uwb = uwb["t_s"].to_numpy()
    anchor = uwb["anchor"].to_numpy()
    range_m = uwb["range_m"].to_numpy()
    if t_uwb.size == 0:
        raise RecordingError(f"{run}: no UWB measurements in any A<id>.csv")
    return ids, anchor_pos, t_uwb, anchor, range_m


def _check_ranges_against_truth(files: list[Path], t_uwb: np.ndarray, anchor: np.ndarray, range_m: np.ndarray,
                                t_truth: np.ndarray, pos: np.ndarray, anchor_pos: np.ndarray,
                                rep: ReportBuilder) -> np.ndarray:
    """Per anchor file: an error when its ranges are far from the truth-to-anchor distances (ranges, anchor
    coordinates or trajectory in cm/mm/km), and its ranges that no geometry explains (error codes such as
    65535) flagged NaN with a count (``implausible_range``)."""
    out = range_m.copy()
    for k, f in enumerate(files):  # one pass per anchor file
        sel = anchor == k
        check_range_scale(f, t_uwb[sel], anchor[sel], range_m[sel], t_truth, pos, anchor_pos,
                          limits=RANGE_SCALE_LIMITS_HANYANG)
        out[sel] = flag_implausible_ranges(range_m[sel], anchor[sel], pos, anchor_pos, f.name, rep)
    return out


def _note_uwb_coverage(rep: ReportBuilder, t_truth: np.ndarray, t_uwb: np.ndarray, anchor: np.ndarray,
                       range_m: np.ndarray, burst: np.ndarray, ids: list[str], burst_gap_s: float
                       ) -> tuple[dict[str, float], dict[str, float]]:
    """Note repeated anchors in a burst, UWB rows outside the truth span, a truth tail without UWB,
    long per-anchor outages and the uncorrected time lag; return the per-anchor rates and max gaps."""
    repeated = pd.DataFrame({"b": burst, "a": anchor}).duplicated().sum()
    if repeated:
        rep.note(f"{int(repeated)} burst(s) hold the same anchor twice (burst gap {burst_gap_s} s)")
    valid = np.isfinite(range_m)
    rates = per_anchor_rate_hz(t_uwb, anchor, valid, ids)
    gaps = max_gap_per_anchor_s(t_uwb, anchor, valid, ids)
    n_before = int(np.count_nonzero(t_uwb < t_truth[0]))
    n_after = int(np.count_nonzero(t_uwb > t_truth[-1]))
    if n_before or n_after:
        rep.note(f"{n_before} UWB row(s) before the first and {n_after} after the last truth sample "
                 "(kept; no residual for them)")
    tail_s = float(t_truth[-1] - t_uwb[-1])
    if tail_s > 2.0:
        rep.note(f"truth continues {tail_s:.1f} s after the last UWB measurement (UWB logging stopped; "
                 "use crop_to_uwb to drop it)")
    outages = {a: g for a, g in gaps.items() if g > 5.0}
    if outages:
        rep.note("longest UWB gap per anchor [s]: " + ", ".join(f"{a}={g:.1f}" for a, g in outages.items()))
    rep.note(LAG_NOTE)
    return rates, gaps


def _run_meta(run: Path, origin_ns: int, *, tag_height_offset_m: float, burst_gap_s: float,
              velocity_window_s: float, crop_to_uwb: bool, rates: dict[str, float],
              gaps: dict[str, float]) -> dict[str, Any]:
    """``trace.meta`` of a dynamic run."""
    env = next((p for p in run.parts[::-1] if p in ("LOS", "NLOS")), None)
    return {
        "source": "hanyang-uwb",
        "run": "/".join(run.parts[-3:]),
        "environment": env,
        "path": str(run.resolve()),
        "citation": CITATION,
        "time_origin_unix_s": origin_ns * 1e-9,
        "time_origin_s": origin_ns * 1e-9,
        "time_base": "seconds since the first trajectory.csv sample (UWB from field.stamp)",
        "frame": "local anchor frame taken as ENU: E = x, N = y, U = z [m]",
        "truth_source": "trajectory.csv (RTK-GNSS, ~8 Hz)",
        "tag_height_offset_m": float(tag_height_offset_m),
        "truth_velocity": f"Savitzky-Golay derivative of position (window {velocity_window_s} s, order 2)",
        "uwb_time_column": "field.stamp",
        "uwb_time_lag_applied": False,
        "uwb_time_lag_note": LAG_NOTE,
        "uwb_burst": f"gap-based grouping, new burst after a gap > {burst_gap_s} s",
        "uwb_rate_hz": rates,
        "uwb_max_gap_s": gaps,
        "cropped_to_uwb": bool(crop_to_uwb),
    }


def _truth_quality(path: Path, origin_ns: int, t_end_s: float, rep: ReportBuilder) -> dict[str, Any]:
    """``trace.meta`` items on the truth's own quality from ``gnss.csv`` (none when the file is absent): the
    spans where the GNSS solution is not RTK-fixed or its horizontal position std exceeds 3.2 cm
    (``truth_untrusted_s``, trace time [s]; each runs from the first such solution to the next trusted one)
    and the trusted share of the solutions."""
    if not path.is_file():
        rep.note("no gnss.csv: the truth's quality is unknown (every sample trusted)")
        return {}
    df = read_table(path, rep)
    require_columns(df, path, _GNSS_COLS)
    df = drop_nan_rows(to_float(df, list(_GNSS_COLS)), list(_GNSS_COLS), path.name, rep)
    df = sort_and_dedupe(df[list(_GNSS_COLS)], ["field.header.stamp"], path.name, rep)
    if df.empty:
        raise RecordingError(f"{path}: no usable GNSS rows")
    t = (df["field.header.stamp"].to_numpy() - float(origin_ns)) * 1e-9
    var = np.maximum(df["field.position_covariance0"].to_numpy(), df["field.position_covariance4"].to_numpy())
    bad = (df["field.status.status"].to_numpy() != RTK_FIXED_STATUS) | (var > TRUSTED_POSITION_VAR_M2)
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    first, stop = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # [first, stop) runs of bad rows
    ends = np.append(t, max(t_end_s, float(t[-1])) + 1e-3)[stop]  # up to the next trusted solution (excluded)
    spans = [[round(float(a), 3), round(float(b), 3)] for a, b in zip(t[first], ends, strict=True)]
    share = float(1.0 - bad.mean())
    rep.note(f"gnss.csv: {share:.1%} of the GNSS solutions RTK-fixed within 3.2 cm; {len(spans)} span(s) "
             f"without that ({TRUTH_UNTRUSTED_KEY})")
    return {TRUTH_UNTRUSTED_KEY: spans, "truth_trusted_share": round(share, 4),
            "truth_quality": "gnss.csv: RTK fix (status 2) and horizontal position std <= 3.2 cm"}


def _read_trajectory(path: Path, rep: ReportBuilder) -> tuple[np.ndarray, np.ndarray]:
    df = read_table(path, rep)
    cols = ["timestamp", "x", "y", "z"]
    require_columns(df, path, cols)
    df = to_float(df, cols)
    if df.empty:
        raise RecordingError(f"{path}: no data rows (header only)")
    ts = df["timestamp"].to_numpy()
    med = float(np.nanmedian(ts)) if np.isfinite(ts).any() else float("nan")
    if not 1e17 < med < 1e19:
        raise RecordingError(f"{path}: timestamp values around {med:.4g} are not Unix nanoseconds")
    df = drop_nan_rows(df, cols, path.name, rep)
    df = sort_and_dedupe(df[cols], ["timestamp"], path.name, rep)
    if len(df) < 2:
        raise RecordingError(f"{path}: fewer than 2 usable trajectory rows")
    return df["timestamp"].to_numpy(), df[["x", "y", "z"]].to_numpy().copy()


def _read_anchor_file(path: Path, aid: int, origin_ns: int, rep: ReportBuilder
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Anchor position (3,) [m], UWB times [s since origin] and ranges [m] of one A<id>.csv."""
    df = read_table(path, rep)
    require_columns(df, path, _UWB_COLS)
    stamp_raw = pd.to_numeric(df["field.stamp"], errors="coerce")
    # the anchor's id and coordinates repeat on every row: a cell that is not a number is counted, the row kept
    count_coerced_cells(df, ["field.id"], path.name, rep, "field.id")
    count_coerced_cells(df, ["field.x", "field.y", "field.z"], path.name, rep, "anchor_xyz")
    df = to_float(df, [c for c in _UWB_COLS if c != "field.stamp"])
    ids = df["field.id"].dropna().unique()
    if ids.size and not np.all(ids == aid):
        raise RecordingError(f"{path}: field.id is {', '.join(f'{i:g}' for i in ids)} but the file name "
                             f"says anchor {aid}")
    xyz = df[["field.x", "field.y", "field.z"]].dropna().drop_duplicates().to_numpy()
    if xyz.shape[0] == 0:
        raise RecordingError(f"{path}: anchor A{aid} has no coordinates (field.x/y/z empty)")
    if xyz.shape[0] > 1 and np.ptp(xyz, axis=0).max() > 1e-6:
        raise RecordingError(f"{path}: the anchor position (field.x/y/z) changes within the file")
    check_range_metres(df["field.distanceFromTag"].to_numpy(), path, "field.distanceFromTag")
    # Nanosecond stamps: integer arithmetic relative to the origin keeps them exact.
    if pd.api.types.is_integer_dtype(stamp_raw):
        t = (stamp_raw.to_numpy(np.int64) - origin_ns).astype(np.float64) * 1e-9
    else:
        t = (stamp_raw.to_numpy(np.float64) - float(origin_ns)) * 1e-9
    med = float(np.nanmedian(stamp_raw.to_numpy(np.float64))) if stamp_raw.notna().any() else float("nan")
    if not 1e17 < med < 1e19:
        raise RecordingError(f"{path}: field.stamp values around {med:.4g} are not Unix nanoseconds")
    tab = pd.DataFrame({"t_s": t, "range_m": df["field.distanceFromTag"].to_numpy()})
    tab = drop_nan_rows(tab, ["t_s"], path.name, rep, reason="nan_time")
    tab = sort_and_dedupe(tab, ["t_s"], path.name, rep)
    r = flag_ranges(tab["range_m"].to_numpy(), path.name, rep)
    rep.kept(path.name, len(tab))
    return xyz[0], tab["t_s"].to_numpy(), r


def import_hanyang_static(root: str | os.PathLike) -> tuple[pd.DataFrame, ImportReport]:
    """Read the Hanyang static range sweeps into one table, for the range-dependent bias.

    Each file ``{LOS,NLOS}/height_<h>cm/<d>m.csv`` under ``root`` (the ``Static_measurements``
    folder, or any folder below it) holds ~13 s of ranging between a fixed tag and one anchor
    at nominal horizontal distance ``d`` (file name); the anchor antenna is at height ``h`` (folder
    name) and the tag at 1.0 m, as in the dataset authors' ``ranging_error_analysis.py``, so the
    geometric distance is ``sqrt(d**2 + (h - 1.0)**2)``.

    Returns
    -------
    (DataFrame, ImportReport)
        One row per kept measurement, columns: ``environment`` ("LOS"/"NLOS"), ``height_m`` (anchor
        antenna height [m]), ``nominal_distance_m`` (horizontal, from the file name [m]),
        ``true_distance_m`` (geometric, see above [m]), ``t_s`` (Unix time [s]), ``range_m``
        (measured ``Distance`` [m]), ``rssi_dbm`` and ``rssi_fp_dbm`` (NaN where the file has -inf
        or nothing), ``anchor_id`` (int, -1 where garbled) and ``file`` (path relative to ``root``).
        Signed range error = ``range_m - true_distance_m``.

        Skipped with a count in the report (pooled under the key ``"static"``): truncated rows,
        empty rows, NUL-byte rows, the authors' trailing summary rows ("Distance Mean", ...), rows
        without a numeric timestamp or Distance, and header-only files (noted).
    """
    base = Path(root)
    if not base.is_dir():
        raise RecordingError(f"Hanyang static folder {base} does not exist or is not a folder")
    pat = re.compile(r"height_(\d+(?:\.\d+)?)cm$")
    files = sorted(f for f in base.rglob("*m.csv")
                   if pat.search(f.parent.name) and re.fullmatch(r"\d+(?:\.\d+)?m\.csv", f.name))
    if not files:
        raise RecordingError(f"{base}: no height_<h>cm/<d>m.csv static measurement files below it")
    # the sweeps are read again and again (range bias, link budget, tools): kept once per set of files,
    # keyed by every file's path, size and modification time, and handed out as copies
    sig = (str(base.resolve()), tuple((str(f), st.st_size, st.st_mtime_ns) for f in files for st in [f.stat()]))
    if sig not in _STATIC_CACHE:
        _STATIC_CACHE.clear()  # one set of sweeps at a time
        _STATIC_CACHE[sig] = _read_static(base, files, pat)
    df, report = _STATIC_CACHE[sig]
    return df.copy(), copy.deepcopy(report)


_STATIC_CACHE: dict[tuple, tuple[pd.DataFrame, ImportReport]] = {}


def _read_static(base: Path, files: list[Path], pat: re.Pattern) -> tuple[pd.DataFrame, ImportReport]:
    """The body of :func:`import_hanyang_static`: every file read and checked, one table."""
    rep = ReportBuilder("hanyang-static", base)
    key = "static"
    frames, empty_files = [], []
    for f in files:  # one pass per file (~13 s of data each)
        sub = ReportBuilder("hanyang-static", f)
        df = read_table(f, sub, skip_prefixes=("Distance", "RSSI"))
        rep.read(key, sum(sub.rows_read.values()))
        for table, dst in ((sub.dropped, rep.drop), (sub.repaired, rep.repair), (sub.flagged, rep.flag)):
            for counts in table.values():
                for reason, n in counts.items():
                    dst(key, reason, n)
        if df.empty:
            empty_files.append(str(f.relative_to(base)))
            continue
        require_columns(df, f, ["timestamp", "Distance"])
        env = next((p for p in f.parts[::-1] if p in ("LOS", "NLOS")), "unknown")
        h_m = float(pat.search(f.parent.name).group(1)) / 100.0  # type: ignore[union-attr]
        d_m = float(f.name[:-5])
        num = to_float(df, [c for c in ("timestamp", "Distance", "RSSI(dBm)", "RSSI_fp(dBm)", "anchor_id")
                            if c in df.columns])
        out = pd.DataFrame({
            "environment": env,
            "height_m": h_m,
            "nominal_distance_m": d_m,
            "true_distance_m": float(np.hypot(d_m, h_m - _STATIC_HEIGHT_TAG_M)),
            "t_s": num["timestamp"].to_numpy(),
            "range_m": num["Distance"].to_numpy(),
            "rssi_dbm": num["RSSI(dBm)"].to_numpy() if "RSSI(dBm)" in num else np.nan,
            "rssi_fp_dbm": num["RSSI_fp(dBm)"].to_numpy() if "RSSI_fp(dBm)" in num else np.nan,
            "anchor_id": num["anchor_id"].to_numpy() if "anchor_id" in num else np.nan,
            "file": str(f.relative_to(base)),
        })
        frames.append(out)
    if empty_files:
        rep.note(f"{len(empty_files)} header-only file(s) without data, e.g. {empty_files[0]}")
    if not frames:
        raise RecordingError(f"{base}: the static measurement files hold no data rows")
    df = pd.concat(frames, ignore_index=True)
    df = drop_nan_rows(df, ["t_s", "range_m"], key, rep)
    rep.flag(key, "garbled_anchor_id", int(df["anchor_id"].isna().sum()))
    rep.flag(key, "missing_rssi", int(df[["rssi_dbm", "rssi_fp_dbm"]].isna().any(axis=1).sum()))
    df["anchor_id"] = df["anchor_id"].fillna(-1).astype(np.int64)
    neg = df["range_m"] < 0
    rep.drop(key, "negative_range", int(neg.sum()))
    df = df.loc[~neg].reset_index(drop=True)
    rep.kept(key, len(df))
    return df, rep.build()
