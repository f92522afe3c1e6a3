"""The burst schedule and the late stamps (a burst's ranges stamped late)."""

from __future__ import annotations

import numpy as np

from ...records import Reason, Uwb


def burst_times(t_start_s: float, t_end_s: float, burst_rate_hz: float, jitter_s: float, min_period_s: float,
                *, rng: np.random.Generator, phase_s: float | None = None) -> np.ndarray:
    """Tag burst start times in [t_start, t_end).

    The tag's clock locks the bursts to a fixed period (random phase at the start); each burst is
    displaced by its own Gaussian jitter of standard deviation ``jitter_s``, so consecutive periods
    scatter by ``sqrt(2) * jitter_s`` without the schedule drifting. Bursts keep at least
    ``min_period_s`` apart (room for every anchor slot).
    """
    period = 1.0 / burst_rate_hz
    n = int(np.ceil((t_end_s - t_start_s) * burst_rate_hz)) + 2
    first = rng.uniform(0.0, period) if phase_s is None else float(phase_s) % period
    t = np.arange(n, dtype=np.float64)  # t_start + first + period k, in one buffer (the same values)
    t *= period
    t += t_start_s + first
    if jitter_s > 0:
        jitter = rng.standard_normal(n)
        jitter *= jitter_s
        np.maximum(jitter, -0.45 * period, out=jitter)  # numpy.clip's values
        np.minimum(jitter, 0.45 * period, out=jitter)
        t += jitter
        gap = np.subtract(t[1:], t[:-1])  # numpy.diff's values
        np.maximum(gap, min_period_s, out=gap)
        np.cumsum(gap, out=t[1:])  # t_0 + the cumulative gaps, into t (t_0 itself stays)
        t[1:] += t[0]
        if not min_period_s >= 0:  # gaps of either sign: not sorted
            return t[(t >= t_start_s) & (t < t_end_s)]
    # sorted times (periods, or gaps of at least min_period_s >= 0): those in [t_start, t_end) are one run
    return t[t.searchsorted(t_start_s, side="left"):t.searchsorted(t_end_s, side="left")]


def late_stamps(rec: Uwb, prob: float, delay_s: float, *, rng: np.random.Generator, t_max_s: float = np.inf) -> Uwb:
    """``rec`` (rows in burst order, as :func:`uwb_record` writes them) with each burst, with probability
    ``prob``, a late one: its delivered ranges after the first stamped ``delay_s`` later, then every row
    sorted by stamp (stable). Every other column travels with its row: a range stays the one measured at
    its attempt (:class:`UwbParams`, late stamps). A row whose late stamp would pass ``t_max_s`` (the end
    of the truth) keeps its own, so that every stamp stays inside the truth span; one draw per burst from
    ``rng``, so the trace's other draws stay those without late stamps."""
    if rec.t_s.shape[0] == 0:
        return rec
    if rec.burst[0] < 0 or (rec.burst[1:] < rec.burst[:-1]).any():
        raise ValueError("late_stamps needs the rows of uwb_record: burst ids (no -1), in burst order")
    late_burst = rng.random(int(rec.burst[-1]) + 1) < prob
    rows = np.flatnonzero((rec.reason == np.int8(Reason.OK)) & late_burst.take(rec.burst))
    if rows.size:
        b = rec.burst.take(rows)
        rows = rows[1:][b[1:] == b[:-1]]  # each late burst's first delivered range keeps its stamp
        rows = rows[rec.t_s.take(rows) + delay_s <= t_max_s]
    if rows.size == 0:
        return rec
    t = rec.t_s.copy()
    t[rows] += delay_s
    order = np.argsort(t, kind="stable")
    return rec.rows(order, t_s=t.take(order))
