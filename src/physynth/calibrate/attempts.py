"""An anchor's ranging attempts, recorded or inferred from the burst schedule (:class:`AttemptTable`):
what the availability fits read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..records import Reason, Trace
from .uwb_fit import burst_ids


@dataclass(frozen=True, slots=True, kw_only=True)
class AttemptTable:
    """Ranging attempts of one trace on its burst grid: times (B,), attempted/heard (B, A)."""

    t_s: np.ndarray
    attempted: np.ndarray
    heard: np.ndarray
    recorded: bool  # True: attempt rows were in the data; False: inferred from the burst schedule
    burst_rate_hz: float


def has_attempt_rows(trace: Trace) -> bool:
    """Whether a trace records failed attempts (dropout/outage/no-link rows), as synthetic traces do."""
    r = trace.uwb.reason
    return bool(np.isin(r, (Reason.DROPOUT, Reason.OUTAGE, Reason.NO_LINK)).any())


def attempt_table(trace: Trace, burst_rate_hz: float) -> AttemptTable:
    """The (burst x anchor) attempt and heard matrices of a trace.

    With recorded attempt rows, every row is an attempt of its burst. Without, every anchor is taken
    as attempted in every burst (SOURCE.md: all Hanyang anchors are ranged in one burst) and bursts
    missing from the data (no row at all) are filled in on the burst period.
    """
    u = trace.uwb
    n_a = len(trace.anchors)
    b = burst_ids(trace)
    ids, inv = np.unique(b, return_inverse=True)
    nb = ids.size
    start = np.full(nb, np.inf)
    np.minimum.at(start, inv, u.t_s)
    recorded = has_attempt_rows(trace)
    if recorded:
        attempted = np.zeros((nb, n_a), dtype=bool)
        heard = np.zeros((nb, n_a), dtype=bool)
        attempted[inv, u.anchor] = True
        ok = u.valid
        heard[inv[ok], u.anchor[ok]] = True
        return AttemptTable(t_s=start, attempted=attempted, heard=heard, recorded=True,
                            burst_rate_hz=burst_rate_hz)
    ok = u.valid
    has_valid = np.zeros(nb, dtype=bool)
    has_valid[inv[ok]] = True
    # bursts with no valid row are not evidence of a burst: rebuild the grid from bursts with data
    keep = np.flatnonzero(has_valid)
    st = start[keep]
    period = 1.0 / burst_rate_hz
    k = np.maximum(np.round(np.diff(st) / period).astype(np.int64), 1)
    n_new = np.concatenate([[1], k])  # grid slots from the previous kept burst to this one
    pos = np.cumsum(n_new) - 1  # grid index of each kept burst
    total = int(pos[-1]) + 1
    grid_t = np.interp(np.arange(total), pos, st)
    remap = np.full(nb, -1)
    remap[keep] = pos
    heard = np.zeros((total, n_a), dtype=bool)
    rows = ok & (remap[inv] >= 0)
    heard[remap[inv[rows]], u.anchor[rows]] = True
    return AttemptTable(t_s=grid_t, attempted=np.ones((total, n_a), dtype=bool), heard=heard, recorded=False,
                        burst_rate_hz=burst_rate_hz)
