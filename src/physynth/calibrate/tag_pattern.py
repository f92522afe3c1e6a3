"""The tag antenna pattern (``uwb.tag_pattern_m``) from the LOS residuals of moving rows.

A carrier holds its tag antenna one way relative to its direction of travel, and an antenna's delay
depends on the direction the signal comes from: the range error then depends on the anchor's bearing
phi relative to the heading. On the shared Hanyang walks, ranges with the anchors ahead or behind are
longer than with the anchors beside the walker in each of the four runs (2 c2 = 1.9-6.2 cm run by run,
3.7 cm pooled), and the residuals step by up to as much within seconds at the turns, where the position
hardly changes (docs/calibration.md).

Model: b(phi) = c1 cos(phi) + s1 sin(phi) + c2 cos(2 phi) + s2 sin(2 phi)
(:func:`physynth.models.uwb.pattern_features`). Fit: the LOS rows of every (run, anchor) sequence
while the carrier moves (heading defined, horizontal speed >= ``TURN_MIN_SPEED_MPS``); within each
sequence its own intercept and slope on log10(range) are projected out of the residuals and of the four
terms (so neither a run's offset nor a range law can pass for a pattern), then one least-squares fit
pooled over the sequences. Its covariance by a delete-one-block jackknife over blocks of
:data:`BLOCK_S` of each run (the slow error is correlated over seconds and shared by a run's anchors).
Kept when the Wald statistic c' C^-1 c exceeds :data:`WALD_MIN` (chi-square, 4 degrees of freedom,
p = 0.001) on at least :data:`MIN_ROWS` rows and :data:`MIN_BLOCKS` blocks; then each term whose
coefficient is within :data:`TERM_MIN_SE` standard errors of 0 is set to 0 (on the four shared Hanyang
walks only cos(2 phi) stays: 18.4 +- 3.4 mm, the other three within 0.6 standard errors). The pipeline
always reports the fit and generates it only on request (``calibrate(..., tag_pattern=True)``).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from ..models.uwb import TURN_MIN_SPEED_MPS

BLOCK_S = 30.0
"""Length of the jackknife blocks [s] (several correlation lengths of the slow error at walking speed)."""
WALD_MIN = 18.47
"""Wald statistic above which the pattern is kept (chi-square with 4 degrees of freedom, p = 0.001)."""
MIN_ROWS = 500
"""Fewest moving LOS rows on which a pattern is fitted."""
MIN_BLOCKS = 8
"""Fewest jackknife blocks on which a pattern is fitted."""

COND_MAX = 1e6
"""Largest condition number of the (scaled) normal equations: beyond it the bearings do not vary enough."""
TERM_MIN_SE = 3.0
"""A kept pattern's term whose |coefficient| is below this many standard errors is set to 0."""

TERMS = ("cos", "sin", "cos2", "sin2")


def _project_out(x: np.ndarray, feats: np.ndarray, log_range: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x (N,) and feats (N, 4) with their least-squares fit on [1, log10 range] removed (one sequence)."""
    z = np.stack([np.ones_like(log_range), log_range - log_range.mean()], axis=1)
    both = np.concatenate([x[:, None], feats], axis=1)
    coef, *_ = np.linalg.lstsq(z, both, rcond=None)
    out = both - z @ coef
    return out[:, 0], out[:, 1:]


def fit_tag_pattern(sequences: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]]
                    ) -> dict[str, Any]:
    """Fit ``uwb.tag_pattern_m`` from (residual (N,), range (N,), features (N, 4), time (N,), speed (N,),
    run index) of the LOS rows of each (run, anchor) sequence (features:
    :func:`physynth.models.uwb.pattern_features` of each row's bearing relative to the heading).

    Returns the report section: ``identifiable``, ``kept``, ``coef_m`` (4,) (zeros when not kept),
    ``std_error_m``, ``wald``, ``n_rows``, ``n_blocks``, ``variance_reduction_frac``, ``per_run_coef_m``
    and ``why`` when not identifiable.
    """
    xs, fs, blocks, runs = [], [], [], []
    for x, g, feats, t, speed, run in sequences:  # one (run, anchor) sequence at a time
        moving = (speed >= TURN_MIN_SPEED_MPS) & np.isfinite(x) & (g > 0)
        if moving.sum() < 20:
            continue
        xr, fr = _project_out(x[moving], feats[moving], np.log10(g[moving]))
        xs.append(xr)
        fs.append(fr)
        blocks.append(np.stack([np.full(xr.size, run), np.floor(t[moving] / BLOCK_S).astype(np.int64)], axis=1))
        runs.append(np.full(xr.size, run))
    n = int(sum(x.size for x in xs))
    if n < MIN_ROWS:
        return {"identifiable": False, "kept": False, "coef_m": [0.0] * 4, "n_rows": n,
                "why": f"{n} moving LOS rows (at least {MIN_ROWS} needed)"}
    x, f = np.concatenate(xs), np.concatenate(fs)
    _, block = np.unique(np.concatenate(blocks), axis=0, return_inverse=True)
    block = block.reshape(-1)
    n_blocks = int(block.max()) + 1
    if n_blocks < MIN_BLOCKS:
        return {"identifiable": False, "kept": False, "coef_m": [0.0] * 4, "n_rows": n,
                "why": f"{n_blocks} blocks of {BLOCK_S:g} s (at least {MIN_BLOCKS} needed)"}
    # normal equations per block: the jackknife deletes one block's share from the totals
    xtx = np.zeros((n_blocks, 4, 4))
    xty = np.zeros((n_blocks, 4))
    np.add.at(xtx, block, f[:, :, None] * f[:, None, :])
    np.add.at(xty, block, f * x[:, None])
    tot_xx, tot_xy = xtx.sum(axis=0), xty.sum(axis=0)
    scale = np.sqrt(np.diag(tot_xx))
    if np.any(scale <= 0) or np.linalg.cond(tot_xx / np.outer(scale, scale)) > COND_MAX:
        return {"identifiable": False, "kept": False, "coef_m": [0.0] * 4, "n_rows": n,
                "why": "the anchors' bearings from the heading barely vary (a path along the anchors' line?)"}
    coef = np.linalg.solve(tot_xx, tot_xy)
    try:
        loo = np.linalg.solve(tot_xx[None] - xtx, (tot_xy[None] - xty)[..., None])[..., 0]
    except np.linalg.LinAlgError:  # one block holds all of some term's variation
        return {"identifiable": False, "kept": False, "coef_m": [0.0] * 4, "n_rows": n,
                "why": "one block of the data holds all the variation of a bearing term"}
    dev = loo - loo.mean(axis=0)
    cov = (n_blocks - 1) / n_blocks * dev.T @ dev
    wald = float(coef @ np.linalg.pinv(cov) @ coef)
    se = np.sqrt(np.diag(cov))
    kept = wald >= WALD_MIN
    terms = np.abs(coef) >= TERM_MIN_SE * se if kept else np.zeros(4, dtype=bool)
    run = np.concatenate(runs)
    per_run = {}
    for r in np.unique(run):
        m = run == r
        if m.sum() >= 50:
            per_run[int(r)] = [round(float(c), 5) for c in np.linalg.lstsq(f[m], x[m], rcond=None)[0]]
    resid = x - f @ coef
    return {"identifiable": True, "kept": bool(kept), "coef_m": np.where(terms, coef, 0.0).tolist(),
            "fitted_coef_m": coef.tolist(), "std_error_m": se.tolist(), "terms": list(TERMS),
            "terms_kept": [t for t, k in zip(TERMS, terms, strict=True) if k],
            "wald": wald, "wald_min": WALD_MIN, "n_rows": n, "n_blocks": n_blocks,
            "variance_reduction_frac": float(1.0 - resid.var() / x.var()), "per_run_coef_m": per_run,
            "method": (f"least squares on the moving LOS rows, each (run, anchor) sequence's intercept and slope on "
                       f"log10(range) projected out; covariance by a delete-one-block jackknife over {BLOCK_S:g} s "
                       f"blocks of each run; kept when the Wald statistic >= {WALD_MIN} (chi-square, 4 d.o.f., "
                       "p = 0.001)")}
