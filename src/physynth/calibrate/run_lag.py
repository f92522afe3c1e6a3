"""Run-to-run spread of the UWB time offset (the lag of the ranging stamps behind the truth).

The ranging radio and the truth system (RTK, motion capture) are synchronised anew for every run, so
the lag may differ from run to run (on the four shared Hanyang Trajectory_A runs this estimator finds
0.167 to 0.187 s, each +- 0.005 s: no spread at 1 %). A residual taken at a lag that is off by ``d``
seconds is off by ``-g' d`` (``g'`` the range rate): spread out along the run, positive on the way out
and negative on the way back. One lag for every run leaves that in the channel's LOS spread; a lag per
run, drawn from the fitted spread, puts it where it belongs (``uwb.time_offset_std_s``).

Estimator. On the LOS rows of every anchor (pooled over runs), after removing each (run, anchor)
mean (the run's ranging offset) and a per-anchor line in range and in log10 range (the range bias,
either law), the residual at the pooled offset is regressed on ``-g'`` with one coefficient per run:
the run's correction ``d_r`` to the pooled lag. Its standard error is the least-squares one inflated by
``(1 + rho) / (1 - rho)`` for the lag-1 autocorrelation ``rho`` of the residuals (an AR(1)
approximation; the range rate is smooth, so the effective number of independent rows is that of the
residual). The spread is the DerSimonian-Laird random-effects estimate ``tau`` over runs; when
Cochran's Q test of "one lag for all runs" is not rejected at :data:`LAG_SPREAD_ALPHA`, ``tau`` is 0.
``mean_correction_s`` is the random-effects mean (weights ``1 / (se_r^2 + tau^2)``); the calibration
keeps its pooled lag as the centre and uses each run's deviation from that mean.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.stats import chi2

from ..models.uwb import range_decades

LAG_SPREAD_ALPHA = 0.01
"""Cochran's Q test level below which the runs' lags are taken to differ."""
MIN_LOS_ROWS_PER_RUN = 50
"""A run with fewer LOS rows (over all anchors) gets no lag of its own."""


def _demean_blocks(x: np.ndarray, block: np.ndarray, n_blocks: int) -> np.ndarray:
    """``x`` (N,) or (N, K) minus the mean of its block (``block`` (N,) in 0..n_blocks-1)."""
    cnt = np.bincount(block, minlength=n_blocks).astype(float)
    if x.ndim == 1:
        return x - (np.bincount(block, weights=x, minlength=n_blocks) / np.maximum(cnt, 1.0))[block]
    sums = np.stack([np.bincount(block, weights=x[:, k], minlength=n_blocks) for k in range(x.shape[1])], axis=1)
    return x - (sums / np.maximum(cnt, 1.0)[:, None])[block]


def fit_run_lags(rows: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], los: Mapping[str, np.ndarray],
                 run_of_row: Mapping[str, np.ndarray], n_runs: int) -> dict[str, Any] | None:
    """Per-run corrections to the pooled time offset and their run-to-run spread (module docstring).

    ``rows``: per anchor (residual [m] at the pooled offset, geometric range [m], range rate [m/s]),
    rows of each run in time order; ``los``: per anchor, the LOS mask of those rows; ``run_of_row``: per
    anchor, the run index (0..n_runs-1) of each row. Returns None with fewer than two runs with LOS
    rows; else a dict with ``correction_s`` (n_runs,) (NaN for a run without enough LOS rows),
    ``std_error_s``, ``spread_s`` (tau), ``mean_correction_s``, ``q``, ``p_value``, ``significant``,
    ``lag1_autocorrelation``.
    """
    keys = [a for a in rows if los[a].sum() > 10]
    if n_runs < 2 or not keys:
        return None
    y_parts, x_parts, gd_parts, blk_parts, run_parts = [], [], [], [], []
    for j, a in enumerate(keys):
        r, g, gd = (v[los[a]] for v in rows[a])
        run = run_of_row[a][los[a]]
        cols = np.zeros((r.size, 2 * len(keys)))
        cols[:, 2 * j] = g
        cols[:, 2 * j + 1] = range_decades(g)
        y_parts.append(r)
        x_parts.append(cols)
        gd_parts.append(-gd)
        run_parts.append(run)
        blk_parts.append(run * len(keys) + j)  # (run, anchor) block
    y, xb, gd = np.concatenate(y_parts), np.concatenate(x_parts), np.concatenate(gd_parts)
    run, blk = np.concatenate(run_parts), np.concatenate(blk_parts)
    per_run = np.bincount(run, minlength=n_runs)
    usable = per_run >= MIN_LOS_ROWS_PER_RUN
    if usable.sum() < 2:
        return None
    keep = usable[run]
    y, xb, gd, run, blk = y[keep], xb[keep], gd[keep], run[keep], blk[keep]
    idx = np.flatnonzero(usable)
    col = np.full(n_runs, -1)
    col[idx] = np.arange(idx.size)
    rc = col[run]  # the row's lag column
    n_lag, n_blk = idx.size, int(blk.max()) + 1
    # x = [range columns, one lag column per run]; a lag column is -g' on its run's rows and 0 elsewhere,
    # and stays so after the (run, anchor) means are removed, so the normal equations are built from
    # bincounts without the (rows x runs) matrix
    xb = _demean_blocks(xb, blk, n_blk)
    xb = xb[:, np.ptp(xb, axis=0) > 0]  # a range column of an anchor seen at one range only carries nothing
    ld, yd = _demean_blocks(gd, blk, n_blk), _demean_blocks(y, blk, n_blk)
    l2 = np.bincount(rc, weights=ld * ld, minlength=n_lag)
    if np.any(l2 <= 0):
        return None  # a run whose range rate never changes: its lag is not identifiable
    k = xb.shape[1]
    normal = np.zeros((k + n_lag, k + n_lag))
    normal[:k, :k] = xb.T @ xb
    cross = np.stack([np.bincount(rc, weights=xb[:, i] * ld, minlength=n_lag) for i in range(k)]) if k else None
    if cross is not None:
        normal[:k, k:] = cross
        normal[k:, :k] = cross.T
    normal[k:, k:] = np.diag(l2)
    rhs = np.concatenate([xb.T @ yd, np.bincount(rc, weights=ld * yd, minlength=n_lag)])
    a_inv = np.linalg.pinv(normal)
    coef = a_inv @ rhs
    resid = yd - xb @ coef[:k] - ld * coef[k:][rc]
    dof = max(yd.size - k - n_lag - n_blk, 1)
    s2 = float(resid @ resid / dof)
    same = blk[1:] == blk[:-1]  # consecutive rows of one block
    rho = float(np.clip(np.sum(resid[1:][same] * resid[:-1][same]) / max(float(resid @ resid), 1e-300), 0.0, 0.95))
    cov = a_inv * s2 * (1.0 + rho) / (1.0 - rho)
    d = coef[k:]
    se = np.sqrt(np.diag(cov)[k:])
    w = 1.0 / se**2
    mu_fe = float(np.sum(w * d) / np.sum(w))
    q = float(np.sum(w * (d - mu_fe) ** 2))
    df = n_lag - 1
    c = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    tau2 = max((q - df) / c, 0.0) if c > 0 else 0.0
    p_value = float(chi2.sf(q, df))
    significant = bool(p_value < LAG_SPREAD_ALPHA and tau2 > 0)
    if not significant:
        tau2 = 0.0
    w_re = 1.0 / (se**2 + tau2)
    corr = np.full(n_runs, np.nan)
    corr[idx] = d
    se_all = np.full(n_runs, np.nan)
    se_all[idx] = se
    return {"correction_s": corr, "std_error_s": se_all, "spread_s": float(np.sqrt(tau2)),
            "mean_correction_s": float(np.sum(w_re * d) / np.sum(w_re)), "q": q, "dof": df, "p_value": p_value,
            "significant": significant, "lag1_autocorrelation": rho, "n_los_rows": int(y.size)}
