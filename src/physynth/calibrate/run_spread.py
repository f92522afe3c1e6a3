"""What changes from one recording to the next in the ranging error: per-run offsets and per-run tilts
of the range law, as random effects.

Several runs of one site each read their own level (a truth system or tag antenna moved, an anchor
re-surveyed) and their own growth of the error with range (the received-power bias of leading-edge
timing, 13-15 cm per decade of range in one Hanyang walk against 20-26 cm in the three others). Each is
measured per (run, anchor) cell on the rows the anchor's mixture calls LOS, with the cell's sampling
variance from the scatter over blocks in time, and split by REML into a run-to-run spread common to
the anchors of a run and a per-anchor remainder; generation draws both per synthetic trace
(``uwb.run_*offset_std_m``, ``uwb.run_*slope_std_m``; :mod:`physynth.models.uwb`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.optimize import minimize

RUN_OFFSET_MAX_BLOCKS = 10
"""Sampling variance of a run's mean LOS residual: batch means over at most this many blocks in time."""
RUN_OFFSET_BLOCK_ROWS = 50
"""... of at least this many rows each (at least two blocks)."""
RUN_OFFSET_LR_MIN = 10.0
"""REML likelihood-ratio statistic (spreads vs none) below which both run-to-run spreads are 0."""


def batch_mean_var(x: np.ndarray, floor: float) -> float:
    """Variance of the mean of ``x`` (rows in time order) from the scatter of its block means.

    Slow error components (NLOS episodes, misclassified rows) make it larger than sigma^2 / n; the
    block means see them, up to the block length. At least ``floor``.
    """
    b = int(np.clip(x.size // RUN_OFFSET_BLOCK_ROWS, 2, RUN_OFFSET_MAX_BLOCKS))
    means = np.array([blk.mean() for blk in np.array_split(x, b)])  # b <= 10 blocks
    return max(float(means.var(ddof=1)) / b, floor)


def reml_two_way(y: np.ndarray, anchor: np.ndarray, run: np.ndarray,
                  v: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """REML of y = mu_anchor + u_run + e_cell + eps, u ~ N(0, s_r), e ~ N(0, s_e), eps ~ N(0, v) known.

    Returns (s_r, s_e, BLUP of u_run + e_cell per cell, the REML profile at the optimum's corners).
    """
    n_a, n_r = int(anchor.max()) + 1, int(run.max()) + 1
    x = np.eye(n_a)[anchor]
    z = np.eye(n_r)[run]
    zz = z @ z.T
    scale = float(np.mean(v) + np.var(y))

    def parts(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        vm = scale * (q[0] * zz + np.diag(q[1] + v / scale))
        return vm, np.linalg.inv(vm)

    def nll(q: np.ndarray) -> float:
        vm, vi = parts(q)
        xtvx = x.T @ vi @ x
        p = vi - vi @ x @ np.linalg.solve(xtvx, x.T @ vi)
        return 0.5 * float(np.linalg.slogdet(vm)[1] + np.linalg.slogdet(xtvx)[1] + y @ p @ y)

    best = None
    for q0 in ((0.1, 0.1), (1.0, 0.01), (0.01, 1.0), (1e-4, 1e-4)):  # a few starts of a 2-parameter search
        res = minimize(nll, np.array(q0), method="L-BFGS-B", bounds=[(0.0, 1e3), (0.0, 1e3)])
        if best is None or res.fun < best.fun:
            best = res
    q = best.x
    vm, vi = parts(q)
    beta = np.linalg.solve(x.T @ vi @ x, x.T @ vi @ y)
    cov_re = scale * (q[0] * zz + q[1] * np.eye(y.size))
    blup = cov_re @ vi @ (y - x @ beta)
    profile = np.array([nll(np.array([0.0, 0.0])), nll(np.array([q[0], 0.0])), nll(np.array([0.0, q[1]])),
                        float(best.fun)])
    return float(scale * q[0]), float(scale * q[1]), blup, profile


MIN_DECADE_SPAN = 0.3
"""Rows of a (run, anchor) cell must span at least this many decades of range (a factor of 2) for its
range-law tilt to be measured."""

Cells = dict[tuple[str, str], float]
"""(run label, anchor id) -> a per-run value relative to the anchor's mean over the runs."""


def two_way_spread(raw: Mapping[tuple[str, str], tuple[float, float]], n_rows: Mapping[tuple[str, str], int],
                   labels: Sequence[str], *, unit: str) -> tuple[Cells, dict[str, Any]]:
    """Run-to-run spreads of a per-(run, anchor) quantity: (values to remove per cell, diagnostics).

    ``raw`` maps (run, anchor) to (value, variance of the value), ``n_rows`` to the cell's row count.
    Model: y_ra = mu_a + u_r + e_ra + eps_ra, u the part common to the anchors of a run, e the
    per-anchor remainder, eps the sampling error, whose variance is the cell's, pooled over the
    anchor's runs as a per-row variance (a few blocks in time are too few for one cell) and divided by
    the cell's rows. The spreads are the REML estimates; below :data:`RUN_OFFSET_LR_MIN` (likelihood
    ratio against no spread) both are 0 and nothing is removed. The values removed are each run's own
    (the anchor's mean over runs subtracted). Diagnostic keys: ``run_std``, ``run_anchor_std`` (in
    ``unit``), ``per_run``, ``run_means``, ``removed``, ``blup``, ``reml_lr_vs_no_spread``, ``significant``.
    """
    ids = sorted({a for _, a in raw})
    runs = [lab for lab in labels if any((lab, a) in raw for a in ids)]
    centred: Cells = {}
    for aid in ids:
        vals = [raw[(lab, aid)][0] for lab in runs if (lab, aid) in raw]
        mean = float(np.mean(vals)) if vals else 0.0
        for lab in runs:
            if (lab, aid) in raw:
                centred[(lab, aid)] = raw[(lab, aid)][0] - mean
    diag: dict[str, Any] = {"unit": unit, "per_run": {lab: {a: centred[(lab, a)] for a in ids if (lab, a) in centred}
                                                      for lab in runs}}
    shared = [a for a in ids if sum((lab, a) in raw for lab in runs) >= 2]
    if len(runs) < 2 or not shared:
        diag.update(identifiable=False, why="fewer than two runs share an anchor", run_std=0.0, run_anchor_std=0.0)
        return {}, diag
    cells = [(lab, a) for lab in runs for a in shared if (lab, a) in raw]
    y = np.array([raw[k][0] for k in cells])
    n = np.array([n_rows[k] for k in cells], dtype=float)
    infl = {a: float(np.mean([raw[k][1] * n_rows[k] for k in cells if k[1] == a])) for a in shared}
    v = np.array([infl[a] for _, a in cells]) / n
    s_r, s_e, blup, prof = reml_two_way(y, np.array([shared.index(a) for _, a in cells]),
                                         np.array([runs.index(lab) for lab, _ in cells]), v)
    lr = float(2.0 * (prof[0] - prof[3]))
    significant = lr >= RUN_OFFSET_LR_MIN
    if not significant:  # the sampling errors explain the table: no spread, nothing removed
        s_r, s_e = 0.0, 0.0
    removed: Cells = {k: (centred[k] if significant else 0.0) for k in cells}
    diag.update(identifiable=True, n_runs=len(runs), n_anchors=len(shared),
                run_means={lab: float(np.mean([centred[(lab, a)] for a in shared if (lab, a) in centred]))
                           for lab in runs},
                run_std=float(np.sqrt(s_r)), run_anchor_std=float(np.sqrt(s_e)), sampling_var=float(np.mean(v)),
                sampling_var_per_cell={f"{r} {a}": float(x) for (r, a), x in zip(cells, v, strict=True)},
                removed={f"{r} {a}": removed[(r, a)] for r, a in cells},
                blup={f"{r} {a}": float(b) for (r, a), b in zip(cells, blup, strict=True)},
                reml_lr_vs_no_spread=lr, significant=significant)
    return removed, diag


def _slope(d: np.ndarray, x: np.ndarray) -> float:
    dc = d - d.mean()
    return float(dc @ (x - x.mean())) / float(dc @ dc)


def cell_slope(x: np.ndarray, decades: np.ndarray) -> tuple[float, float, float] | None:
    """Least-squares slope of residuals ``x`` on log10 range ``decades`` (rows in time order), its
    sampling variance by a delete-one-block jackknife over up to :data:`RUN_OFFSET_MAX_BLOCKS` blocks in
    time (slow error components make it larger than the rows' scatter says), and the rows' mean log10
    range: (slope, variance, centre); None where the rows are too few or span less than
    :data:`MIN_DECADE_SPAN` decades of range."""
    if x.size < 2 * RUN_OFFSET_BLOCK_ROWS or np.ptp(decades) < MIN_DECADE_SPAN:
        return None
    b = int(np.clip(x.size // RUN_OFFSET_BLOCK_ROWS, 2, RUN_OFFSET_MAX_BLOCKS))
    keep = np.ones(x.size, dtype=bool)
    jack = []
    for blk in np.array_split(np.arange(x.size), b):  # b <= 10 fits without one block each
        keep[blk] = False
        if np.ptp(decades[keep]) < MIN_DECADE_SPAN:
            return None
        jack.append(_slope(decades[keep], x[keep]))
        keep[blk] = True
    jack_a = np.array(jack)
    var = (b - 1) / b * float(((jack_a - jack_a.mean()) ** 2).sum())
    return _slope(decades, x), var, float(decades.mean())
