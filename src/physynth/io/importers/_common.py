"""Shared machinery of the recording importers: tolerant table reading, cleaning rules and the report.

Every importer follows the same rules (docs/recording-format.md):

- a file that cannot be read, a missing file or column, a unit that is not the expected one and an
  anchor without coordinates are errors: one :class:`~physynth.errors.RecordingError` line naming the
  file and the problem;
- everything else that is wrong with a row is repaired or dropped *with a count* in the
  :class:`ImportReport`: truncated or corrupt CSV rows are skipped, rows with a NaN time or
  coordinate are dropped, unsorted rows are sorted, exact duplicates are dropped, NaN and negative
  ranges are kept as attempts with a NaN range and ``Reason.INVALID``. Nothing is dropped silently.
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from ..._args import check_number
from ...constants import G0_MPS2
from ...errors import RecordingError

#: Unit suffixes that are recognised in column names and the unit PhySynth expects instead.
_LENGTH_UNITS = ("mm", "cm", "dm", "km", "ft", "in", "um", "nm")
_TIME_UNITS = ("ms", "us", "ns", "min", "h")
_ACC_UNITS = ("g", "mg", "ug", "cmps2", "mmps2")
_SPEED_UNITS = ("kmh", "kph", "mmps", "cmps")
_EXPECTED_UNIT = {"m": _LENGTH_UNITS, "s": _TIME_UNITS, "mps2": _ACC_UNITS, "mps": _SPEED_UNITS}
_UNIT_WORDS = {"m": "metres", "s": "seconds", "mps2": "m/s^2", "mps": "m/s"}

MAX_PLAUSIBLE_RANGE_MEDIAN_M = 5000.0
"""A median range above this is taken as a unit mistake (millimetres or centimetres) [m]."""

MAX_PLAUSIBLE_TIME_S = 1e11
"""Times above this are not seconds (Unix seconds are ~1.7e9; milli/micro/nanoseconds are larger)."""


# --------------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class ImportReport:
    """What an importer read, kept, repaired, dropped and flagged, per input file.

    ``rows_read`` counts the data rows (CSV lines after the header, or Parquet rows) of each file,
    ``rows_kept`` those that reached the trace. ``dropped``, ``repaired`` and ``flagged`` map a file
    name to ``{reason: count}``: dropped rows are gone from the trace, repaired rows were changed
    (e.g. sorted), flagged rows are kept but marked (a NaN range with ``Reason.INVALID``, a masked
    sample). ``notes`` are one-line remarks (e.g. the UWB/GNSS time lag not being corrected).
    """

    source: str
    path: str
    rows_read: Mapping[str, int] = field(default_factory=dict)
    rows_kept: Mapping[str, int] = field(default_factory=dict)
    dropped: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    repaired: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    flagged: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def n_dropped(self) -> int:
        """Total number of dropped rows over all files and reasons."""
        return sum(sum(d.values()) for d in self.dropped.values())

    @property
    def n_repaired(self) -> int:
        """Total number of repaired rows over all files and reasons."""
        return sum(sum(d.values()) for d in self.repaired.values())

    @property
    def n_flagged(self) -> int:
        """Total number of flagged rows over all files and reasons."""
        return sum(sum(d.values()) for d in self.flagged.values())

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able form (stored in ``dataset.json`` under ``import_report``)."""
        return {
            "source": self.source,
            "path": self.path,
            "rows_read": dict(self.rows_read),
            "rows_kept": dict(self.rows_kept),
            "dropped": {k: dict(v) for k, v in self.dropped.items()},
            "repaired": {k: dict(v) for k, v in self.repaired.items()},
            "flagged": {k: dict(v) for k, v in self.flagged.items()},
            "notes": list(self.notes),
        }

    def summary_lines(self) -> list[str]:
        """A few human-readable lines: per file rows read/kept and counts per reason."""
        lines = [f"{self.source}: {self.path}"]
        files = list(dict.fromkeys([*self.rows_read, *self.dropped, *self.repaired, *self.flagged]))
        for f in files:
            parts = [f"read {self.rows_read.get(f, 0)}", f"kept {self.rows_kept.get(f, 0)}"]
            for label, table in (("dropped", self.dropped), ("repaired", self.repaired),
                                 ("flagged", self.flagged)):
                counts = table.get(f, {})
                if counts:
                    parts.append(f"{label} " + ", ".join(f"{k}={v}" for k, v in counts.items()))
            lines.append(f"  {f}: " + "; ".join(parts))
        lines += [f"  note: {n}" for n in self.notes]
        return lines


class ReportBuilder:
    """Mutable collector of counts that :meth:`build` freezes into an :class:`ImportReport`."""

    def __init__(self, source: str, path: str | os.PathLike) -> None:
        self.source = source
        self.path = str(path)
        self.rows_read: dict[str, int] = {}
        self.rows_kept: dict[str, int] = {}
        self.dropped: dict[str, dict[str, int]] = {}
        self.repaired: dict[str, dict[str, int]] = {}
        self.flagged: dict[str, dict[str, int]] = {}
        self.notes: list[str] = []

    @staticmethod
    def _add(table: dict[str, dict[str, int]], file: str, reason: str, n: int | np.integer) -> None:
        n = int(n)
        if n > 0:
            per = table.setdefault(file, {})
            per[reason] = per.get(reason, 0) + n

    def read(self, file: str, n: int) -> None:
        self.rows_read[file] = self.rows_read.get(file, 0) + int(n)

    def kept(self, file: str, n: int) -> None:
        self.rows_kept[file] = self.rows_kept.get(file, 0) + int(n)

    def drop(self, file: str, reason: str, n: int | np.integer) -> None:
        self._add(self.dropped, file, reason, n)

    def repair(self, file: str, reason: str, n: int | np.integer) -> None:
        self._add(self.repaired, file, reason, n)

    def flag(self, file: str, reason: str, n: int | np.integer) -> None:
        self._add(self.flagged, file, reason, n)

    def note(self, text: str) -> None:
        self.notes.append(text)

    def build(self) -> ImportReport:
        return ImportReport(
            source=self.source, path=self.path, rows_read=dict(self.rows_read),
            rows_kept=dict(self.rows_kept), dropped={k: dict(v) for k, v in self.dropped.items()},
            repaired={k: dict(v) for k, v in self.repaired.items()},
            flagged={k: dict(v) for k, v in self.flagged.items()}, notes=tuple(self.notes),
        )


# --------------------------------------------------------------------------------------------------
# Reading tables
# --------------------------------------------------------------------------------------------------


def find_table(folder: Path, name: str, *, required: bool) -> Path | None:
    """``folder/name.csv`` or ``folder/name.parquet``; an error when both or (if required) neither exist."""
    csv, parquet = folder / f"{name}.csv", folder / f"{name}.parquet"
    if csv.is_file() and parquet.is_file():
        raise RecordingError(f"{folder}: both {csv.name} and {parquet.name} exist; keep only one")
    if csv.is_file():
        return csv
    if parquet.is_file():
        return parquet
    if required:
        raise RecordingError(f"{folder}: missing file {name}.csv (or {name}.parquet)")
    return None


def read_table(path: Path, report: ReportBuilder, *, str_columns: Sequence[str] = (),
               skip_prefixes: Sequence[str] = ()) -> pd.DataFrame:
    """Read a CSV or Parquet table, skipping (and counting) rows that cannot be parsed.

    CSV rows with fewer fields than the header are skipped as ``truncated_row``, rows with more as
    ``malformed_row``, rows holding NUL bytes as ``corrupt_row``, blank lines or lines of bare
    separators inside the file as ``empty_row`` and rows starting with one of ``skip_prefixes`` as
    ``summary_row``; each count goes to ``report`` under the file's name. Columns named in
    ``str_columns`` are read as text, the others as pandas infers them (numeric conversion is left to
    the caller, which counts the resulting NaN values where it drops or flags them).
    """
    name = path.name
    if path.suffix == ".parquet":
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises many types; one clear line instead
            raise RecordingError(f"{path}: cannot read Parquet file: {_first_line(exc)}") from None
        df.columns = [str(c).strip() for c in df.columns]
        report.read(name, len(df))
        return df
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read file: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{path}: not a UTF-8 text CSV file ({exc.reason} at byte {exc.start})") from None
    lines = pd.Series(text.split("\n"), dtype=object).str.rstrip("\r")
    if len(lines) and lines.iloc[-1] == "":
        lines = lines.iloc[:-1]  # the newline that ends the last row
    if len(lines) == 0 or not str(lines.iloc[0]).strip():
        raise RecordingError(f"{path}: empty file or no header row")
    header = str(lines.iloc[0])
    body = lines.iloc[1:].astype(str)
    report.read(name, len(body))
    n_header = header.count(",") + 1
    blank = body.str.strip(", \t") == ""  # nothing, or only separators
    corrupt = body.str.contains("\x00", regex=False) & ~blank
    summary = (body.str.startswith(tuple(skip_prefixes)) if skip_prefixes else pd.Series(False, body.index))
    summary &= ~blank & ~corrupt
    quoted = body.str.contains('"', regex=False)
    n_fields = body.str.count(",") + 1
    other = ~(blank | corrupt | summary | quoted)
    truncated = other & (n_fields < n_header)
    extra = other & (n_fields > n_header)
    report.drop(name, "empty_row", blank.sum())
    report.drop(name, "corrupt_row", corrupt.sum())
    report.drop(name, "summary_row", summary.sum())
    report.drop(name, "truncated_row", truncated.sum())
    report.drop(name, "malformed_row", extra.sum())
    keep = ~(blank | corrupt | summary | truncated | extra)
    good = body[keep]
    dtype = {c.strip(): str for c in header.split(",") if c.strip() in set(str_columns)}
    try:
        df = pd.read_csv(io.StringIO("\n".join([header, *good.tolist()]) + "\n"), dtype=dtype or None,
                         on_bad_lines="skip", skip_blank_lines=True, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        raise RecordingError(f"{path}: cannot parse CSV: {_first_line(exc)}") from None
    report.drop(name, "malformed_row", int(keep.sum()) - len(df))  # quoted rows pandas could not parse
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def require_columns(df: pd.DataFrame, path: Path, required: Iterable[str], *,
                    optional: Iterable[str] = ()) -> None:
    """Error for a missing required column, or for a known column given in another unit.

    A column ``range_mm`` where ``range_m`` is expected (or ``t_ms`` for ``t_s``) is reported as a
    unit error rather than as a missing column, so the user knows what to convert.
    """
    cols = set(df.columns)
    for col in [*required, *optional]:
        if col in cols:
            continue
        base, _, unit = col.rpartition("_")
        for other in _EXPECTED_UNIT.get(unit, ()):
            if f"{base}_{other}" in cols:
                raise RecordingError(
                    f"{path}: column {base}_{other} is in {other}; PhySynth expects {col} in "
                    f"{_UNIT_WORDS[unit]} (convert the values and rename the column)")
    missing = [c for c in required if c not in cols]
    if missing:
        raise RecordingError(f"{path}: missing column(s) {', '.join(missing)} "
                             f"(found: {', '.join(map(str, df.columns)) or 'none'})")


def to_float(df: pd.DataFrame, cols: Sequence[str]) -> pd.DataFrame:
    """Columns as float64: empty cells, text that is not a number and infinities become NaN.

    The NaN values are counted where the caller drops or flags them (``nan_value``, ``nan_range``).
    """
    out = df.copy()
    for c in cols:
        num = pd.to_numeric(out[c], errors="coerce").astype(np.float64)
        out[c] = num.mask(np.isinf(num.to_numpy()))
    return out


def drop_nan_rows(df: pd.DataFrame, cols: Sequence[str], file: str, report: ReportBuilder,
                  reason: str = "nan_value") -> pd.DataFrame:
    """Drop rows with a NaN in any of ``cols`` (counted under ``reason``)."""
    bad = df[list(cols)].isna().any(axis=1)
    report.drop(file, reason, int(bad.sum()))
    return df.loc[~bad]


def check_seconds(t_s: np.ndarray, path: Path, col: str) -> None:
    """Error when a time column is evidently not in seconds."""
    t = t_s[np.isfinite(t_s)]
    if t.size and float(np.median(np.abs(t))) > MAX_PLAUSIBLE_TIME_S:
        raise RecordingError(
            f"{path}: {col} values around {np.median(t):.4g} are not seconds "
            f"(milli-, micro- or nanoseconds?); convert to seconds")


#: Plausible median time step [s] of each stream (lowest, highest): outside, the times are in another unit.
PLAUSIBLE_STEP_S = {"truth": (1e-4, 5.0), "imu": (1e-5, 1.0), "uwb": (1e-6, 60.0)}
#: A stream spanning this many times more (or less) time than the truth is in another time unit.
MAX_SPAN_RATIO = 200.0


def _unit_guess(factor: float) -> str:
    for name, f in (("nanoseconds", 1e9), ("microseconds", 1e6), ("milliseconds", 1e3)):
        if factor > f / 30:
            return name
    return "another unit"


def check_time_steps(t_s: np.ndarray, path: Path, col: str, stream: str) -> None:
    """Error when the median step between successive times is implausible for ``stream`` in seconds."""
    t = np.sort(t_s[np.isfinite(t_s)])
    d = np.diff(t)
    d = d[d > 0]
    if d.size < 2:
        return
    step = float(np.median(d))
    lo, hi = PLAUSIBLE_STEP_S[stream]
    if step > hi:
        raise RecordingError(
            f"{path}: {col} has a median step of {step:.4g} ({1 / step:.3g} samples per unit), implausible "
            f"for a {stream} stream in seconds (at most {hi:g} s); the times look like {_unit_guess(step / hi)}: "
            "convert them to seconds")
    if step < lo:
        raise RecordingError(
            f"{path}: {col} has a median step of {step:.3g} s ({1 / step:.3g} Hz), implausibly fast for a "
            f"{stream} stream (at least {lo:g} s); are the times in minutes or hours? convert them to seconds")


def check_time_spans(path: Path, t: np.ndarray, truth_path: Path, t_truth: np.ndarray) -> None:
    """Error when a stream and the truth span durations that differ by MAX_SPAN_RATIO or more."""
    if t.size < 2 or t_truth.size < 2:
        return
    span, span_truth = float(np.ptp(t)), float(np.ptp(t_truth))
    if span <= 0 or span_truth <= 0:
        return
    ratio = span_truth / span
    if ratio >= MAX_SPAN_RATIO or ratio <= 1 / MAX_SPAN_RATIO:
        longer, shorter, factor = ((truth_path.name, path.name, ratio) if ratio > 1
                                   else (path.name, truth_path.name, 1 / ratio))
        raise RecordingError(
            f"{path}: spans {span:.4g} s but {truth_path.name} spans {span_truth:.4g} s ({factor:.3g} times "
            f"apart): either {longer} is in {_unit_guess(factor)} (convert its times to seconds) or {shorter} "
            "covers only a small part of the recording")


#: Median ratio of measured range to the anchor-to-truth distance outside which a unit is wrong.
RANGE_SCALE_LIMITS = (0.05, 20.0)


def check_range_scale(path: Path, t_uwb: np.ndarray, anchor: np.ndarray, range_m: np.ndarray,
                      t_truth: np.ndarray, pos_m: np.ndarray, anchor_pos_m: np.ndarray, *,
                      limits: tuple[float, float] = RANGE_SCALE_LIMITS) -> None:
    """Error when the ranges are far from the distances between truth and anchors (a unit mistake in
    the ranges, the truth or the anchor coordinates): their median ratio outside ``limits``."""
    ok = np.isfinite(range_m) & (t_uwb >= t_truth[0]) & (t_uwb <= t_truth[-1])
    if np.count_nonzero(ok) < 10:
        return
    p = np.stack([np.interp(t_uwb[ok], t_truth, pos_m[:, k]) for k in range(3)], axis=1)
    dist = np.linalg.norm(p - anchor_pos_m[anchor[ok]], axis=1)
    good = dist > 0.5  # next to an anchor the ratio says nothing
    if np.count_nonzero(good) < 10:
        return
    ratio = float(np.median(range_m[ok][good] / dist[good]))
    lo, hi = limits
    if not lo <= ratio <= hi:
        guess = ("the ranges in millimetres or centimetres, or the positions in kilometres" if ratio > hi
                 else "the ranges in kilometres, or the positions in millimetres or centimetres")
        raise RecordingError(f"{path}: the ranges are {ratio:.3g} times the distances between the truth and "
                             f"the anchors (median); are {guess}? convert them to metres")


IMPLAUSIBLE_RANGE_EXCESS_M = 1000.0
"""A range longer than the farthest the truth ever is from its anchor by more than this [m] cannot come from
the recorded geometry (no multipath adds a kilometre): a radio's error code (65535) or a corrupt value."""


def flag_implausible_ranges(range_m: np.ndarray, anchor: np.ndarray, pos_m: np.ndarray, anchor_pos_m: np.ndarray,
                            file: str, report: ReportBuilder) -> np.ndarray:
    """Ranges with NaN (reason INVALID) where they exceed the truth's largest distance from their anchor by
    more than :data:`IMPLAUSIBLE_RANGE_EXCESS_M`; counted as flagged ``implausible_range``."""
    p = pos_m[np.all(np.isfinite(pos_m), axis=1)]
    if p.size == 0 or anchor_pos_m.size == 0:
        return range_m
    far = np.sqrt(np.max([np.sum((p - a) ** 2, axis=1) for a in anchor_pos_m], axis=1))  # one row per anchor
    bad = range_m > far[anchor] + IMPLAUSIBLE_RANGE_EXCESS_M  # NaN compares False
    report.flag(file, "implausible_range", int(np.count_nonzero(bad)))
    return np.where(bad, np.nan, range_m)


def integer_column(values: pd.Series, file: str, col: str, report: ReportBuilder,
                   missing: int = -1) -> np.ndarray:
    """An integer column: empty cells become ``missing``; text and non-integers become ``missing`` too,
    each counted as repaired (``<col>_not_a_number``, ``<col>_not_an_integer``)."""
    num, text, raw_empty = _text_and_empty(values)
    report.repair(file, f"{col}_not_a_number", int(np.count_nonzero(text)))
    frac = np.isfinite(num) & (num != np.round(num))
    report.repair(file, f"{col}_not_an_integer", int(np.count_nonzero(frac)))
    report.repair(file, f"{col}_empty", int(np.count_nonzero(raw_empty)))
    bad = ~np.isfinite(num) | frac | (np.abs(num) > 2**62)
    out = np.where(bad, missing, num)
    return out.astype(np.int64)


def _text_and_empty(values: pd.Series) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(numbers, text, empty)`` of a column: its values as float64 (NaN where not a number) and the masks of
    the cells that hold text that is not a number (or an infinity) and of the empty cells."""
    num = pd.to_numeric(values, errors="coerce").astype(np.float64).to_numpy()
    raw_empty = values.isna().to_numpy() | (values.astype("string").str.strip() == "").fillna(True).to_numpy()
    text = ~np.isfinite(num) & ~raw_empty
    return np.where(np.isinf(num), np.nan, num), text, raw_empty


def count_coerced_cells(df: pd.DataFrame, cols: Sequence[str], file: str, report: ReportBuilder,
                        label: str) -> None:
    """Count the rows whose ``cols`` hold a cell that is not a number (text, an infinity) or is empty, where
    the importer reads those cells as NaN and keeps the row (e.g. the anchor coordinates a UWB file repeats
    on every row): repaired ``<label>_not_a_number`` and ``<label>_empty``."""
    text = np.zeros(len(df), dtype=bool)
    empty = np.zeros(len(df), dtype=bool)
    for c in cols:
        _, t, e = _text_and_empty(df[c])
        text |= t
        empty |= e
    report.repair(file, f"{label}_not_a_number", int(np.count_nonzero(text)))
    report.repair(file, f"{label}_empty", int(np.count_nonzero(empty & ~text)))


MAX_PLAUSIBLE_ACC_MEDIAN_MPS2 = 500.0
"""A median |acceleration| above this is taken as a unit mistake (mg, mm/s^2) [m/s^2]."""
MAX_PLAUSIBLE_GYRO_MEDIAN_RADPS = 30.0
"""A median |angular rate| above this is taken as degrees per second [rad/s]."""
GYRO_SCALE_LIMITS = (0.5, 2.0)
"""Median ratio of |gyro| to the reference body rate (e.g. from an optical attitude) outside which the gyro
is in another unit (deg/s reads 57 times the rad/s rate)."""
QUAT_NORM_TOLERANCE = 0.01
"""Largest relative deviation of an attitude quaternion's norm from 1."""


def check_specific_force(f_body: np.ndarray, path: Path, what: str) -> None:
    """Error when an accelerometer's specific force (N, 3), gravity included, is evidently not in m/s^2: its
    median magnitude must lie between half of g (g units read ~1) and 500 m/s^2 (milli-g, mm/s^2)."""
    f = f_body[np.all(np.isfinite(f_body), axis=1)]
    if not f.size:
        return
    med = float(np.median(np.linalg.norm(f, axis=1)))
    if not 0.5 * G0_MPS2 < med < MAX_PLAUSIBLE_ACC_MEDIAN_MPS2:
        raise RecordingError(f"{path}: median |{what}| {med:.4g} m/s^2 is implausible: an accelerometer reads "
                             "about 9.81 at rest (gravity included; m/s^2, not g)")


def check_gyro_radps(gyro: np.ndarray, path: Path, what: str, omega_ref: np.ndarray | None = None) -> None:
    """Error when angular rates (N, 3) are evidently not in rad/s: a median magnitude above 30 rad/s, or
    (given a reference body rate ``omega_ref`` (N, 3) [rad/s], e.g. from an optical attitude) a median ratio
    of the magnitudes outside :data:`GYRO_SCALE_LIMITS` over the samples where the reference turns."""
    g = np.linalg.norm(gyro, axis=1)
    ok = np.isfinite(g)
    if ok.any() and float(np.median(g[ok])) > MAX_PLAUSIBLE_GYRO_MEDIAN_RADPS:
        raise RecordingError(f"{path}: median |{what}| above {MAX_PLAUSIBLE_GYRO_MEDIAN_RADPS:g} rad/s is "
                             "implausible; convert deg/s to rad/s")
    if omega_ref is None:
        return
    w = np.linalg.norm(omega_ref, axis=1)
    turning = ok & np.isfinite(w) & (w > 0.1)  # slower turns are lost in the gyro's noise and bias
    if np.count_nonzero(turning) < 100:
        return
    ratio = float(np.median(g[turning] / w[turning]))
    lo, hi = GYRO_SCALE_LIMITS
    if not lo <= ratio <= hi:
        guess = "in deg/s? convert to rad/s" if 30 < ratio < 100 else "in another unit than rad/s?"
        raise RecordingError(f"{path}: |{what}| is {ratio:.3g} times the body rate of the reference attitude "
                             f"(median); is it {guess}")


def check_unit_quaternions(quat: np.ndarray, path: Path, hint: str) -> np.ndarray:
    """Attitude quaternions (N, 4) normalised; an error when a finite one's norm is off 1 by more than 1 %
    (``hint`` says what is expected). Rows with a NaN stay NaN."""
    norm = np.linalg.norm(quat, axis=1)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOLERANCE  # NaN compares False
    if off.any():
        raise RecordingError(f"{path}: {int(np.count_nonzero(off))} attitude quaternion(s) are not unit (|q| off "
                             f"by more than {QUAT_NORM_TOLERANCE:.0%}, e.g. {norm[off][0]:.4g}); {hint}")
    return quat / norm[:, None]


def check_range_metres(range_m: np.ndarray, path: Path, col: str) -> None:
    """Error when the ranges are evidently not in metres (median above 5 km)."""
    r = range_m[np.isfinite(range_m)]
    if r.size and float(np.median(r)) > MAX_PLAUSIBLE_RANGE_MEDIAN_M:
        raise RecordingError(
            f"{path}: {col} has median {np.median(r):.4g}, implausible for metres "
            f"(millimetres or centimetres?); convert ranges to metres")


def sort_and_dedupe(df: pd.DataFrame, keys: Sequence[str], file: str, report: ReportBuilder) -> pd.DataFrame:
    """Sort rows by ``keys`` (counting the rows that were out of order) and drop duplicates.

    A row identical to an earlier one in every column is dropped as ``duplicate_row``; a row that
    repeats the keys (time, or time and anchor) of an earlier one with other values is dropped as
    ``duplicate_time_conflict`` (the first one is kept).
    """
    t = df[keys[0]].to_numpy()
    n_unsorted = int(np.count_nonzero(np.diff(t) < 0)) if t.size > 1 else 0
    if n_unsorted:
        report.repair(file, "unsorted_rows", n_unsorted)
    df = df.sort_values(list(keys), kind="stable")
    exact = df.duplicated(keep="first")
    report.drop(file, "duplicate_row", int(exact.sum()))
    df = df.loc[~exact]
    conflict = df.duplicated(subset=list(keys), keep="first")
    report.drop(file, "duplicate_time_conflict", int(conflict.sum()))
    return df.loc[~conflict]


def flag_ranges(range_m: np.ndarray, file: str, report: ReportBuilder) -> np.ndarray:
    """Ranges with NaN for negative values; counts ``nan_range`` and ``negative_range`` as flagged.

    The rows stay in the trace as attempts whose ``reason`` is ``Reason.INVALID`` (see
    :class:`~physynth.records.Uwb`, which derives it from the NaN).
    """
    r = np.asarray(range_m, dtype=np.float64).copy()
    report.flag(file, "nan_range", int(np.count_nonzero(np.isnan(r))))
    neg = r < 0
    report.flag(file, "negative_range", int(np.count_nonzero(neg)))
    r[neg] = np.nan
    return r


# --------------------------------------------------------------------------------------------------
# Derived quantities
# --------------------------------------------------------------------------------------------------


def velocity_from_position(t_s: np.ndarray, pos_m: np.ndarray, *, window_s: float, polyorder: int = 2,
                           max_gap_s: float = 1.0) -> np.ndarray:
    """Velocity (T, 3) [m/s] by Savitzky-Golay differentiation of a position track (T, 3) [m].

    The track is cut into segments at NaN positions and at time gaps longer than ``max_gap_s``; each
    segment is resampled onto a uniform grid at its median step (linear interpolation), smoothed and
    differentiated with a local polynomial of order ``polyorder`` over about ``window_s`` seconds
    (at least ``polyorder + 3`` samples, odd), and interpolated back to the sample times. Velocity is
    NaN where the position is NaN and on isolated single samples.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    pos_m = np.asarray(pos_m, dtype=np.float64)
    vel = np.full_like(pos_m, np.nan)
    ok = np.all(np.isfinite(pos_m), axis=1)
    if not ok.any():
        return vel
    idx = np.flatnonzero(ok)
    new_seg = np.ones(idx.size, dtype=bool)
    new_seg[1:] = (np.diff(idx) > 1) | (np.diff(t_s[idx]) > max_gap_s)
    starts = np.flatnonzero(new_seg)
    ends = np.append(starts[1:], idx.size)
    for s, e in zip(starts, ends, strict=True):  # one pass per contiguous segment, vectorised inside
        rows = idx[s:e]
        ts, ps = t_s[rows], pos_m[rows]
        if rows.size < 2:
            continue
        dt = float(np.median(np.diff(ts)))
        if not dt > 0:
            continue
        n_grid = int(np.round((ts[-1] - ts[0]) / dt)) + 1
        tg = ts[0] + np.arange(n_grid) * dt
        pg = np.stack([np.interp(tg, ts, ps[:, k]) for k in range(3)], axis=1)
        win = max(int(np.round(window_s / dt)), polyorder + 3)
        win += 1 - win % 2
        if n_grid >= win:
            vg = savgol_filter(pg, win, polyorder, deriv=1, delta=dt, axis=0, mode="interp")
        else:
            vg = np.gradient(pg, tg, axis=0)
        vel[rows] = np.stack([np.interp(ts, tg, vg[:, k]) for k in range(3)], axis=1)
    return vel


def checked_window_and_gap(velocity_window_s: float, burst_gap_s: float | None = None) -> tuple[float, float | None]:
    """An importer's smoothing window and burst gap [s] (None: none given), checked before any file is read:
    positive finite numbers (a gap of 0 or less would make every row its own burst).

    Raises
    ------
    ArgumentError
        One of them is not a positive finite number.
    """
    window = check_number(velocity_window_s, "velocity_window_s", positive=True, unit="s")
    return window, None if burst_gap_s is None else check_number(burst_gap_s, "burst_gap_s", positive=True, unit="s")


def gap_bursts(t_s: np.ndarray, gap_s: float) -> np.ndarray:
    """Burst index of time-sorted measurements: a new burst starts after a gap longer than ``gap_s``."""
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(np.diff(t_s) > gap_s)]).astype(np.int64)


def auto_burst_gap_s(t_s: np.ndarray, anchor: np.ndarray) -> float:
    """Half the median interval between consecutive measurements of the same anchor [s]."""
    order = np.lexsort((t_s, anchor))
    a, t = anchor[order], t_s[order]
    d = np.diff(t)[np.diff(a) == 0]
    d = d[d > 0]
    return float(np.median(d) / 2.0) if d.size else 0.05


def per_anchor_rate_hz(t_s: np.ndarray, anchor: np.ndarray, valid: np.ndarray,
                       ids: Sequence[str]) -> dict[str, float]:
    """Effective rate [Hz] of valid ranges per anchor: (count - 1) / (last - first)."""
    out = {}
    for i, a in enumerate(ids):  # one pass per anchor
        t = t_s[valid & (anchor == i)]
        out[a] = float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 and t[-1] > t[0] else float("nan")
    return out


def max_gap_per_anchor_s(t_s: np.ndarray, anchor: np.ndarray, valid: np.ndarray,
                         ids: Sequence[str]) -> dict[str, float]:
    """Longest interval between consecutive valid ranges of each anchor [s]."""
    out = {}
    for i, a in enumerate(ids):
        t = t_s[valid & (anchor == i)]
        out[a] = float(np.max(np.diff(t))) if t.size > 1 else float("nan")
    return out
