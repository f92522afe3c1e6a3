"""The one data model shared by real and synthetic traces (docs/data-and-metrics.md, section 1).

A :class:`Trace` is one run of one tag: ground truth, IMU samples, UWB measurements and the anchor
layout. Importers of real recordings and the generator produce exactly these records; calibration,
validation and writers never ask where a trace came from. Synthetic traces carry extra labels
(true range, NLOS flag, burst index, reason of a missing range); real traces leave them unknown
(NaN true range, ``nlos_known`` False, burst -1).

World frame ENU [m], time float64 seconds, shapes time-first then component: (T, 3).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .constants import IMU_BODY_FRAME, IMU_FRAME
from .errors import ArgumentError


class Reason(enum.IntEnum):
    """Why a UWB row has (or has not) a range. Stored as a small integer in the ``reason`` column."""

    OK = 0
    DROPOUT = 1  # lost on its own (per-burst dropout)
    OUTAGE = 2  # anchor in an outage period
    NO_LINK = 3  # out of radio range / blocked (link-visibility model)
    INVALID = 4  # real data: range present in the file but unusable (NaN, negative)


def _f64(a: Any, shape_tail: tuple[int, ...], name: str) -> np.ndarray:
    """float64 array of shape (N, *shape_tail); a C- or Fortran-contiguous float64 input is kept as is
    (the generator builds (3, N) component-first arrays: their transpose needs no copy)."""
    arr = np.asarray(a, dtype=np.float64)
    if not (arr.flags.c_contiguous or arr.flags.f_contiguous):
        arr = np.ascontiguousarray(arr)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ValueError(f"{name}: expected shape (N, {', '.join(map(str, shape_tail))}), got {arr.shape}")
    return arr


def _check_time(t_s: np.ndarray, name: str) -> None:
    if t_s.ndim != 1:
        raise ValueError(f"{name}.t_s must be 1-D")
    n = t_s.shape[0]
    if n > 1 and np.isfinite(t_s[0]) and np.isfinite(t_s[-1]) and (t_s[1:] >= t_s[:-1]).all():
        return  # sorted (no NaN) between finite ends: every time is finite, one pass instead of two
    if t_s.size and not np.isfinite(t_s).all():
        raise ValueError(f"{name}.t_s contains NaN or infinite times")
    if t_s.size > 1 and (t_s[1:] < t_s[:-1]).any():  # finite: the same test as diff < 0, without a float temporary
        raise ValueError(f"{name}.t_s is not sorted")


@dataclass(frozen=True, slots=True, kw_only=True)
class Anchors:
    """The anchor layout: ids (e.g. "A101"), display names and ENU positions (A, 3) [m]."""

    ids: tuple[str, ...]
    pos_enu_m: np.ndarray
    names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "ids", tuple(str(i) for i in self.ids))
        object.__setattr__(self, "pos_enu_m", _f64(self.pos_enu_m, (3,), "anchors.pos_enu_m"))
        if not self.names:
            object.__setattr__(self, "names", self.ids)
        if len(set(self.ids)) != len(self.ids):
            raise ValueError(f"anchor ids are not unique: {self.ids}")
        if len(self.ids) != self.pos_enu_m.shape[0] or len(self.names) != len(self.ids):
            raise ValueError("anchors: ids, names and positions differ in length")

    def __len__(self) -> int:
        return len(self.ids)

    def index(self, anchor_id: str) -> int:
        return self.ids.index(anchor_id)


@dataclass(frozen=True, slots=True, kw_only=True)
class Truth:
    """Ground truth: time [s], position (T, 3) [m] and velocity (T, 3) [m/s] in ENU.

    Optional attitude: ``quat_wxyz`` (T, 4), the Hamilton quaternion of the body (FLU) to ENU
    rotation, scalar first; ``omega_body_radps`` (T, 3), the body angular velocity [rad/s] in the body
    frame (row k holds the rate over [t_k, t_{k+1}), :mod:`physynth.models.attitude`). None when the
    recording has no attitude.
    """

    t_s: np.ndarray
    pos_enu_m: np.ndarray
    vel_enu_mps: np.ndarray
    quat_wxyz: np.ndarray | None = None
    omega_body_radps: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_s", np.ascontiguousarray(self.t_s, dtype=np.float64))
        _check_time(self.t_s, "truth")
        object.__setattr__(self, "pos_enu_m", _f64(self.pos_enu_m, (3,), "truth.pos_enu_m"))
        object.__setattr__(self, "vel_enu_mps", _f64(self.vel_enu_mps, (3,), "truth.vel_enu_mps"))
        n = self.t_s.shape[0]
        if n == 0:
            raise ValueError("truth: no samples (t_s is empty); a trace needs at least one truth sample")
        if self.pos_enu_m.shape[0] != n or self.vel_enu_mps.shape[0] != n:
            raise ValueError("truth: t_s, pos_enu_m and vel_enu_mps differ in length")
        for name, width in (("quat_wxyz", 4), ("omega_body_radps", 3)):
            value = getattr(self, name)
            if value is not None:
                value = _f64(value, (width,), f"truth.{name}")
                if value.shape[0] != n:
                    raise ValueError(f"truth: t_s and {name} differ in length")
                object.__setattr__(self, name, value)

    @property
    def has_attitude(self) -> bool:
        return self.quat_wxyz is not None

    def position_at(self, t_s: np.ndarray) -> np.ndarray:
        """Truth position linearly interpolated at times ``t_s`` (N,) -> (N, 3) [m].

        Rows where the truth position is NaN (masked dropouts of a real reference) are skipped, so
        a query inside a masked span is interpolated across it; outside the truth span it is NaN.
        """
        t_s = np.asarray(t_s, dtype=np.float64)
        ok = np.all(np.isfinite(self.pos_enu_m), axis=1)
        tt, pp = self.t_s[ok], self.pos_enu_m[ok]
        out = np.empty(t_s.shape + (3,))
        for k in range(3):
            out[..., k] = np.interp(t_s, tt, pp[:, k], left=np.nan, right=np.nan)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class Imu:
    """IMU samples on one time base ``t_s`` [s], in one or both of two frames.

    ``acc_mps2`` (N, 3): acceleration in ``frame`` (ENU, gravity removed: the paper's form) [m s^-2],
    or None when the recording has only the body-frame sensor. ``acc_body_mps2`` (N, 3): specific
    force in the body frame (FLU), gravity included, as an accelerometer reads it (a level unit at
    rest reads (0, 0, +9.81)) [m s^-2]; ``gyro_body_radps`` (N, 3): body angular rate [rad/s]. Either
    may be None.
    """

    t_s: np.ndarray
    acc_mps2: np.ndarray | None = None
    frame: str = IMU_FRAME
    acc_body_mps2: np.ndarray | None = None
    gyro_body_radps: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_s", np.ascontiguousarray(self.t_s, dtype=np.float64))
        _check_time(self.t_s, "imu")
        present = False
        for name in ("acc_mps2", "acc_body_mps2", "gyro_body_radps"):
            value = getattr(self, name)
            if value is None:
                continue
            value = _f64(value, (3,), f"imu.{name}")
            if value.shape[0] != self.t_s.shape[0]:
                raise ValueError(f"imu: t_s and {name} differ in length")
            object.__setattr__(self, name, value)
            present = True
        if not present:
            raise ValueError("imu: no acceleration or angular rate given")

    @property
    def frames(self) -> tuple[str, ...]:
        """The conventions present: ``IMU_FRAME`` (ENU gravity-free) and/or ``IMU_BODY_FRAME``."""
        out = (self.frame,) if self.acc_mps2 is not None else ()
        if self.acc_body_mps2 is not None or self.gyro_body_radps is not None:
            out += (IMU_BODY_FRAME,)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class Uwb:
    """UWB ranging attempts, one row each, sorted by time.

    ``anchor`` indexes the trace's :class:`Anchors`. ``range_m`` is NaN when no range was delivered
    (``reason`` says why). Labels: ``true_range_m`` (NaN when unknown), ``nlos`` (meaningful only
    when ``nlos_known``), ``burst`` (-1 when unknown).
    """

    t_s: np.ndarray
    anchor: np.ndarray
    range_m: np.ndarray
    true_range_m: np.ndarray | None = None
    nlos: np.ndarray | None = None
    burst: np.ndarray | None = None
    reason: np.ndarray | None = None
    nlos_known: bool = False

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t_s, dtype=np.float64)
        _check_time(t, "uwb")
        n = t.shape[0]
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "anchor", np.ascontiguousarray(self.anchor, dtype=np.int16))
        object.__setattr__(self, "range_m", np.ascontiguousarray(self.range_m, dtype=np.float64))
        defaults = {
            "true_range_m": (np.float64, np.nan),
            "nlos": (np.bool_, False),
            "burst": (np.int64, -1),
            "reason": (np.int8, None),
        }
        for name, (dtype, fill) in defaults.items():
            value = getattr(self, name)
            if value is None:
                if name == "reason":
                    value = np.where(np.isnan(self.range_m), Reason.INVALID, Reason.OK)
                else:
                    value = np.full(n, fill, dtype=dtype)
            object.__setattr__(self, name, np.ascontiguousarray(value, dtype=dtype))
        for name in ("anchor", "range_m", "true_range_m", "nlos", "burst", "reason"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"uwb.{name} has shape {getattr(self, name).shape}, expected ({n},)")

    @property
    def valid(self) -> np.ndarray:
        """Mask of rows that carry a usable range."""
        return np.isfinite(self.range_m)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def rows(self, index: np.ndarray, *, t_s: np.ndarray | None = None, anchor: np.ndarray | None = None) -> Uwb:
        """The rows ``index`` (integer positions or a boolean mask), every column alike; ``t_s`` and
        ``anchor`` replace those columns of the result when given (already indexed)."""
        return Uwb(t_s=self.t_s[index] if t_s is None else t_s,
                   anchor=self.anchor[index] if anchor is None else anchor, range_m=self.range_m[index],
                   true_range_m=self.true_range_m[index], nlos=self.nlos[index], burst=self.burst[index],
                   reason=self.reason[index], nlos_known=self.nlos_known)


TRUTH_UNTRUSTED_KEY = "truth_untrusted_s"
"""``trace.meta`` key of the spans [[start, end), ...] [s, trace time] where the recording's own truth system
says its position is unreliable (for an RTK-GNSS truth: no RTK fix, or a position std above 3.2 cm).
The residual metrics leave the ranges inside them out, and ``calibrate(..., trusted_truth=True)`` fits the
ranging channel outside them (docs/calibration.md, "Where the truth itself errs"); absent or empty: every
sample is trusted."""


def untrusted_truth(meta: dict[str, Any], t_s: np.ndarray) -> np.ndarray:
    """Boolean mask of the truth times ``t_s`` [s] that fall inside a ``TRUTH_UNTRUSTED_KEY`` span of ``meta``."""
    t = np.asarray(t_s, dtype=float)
    spans = np.asarray(meta.get(TRUTH_UNTRUSTED_KEY) or [], dtype=float).reshape(-1, 2)
    if spans.size == 0:
        return np.zeros(t.shape, dtype=bool)
    order = np.argsort(spans[:, 0], kind="stable")
    start, end = spans[order, 0], np.maximum.accumulate(spans[order, 1])
    k = np.searchsorted(start, t, side="right") - 1  # the last span starting at or before t
    return (k >= 0) & (t < end[np.clip(k, 0, None)])  # each span [start, end)


@dataclass(frozen=True, slots=True, kw_only=True)
class Trace:
    """One run of one tag. ``imu`` is None when the recording has no IMU."""

    truth: Truth
    uwb: Uwb
    anchors: Anchors
    imu: Imu | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.uwb) and (int(self.uwb.anchor.max()) >= len(self.anchors) or int(self.uwb.anchor.min()) < 0):
            raise ValueError(f"uwb rows refer to an anchor index outside the anchor layout (0 .. "
                             f"{len(self.anchors) - 1}): {int(self.uwb.anchor.min())} .. {int(self.uwb.anchor.max())}")

    @property
    def t0_s(self) -> float:
        return float(self.truth.t_s[0])

    @property
    def duration_s(self) -> float:
        return float(self.truth.t_s[-1] - self.truth.t_s[0])


def trace_iterable(traces: Iterable[Trace]) -> Iterable[Trace]:
    """``traces`` as given; one :class:`Trace` passed where an iterable of them is expected is refused.

    Raises
    ------
    ArgumentError
        ``traces`` is a single Trace.
    """
    if isinstance(traces, Trace):
        raise ArgumentError("traces must be an iterable of Trace records, got a single Trace (pass [trace])")
    return traces
