"""Run-to-run spread of the UWB time offset (the lag of the ranging stamps behind the truth).

The ranging radio and the truth system (RTK, motion capture) are synchronised anew for every run, so
the lag may differ from run to run. A residual taken at a lag that is off by ``d`` seconds is off by
``-g' d`` (``g'`` the range rate): spread out along the run, positive on the way out and negative on
the way back. One lag for every run leaves that in the channel's LOS spread; a lag per run, drawn from
the fitted spread, puts it where it belongs (``uwb.time_offset_std_s``).

Estimator. On the LOS rows of every anchor (pooled over runs), after removing each (run, anchor)
mean (the run's ranging offset) and a per-anchor line in range and in log10 range (the range bias,
either law), the residual at the pooled offset is regressed on ``-g'`` with one coefficient per run:
the run's correction ``d_r`` to the pooled lag.

Its standard error must hold for a slow ranging error. The antenna sway (``uwb.antenna_sway_*``) is
correlated over seconds and metres, and multiplied by the smooth range rate it does not average out
within a run: a lag-1 (AR(1)) inflation of the least-squares error left it 3 to 5 times too small (on
20 traces generated with one lag, Cochran's Q was 349 on 19 degrees of freedom and the calibration
invented a spread of 13 ms). Instead each run's rows, every anchor together (the sway is common to
the anchors), are cut into :data:`LAG_BLOCKS` blocks in time, and the run's lag is estimated again
with each block left out, the (run, anchor) means taken again without it (a delete-one-block
jackknife; the score summed per block with the means held fixed, batch means, comes out about 40 %
too small, since those means carry the slow error too; the range terms, pooled over every run, are held
at their fit). A block must outlast the error's correlation:
on walks with the Hanyang sway (``walk-hanyang``: length 20 m, about 20 s of walking) 5 blocks per
run of 4 minutes are calibrated, 10 are not. Five blocks give a run's variance on 4 degrees of
freedom, too few for Cochran's Q, whose terms then have heavy tails; the slow error is one process
of the site (the generator draws one sway for every run), so the ratio of the jackknife variance to
the independent-rows one (``variance_inflation``) is pooled over the runs (mean of the runs' ratios,
at least 1), each run's standard error is its independent-rows error times its square root, and
Q / dof is referred to F(dof, sum of the runs' blocks - 1) instead of chi^2 (the inflation is
estimated). The run's own jackknife error is kept as ``own_std_error_s``.

The spread is the DerSimonian-Laird random-effects estimate ``tau`` over runs; when Cochran's test
of "one lag for all runs" is not rejected at :data:`LAG_SPREAD_ALPHA`, ``tau`` is 0.
``mean_correction_s`` is the random-effects mean (weights ``1 / (se_r^2 + tau^2)``); the calibration
keeps its pooled lag as the centre and uses each run's deviation from that mean. On the four shared
Hanyang Trajectory_A runs: 0.183 / 0.187 / 0.167 / 0.175 s, each +- 0.016-0.018 s, Q = 0.8 on 3
degrees of freedom (p = 0.85): no spread (docs/calibration.md, "A lag per run").
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.stats import f as f_dist

from ..models.uwb import range_decades
from .run_spread import RUN_OFFSET_BLOCK_ROWS

LAG_SPREAD_ALPHA = 0.01
"""Cochran's Q test level below which the runs' lags are taken to differ."""
MIN_LOS_ROWS_PER_RUN = 50
"""A run with fewer LOS rows (over all anchors) gets no lag of its own."""
LAG_BLOCKS = 5
"""Blocks in time per run for the lag's jackknife (fewer where a block would hold under
:data:`~physynth.calibrate.run_spread.RUN_OFFSET_BLOCK_ROWS` rows; at least two): a block must outlast
the slow error's correlation in time (about 20 s for a walker's antenna sway on the real runs)."""


def _demean_blocks(x: np.ndarray, block: np.ndarray, n_blocks: int) -> np.ndarray:
    """``x`` (N,) or (N, K) minus the mean of its block (``block`` (N,) in 0..n_blocks-1)."""
    cnt = np.bincount(block, minlength=n_blocks).astype(float)
    if x.ndim == 1:
        return x - (np.bincount(block, weights=x, minlength=n_blocks) / np.maximum(cnt, 1.0))[block]
    sums = np.stack([np.bincount(block, weights=x[:, k], minlength=n_blocks) for k in range(x.shape[1])], axis=1)
    return x - (sums / np.maximum(cnt, 1.0)[:, None])[block]


def _row_clock(run: np.ndarray, t: np.ndarray | Sequence[np.ndarray] | None) -> np.ndarray:
    """Where each row of an anchor (``run`` its runs, rows of a run in time order) lies in its run: its
    time ``t`` (one array, or one per run in order), else its place among the anchor's rows of that run
    as a fraction (the attempts are regular, so about the fraction of the run's time)."""
    if t is not None:
        return np.asarray(t, dtype=float) if isinstance(t, np.ndarray) else np.concatenate(list(t))
    n = np.bincount(run)
    order = np.argsort(run, kind="stable")
    pos = np.empty(run.size)
    pos[order] = np.arange(run.size) - np.concatenate([[0], np.cumsum(n)[:-1]])[run[order]]
    return (pos + 0.5) / n[run]


def _time_blocks(run: np.ndarray, clock: np.ndarray, n_runs: int) -> tuple[np.ndarray, np.ndarray]:
    """Blocks in time within each run, every anchor's rows together (the slow error is common to the
    anchors): each run's rows, by time, cut into :data:`LAG_BLOCKS` equal counts. Returns (each row's
    block within its run, blocks per run)."""
    block = np.zeros(run.size, dtype=np.int64)
    n_blocks = np.zeros(n_runs, dtype=np.int64)
    for r in range(n_runs):
        rows = np.flatnonzero(run == r)
        n_blocks[r] = int(np.clip(rows.size // RUN_OFFSET_BLOCK_ROWS, 2, LAG_BLOCKS))
        for b, part in enumerate(np.array_split(rows[np.argsort(clock[rows], kind="stable")], n_blocks[r])):
            block[part] = b
    return block, n_blocks


def los_row_blocks(los: Mapping[str, np.ndarray], run_of_row: Mapping[str, np.ndarray],
                   t_of_row: Mapping[str, np.ndarray | Sequence[np.ndarray]] | None, keys: Sequence[str]) -> np.ndarray:
    """The block in time (numbered over every run) of each LOS row of the anchors ``keys``, stacked in
    that order: each run's rows, every anchor together, cut by time as for the per-run lags
    (:func:`_time_blocks`), so that a jackknife over them sees the slow error the anchors share."""
    run = np.concatenate([run_of_row[a][los[a]] for a in keys]).astype(np.int64)
    clock = np.concatenate([_row_clock(run_of_row[a], None if t_of_row is None else t_of_row.get(a))[los[a]]
                            for a in keys])
    n_runs = int(run.max()) + 1 if run.size else 0
    block, n_blocks = _time_blocks(run, clock, n_runs)
    return block + np.concatenate([[0], np.cumsum(n_blocks)[:-1]])[run]


def _random_effects(d: np.ndarray, se: np.ndarray, variance_dof: int) -> dict[str, Any]:
    """DerSimonian-Laird spread of the runs' lags, 0 unless Cochran's Q rejects one lag at
    :data:`LAG_SPREAD_ALPHA`, and the random-effects mean. The variances carry ``variance_dof``
    degrees of freedom (a jackknife over few blocks), so Q / dof is referred to F(dof, variance_dof)."""
    w = 1.0 / se**2
    mu_fe = float(np.sum(w * d) / np.sum(w))
    q = float(np.sum(w * (d - mu_fe) ** 2))
    df = d.size - 1
    c = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    tau2 = max((q - df) / c, 0.0) if c > 0 else 0.0
    p_value = float(f_dist.sf(q / df, df, variance_dof))
    significant = bool(p_value < LAG_SPREAD_ALPHA and tau2 > 0)
    if not significant:
        tau2 = 0.0
    w_re = 1.0 / (se**2 + tau2)
    return {"spread_s": float(np.sqrt(tau2)), "mean_correction_s": float(np.sum(w_re * d) / np.sum(w_re)), "q": q,
            "dof": df, "variance_dof": variance_dof, "p_value": p_value, "significant": significant}


def _stack(rows: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], los: Mapping[str, np.ndarray],
           run_of_row: Mapping[str, np.ndarray], t_of_row: Mapping[str, np.ndarray | Sequence[np.ndarray]] | None,
           keys: Sequence[str]) -> tuple[np.ndarray, ...]:
    """The LOS rows of the anchors ``keys`` stacked: residual, range columns (a line in range and in log10
    range per anchor), -g', run, (run, anchor) cell, the row's clock within its run."""
    y_parts, x_parts, gd_parts, cell_parts, run_parts, clock_parts = [], [], [], [], [], []
    for j, a in enumerate(keys):
        m = los[a]
        r, g, gd = (v[m] for v in rows[a])
        run = run_of_row[a][m]
        cols = np.zeros((r.size, 2 * len(keys)))
        cols[:, 2 * j] = g
        cols[:, 2 * j + 1] = range_decades(g)
        y_parts.append(r)
        x_parts.append(cols)
        gd_parts.append(-gd)
        run_parts.append(run)
        cell_parts.append(run * len(keys) + j)
        clock_parts.append(_row_clock(run_of_row[a], None if t_of_row is None else t_of_row.get(a))[m])
    return tuple(np.concatenate(p) for p in (y_parts, x_parts, gd_parts, run_parts, cell_parts, clock_parts))


def _lag_normal_equations(xb: np.ndarray, ld: np.ndarray, yd: np.ndarray, rc: np.ndarray,
                          n_lag: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(inverse of the normal matrix, coefficients) of yd on [xb, one column ld per run]; a lag column
    is ld on its run's rows and 0 elsewhere, so the normal equations are built from bincounts without
    the (rows x runs) matrix. None where a run's range rate never changes (its lag is not identifiable)."""
    l2 = np.bincount(rc, weights=ld * ld, minlength=n_lag)
    if np.any(l2 <= 0):
        return None
    k = xb.shape[1]
    normal = np.zeros((k + n_lag, k + n_lag))
    normal[:k, :k] = xb.T @ xb
    if k:
        cross = np.stack([np.bincount(rc, weights=xb[:, i] * ld, minlength=n_lag) for i in range(k)])
        normal[:k, k:] = cross
        normal[k:, :k] = cross.T
    normal[k:, k:] = np.diag(l2)
    rhs = np.concatenate([xb.T @ yd, np.bincount(rc, weights=ld * yd, minlength=n_lag)])
    a_inv = np.linalg.pinv(normal)
    return a_inv, a_inv @ rhs


def _run_jackknife(ld: np.ndarray, z: np.ndarray, cell: np.ndarray, block: np.ndarray, n_blk: int) -> float:
    """Delete-one-block jackknife variance of one run's lag, d = sum (ld - mean) (z - mean) / sum (ld - mean)^2
    with the means taken per (run, anchor) cell: each block in turn is left out and the cells' means are
    taken again without it (a cell mean is not known in advance, and a slow error moves it)."""
    _, c = np.unique(cell, return_inverse=True)
    nc = int(c.max()) + 1
    key = block * nc + c
    parts = [np.bincount(key, weights=w, minlength=n_blk * nc).reshape(n_blk, nc)
             for w in (np.ones_like(ld), ld, z, ld * z, ld * ld)]
    n, sl, sz, slz, sll = (p.sum(axis=0)[None, :] - p for p in parts)  # each block left out
    nn = np.maximum(n, 1.0)
    sxy = np.sum(np.where(n > 0, slz - sl * sz / nn, 0.0), axis=1)
    sxx = np.sum(np.where(n > 0, sll - sl * sl / nn, 0.0), axis=1)
    d = sxy / np.maximum(sxx, 1e-300)
    return (n_blk - 1) / n_blk * float(np.sum((d - d.mean()) ** 2))


def fit_run_lags(rows: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], los: Mapping[str, np.ndarray],
                 run_of_row: Mapping[str, np.ndarray], n_runs: int, *,
                 t_of_row: Mapping[str, np.ndarray | Sequence[np.ndarray]] | None = None) -> dict[str, Any] | None:
    """Per-run corrections to the pooled time offset and their run-to-run spread (module docstring).

    ``rows``: per anchor (residual [m] at the pooled offset, geometric range [m], range rate [m/s]),
    rows of each run in time order, runs in order; ``los``: per anchor, the LOS mask of those rows;
    ``run_of_row``: per anchor, the run index (0..n_runs-1) of each row; ``t_of_row``: per anchor, the
    time of each row (one array, or one per run in order), which places the blocks in time (without it,
    a row's place among its anchor's rows of the run stands for its time). Returns None with fewer
    than two runs with LOS rows; else a dict with ``correction_s`` (n_runs,) (NaN for a run without
    enough LOS rows), ``std_error_s`` (independent-rows error times the pooled inflation),
    ``own_std_error_s`` (the run's own jackknife), ``white_std_error_s`` (rows taken as independent),
    ``variance_inflation``, ``n_blocks`` (per run with a lag), ``spread_s`` (tau),
    ``mean_correction_s``, ``q``, ``dof``, ``variance_dof``, ``p_value``, ``significant``,
    ``lag1_autocorrelation`` (of the regression residuals; a diagnostic, no longer used).
    """
    keys = [a for a in rows if los[a].sum() > 10]
    if n_runs < 2 or not keys:
        return None
    y, xb, gd, run, cell, clock = _stack(rows, los, run_of_row, t_of_row, keys)
    run = run.astype(np.int64)
    usable = np.bincount(run, minlength=n_runs) >= MIN_LOS_ROWS_PER_RUN
    if usable.sum() < 2:
        return None
    keep = usable[run]
    y, xb, gd, run, cell, clock = y[keep], xb[keep], gd[keep], run[keep], cell[keep], clock[keep]
    idx = np.flatnonzero(usable)
    col = np.full(n_runs, -1)
    col[idx] = np.arange(idx.size)
    rc = col[run]  # the row's lag column
    n_lag, n_cell = idx.size, int(cell.max()) + 1
    xb_raw = xb
    xb = _demean_blocks(xb, cell, n_cell)  # the (run, anchor) means: each run's ranging offset
    carried = np.ptp(xb, axis=0) > 0  # a range column of an anchor seen at one range only carries nothing
    xb, xb_raw = xb[:, carried], xb_raw[:, carried]
    ld, yd = _demean_blocks(gd, cell, n_cell), _demean_blocks(y, cell, n_cell)
    solved = _lag_normal_equations(xb, ld, yd, rc, n_lag)
    if solved is None:
        return None
    a_inv, coef = solved
    k = xb.shape[1]
    resid = yd - xb @ coef[:k] - ld * coef[k:][rc]
    s2 = float(resid @ resid / max(yd.size - k - n_lag - n_cell, 1))
    white = np.sqrt(np.diag(a_inv)[k:] * s2)
    block, n_blocks = _time_blocks(rc, clock, n_lag)
    z = y - xb_raw @ coef[:k]  # the residual with the pooled range terms removed, cell means not yet
    own = np.sqrt([_run_jackknife(gd[m], z[m], cell[m], block[m], int(n_blocks[r]))
                   for r in range(n_lag) for m in [rc == r]])
    inflation = max(float(np.mean(own**2 / white**2)), 1.0)  # one slow error for the site: pooled over runs
    se = white * np.sqrt(inflation)
    d = coef[k:]
    same = (cell[1:] == cell[:-1])  # consecutive rows of one (run, anchor) sequence
    rho = float(np.sum(resid[1:][same] * resid[:-1][same]) / max(float(resid @ resid), 1e-300))
    corr, se_all, own_all, white_all = (np.full(n_runs, np.nan) for _ in range(4))
    corr[idx], se_all[idx], own_all[idx], white_all[idx] = d, se, own, white
    return {"correction_s": corr, "std_error_s": se_all, **_random_effects(d, se, int(np.sum(n_blocks - 1))),
            "own_std_error_s": own_all, "white_std_error_s": white_all, "variance_inflation": inflation,
            "n_blocks": n_blocks, "lag1_autocorrelation": rho, "n_los_rows": int(y.size)}


def refine_time_offset(rows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], los: dict[str, np.ndarray],
                       run_of_row: dict[str, np.ndarray] | None = None,
                       t_of_row: dict[str, list[np.ndarray]] | None = None) -> dict[str, Any] | None:
    """Least-squares correction of the time offset from the LOS rows.

    With r(offset) = range - g(t - offset), r(offset0 + d) ~ r(offset0) + g'(t) d; regressing r(offset0)
    on per-anchor intercepts and range slopes and on -g' gives d, a far more efficient estimate than
    the robust grid search. Its standard error: with ``run_of_row`` (per anchor, each row's run), a
    delete-one-block jackknife over blocks in time of each run, every anchor's rows together
    (:func:`los_row_blocks`; the antenna sway is slow and common to the
    anchors, so rows taken as independent make it 3-5 times too small), at least that independent-rows
    error (``white_std_error_s``); without, the independent-rows error. Also returns, per anchor, the
    sensitivity of the LOS mean and slope to the offset.
    """
    keys = [a for a in rows if los[a].sum() > 10]
    if not keys:
        return None
    blocks_r, blocks_x = [], []
    n_a = len(keys)
    for j, a in enumerate(keys):
        r, g, gd = (x[los[a]] for x in rows[a])
        x = np.zeros((r.size, 2 * n_a + 1))
        x[:, 2 * j] = 1.0
        x[:, 2 * j + 1] = g
        x[:, -1] = -gd
        blocks_r.append(r)
        blocks_x.append(x)
    y = np.concatenate(blocks_r)
    x = np.concatenate(blocks_x)
    if np.ptp(x[:, -1]) == 0:
        return None
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    s2 = float(resid @ resid / max(y.size - x.shape[1], 1))
    white = float(np.sqrt((np.linalg.pinv(x.T @ x) * s2)[-1, -1]))
    se, n_blocks = white, 0
    if run_of_row is not None:
        block = los_row_blocks(los, run_of_row, t_of_row, keys)
        n_blocks = int(block.max()) + 1
        jack = np.array([np.linalg.lstsq(x[block != b], y[block != b], rcond=None)[0][-1]
                         for b in range(n_blocks)])  # a few blocks per run
        se = max(float(np.sqrt((n_blocks - 1) / n_blocks * np.sum((jack - jack.mean()) ** 2))), white)
    sens = {}
    for a in keys:
        r, g, gd = (v[los[a]] for v in rows[a])
        b, m = np.polyfit(g, gd, 1) if np.ptp(g) > 0 else (0.0, float(np.mean(gd)))
        h = range_decades(g)
        bd = np.polyfit(h, gd, 1)[0] if np.ptp(h) > 0 else 0.0
        sens[a] = {"d_los_mean_per_s": float(m), "d_range_bias_per_s": float(b),
                   "d_range_bias_per_decade_per_s": float(bd)}
    return {"correction_s": float(coef[-1]), "std_error_s": se, "white_std_error_s": white,
            "jackknife_blocks": n_blocks, "n_los_rows": int(y.size), "sensitivity": sens}
