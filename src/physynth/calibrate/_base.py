"""Shared pieces of calibration: the :class:`Fit` record, input checks and track smoothing.

Everything here is vectorised over whole traces; the only Python loops run over traces, anchors,
axes or contiguous segments of a track, never over samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np
from scipy.signal import savgol_filter

from .._json import jsonable  # noqa: F401 (re-exported for the calibration modules)
from ..errors import PhySynthError
from ..records import Trace

P = TypeVar("P")


class CalibrationError(PhySynthError):
    """The recordings cannot be calibrated (no truth, no UWB rows, conflicting anchors, ...)."""


class AnchorLayoutError(CalibrationError):
    """Recordings that place an anchor id differently where one layout is asked for. ``conflict`` names
    the anchor and both positions; the message adds ``remedy``, what the caller's user can do."""

    def __init__(self, conflict: str, remedy: str) -> None:
        self.conflict = conflict
        super().__init__(f"conflicting anchors across the recordings: {conflict}; {remedy}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Fit(Generic[P]):
    """A fitted parameter object with what a user needs to trust it.

    ``params`` is the fitted (frozen, validated) parameter object, ``n_samples`` the number of samples
    behind it, ``diagnostics`` a JSON-able dictionary (uncertainties, goodness of fit, what was not
    identifiable) and ``log_likelihood`` the maximised log-likelihood where the fit is a likelihood fit.
    """

    params: P
    n_samples: int
    diagnostics: dict[str, Any] = field(default_factory=dict)
    log_likelihood: float | None = None


def as_trace_list(traces: Trace | Sequence[Trace]) -> list[Trace]:
    """A list of traces from one trace or a sequence (an empty sequence is an error)."""
    out = [traces] if isinstance(traces, Trace) else list(traces)
    if not out:
        raise CalibrationError("no traces to calibrate on")
    for t in out:
        if not isinstance(t, Trace):
            raise CalibrationError(f"expected Trace records, got {type(t).__name__}")
    return out


def run_name(meta: dict[str, Any] | None) -> str | None:
    """The name a recording's metadata gives it: an importer's ``run`` (Hanyang, BROAD) or ``recording``
    (the folder of a CSV recording); None when it has neither."""
    m = meta or {}
    for key in ("run", "recording"):
        if m.get(key):
            return str(m[key])
    return None


def trace_label(trace: Trace, index: int) -> str:
    """A short name of a trace for messages and reports: its ``label``, its run or recording name, its
    ``path``, or ``trace <index>``."""
    m = trace.meta or {}
    if m.get("label"):
        return str(m["label"])
    return run_name(m) or (str(m["path"]) if m.get("path") else f"trace {index}")


def good_truth(trace: Trace) -> tuple[np.ndarray, np.ndarray]:
    """Truth times (T,) [s] and positions (T, 3) [m] with NaN rows removed."""
    ok = np.all(np.isfinite(trace.truth.pos_enu_m), axis=1)
    return trace.truth.t_s[ok], trace.truth.pos_enu_m[ok]


def require_truth(trace: Trace, label: str, min_samples: int = 10) -> None:
    t, _ = good_truth(trace)
    if t.size < min_samples or not t[-1] > t[0]:
        raise CalibrationError(f"{label}: no usable ground truth ({t.size} finite truth samples; "
                               f"at least {min_samples} spanning a positive time are needed)")


def median_step_s(t_s: np.ndarray) -> float:
    d = np.diff(t_s)
    d = d[d > 0]
    return float(np.median(d)) if d.size else float("nan")


def segments(t_s: np.ndarray, ok: np.ndarray, max_gap_s: float) -> list[tuple[int, int]]:
    """[start, end) index ranges of runs of ``ok`` samples without time gaps longer than ``max_gap_s``."""
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    new = np.ones(idx.size, dtype=bool)
    new[1:] = (np.diff(idx) > 1) | (np.diff(t_s[idx]) > max_gap_s)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], idx.size)
    return [(int(idx[s]), int(idx[e - 1]) + 1) for s, e in zip(starts, ends, strict=True)]


def smooth_track(t_s: np.ndarray, pos_m: np.ndarray, *, window_s: float = 1.0, order: int = 3
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed position and velocity of a track on a uniform time grid.

    The finite samples are linearly resampled to a uniform grid at their median step (gaps included:
    a masked span is bridged linearly), then smoothed and differentiated with a Savitzky-Golay filter
    of about ``window_s`` seconds. Returns (t_grid (K,), pos (K, 3) [m], vel (K, 3) [m/s]).
    """
    ok = np.all(np.isfinite(pos_m), axis=1)
    t, p = t_s[ok], pos_m[ok]
    dt = median_step_s(t)
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    tg = t[0] + np.arange(n) * dt
    pg = np.stack([np.interp(tg, t, p[:, k]) for k in range(3)], axis=1)
    win = max(int(round(window_s / dt)) | 1, order + 2 + (order % 2 == 0))
    win += 1 - win % 2
    if n < win:
        return tg, pg, np.gradient(pg, tg, axis=0) if n > 1 else np.zeros_like(pg)
    ps = savgol_filter(pg, win, order, axis=0, mode="interp")
    vs = savgol_filter(pg, win, order, deriv=1, delta=dt, axis=0, mode="interp")
    return tg, ps, vs


def rounded(x: float, digits: int = 6) -> float:
    """A float rounded to ``digits`` significant digits (tidy YAML)."""
    x = float(x)
    if x == 0 or not np.isfinite(x):
        return x
    return float(f"{x:.{digits}g}")
