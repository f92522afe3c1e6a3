"""``ls``: robust multilateration per grid step.

At each grid step the position minimises the robust (``soft_l1``) sum of squared range residuals
``||p - a_i|| - r_i`` over the anchors whose newest range is younger than ``max_aoi_s``, plus a weak pull
``prior_weight * (p - p_warm)`` towards the warm start (the solution of the previous block of steps),
which keeps a step with fewer than three usable ranges where it was.

Steps whose usable ranges are identical to the previous step's (ranges change at ~10 Hz, the grid runs
at 100 Hz) share its solution. The distinct steps are solved in blocks of ``block_steps``: one
``scipy.optimize.least_squares`` call per block with a sparse (block-diagonal) Jacobian, warm-started
from the previous block's last position, so there is no Python loop per step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix

from ..inputs import TrackInput
from .base import ProgressFn


def _block_problem(ranges: np.ndarray, use: np.ndarray, anchors: np.ndarray, warm: np.ndarray, prior_weight: float):
    n, a = ranges.shape
    ri, ai = np.nonzero(use)  # residual rows: (step, anchor) pairs that are used
    r_obs = ranges[ri, ai]
    a_pos = anchors[ai]
    m = ri.size

    def fun(x: np.ndarray) -> np.ndarray:
        p = x.reshape(n, 3)
        d = np.linalg.norm(p[ri] - a_pos, axis=1)
        return np.concatenate([d - r_obs, prior_weight * (p - warm).ravel()])

    def jac(x: np.ndarray) -> coo_matrix:
        p = x.reshape(n, 3)
        diff = p[ri] - a_pos
        d = np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-9)
        u = diff / d
        rows = np.concatenate([np.repeat(np.arange(m), 3), m + np.arange(3 * n)])
        cols = np.concatenate([(3 * ri[:, None] + np.arange(3)).ravel(), np.arange(3 * n)])
        vals = np.concatenate([u.ravel(), np.full(3 * n, prior_weight)])
        return coo_matrix((vals, (rows, cols)), shape=(m + 3 * n, 3 * n))

    return fun, jac


def multilaterate(ranges_m: np.ndarray, use: np.ndarray, anchor_pos_m: np.ndarray, x0_m: np.ndarray, *,
                  loss: str = "soft_l1", f_scale_m: float = 0.3, prior_weight: float = 1e-2) -> np.ndarray:
    """Positions (N, 3) [m] from ranges (N, A) [m] (``use`` (N, A) selects them) to anchors (A, 3) [m].

    Every step is pulled weakly towards ``x0_m`` (3,) [m], which is also the initial guess.
    """
    n = ranges_m.shape[0]
    warm = np.broadcast_to(np.asarray(x0_m, float), (n, 3))
    fun, jac = _block_problem(ranges_m, use, anchor_pos_m, warm, prior_weight)
    sol = least_squares(fun, warm.ravel().copy(), jac=jac, method="trf", loss=loss, f_scale=f_scale_m,
                        tr_solver="lsmr", x_scale=1.0, max_nfev=50)
    return sol.x.reshape(n, 3)


@dataclass(slots=True, kw_only=True)
class LsTracker:
    """Robust multilateration (see the module docstring). Distances [m], ages [s]."""

    max_aoi_s: float = 0.5
    loss: str = "soft_l1"
    f_scale_m: float = 0.3
    prior_weight: float = 1e-2
    block_steps: int = 64
    name: str = "ls"

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> LsTracker:
        """Nothing to learn."""
        return self

    def predict(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) ENU [m]: one multilateration per grid step (NaN before the first range)."""
        use = np.isfinite(inp.range_m) & (inp.aoi_s <= self.max_aoi_s)
        r = np.where(use, inp.range_m, 0.0)
        key = np.where(use, r, -1.0)
        change = np.ones(inp.n_steps, dtype=bool)
        change[1:] = np.any(key[1:] != key[:-1], axis=1)
        idx = np.flatnonzero(change)
        warm = _initial_guess(r[idx], use[idx], inp.anchor_pos_rel_m)  # later blocks warm-start
        sol = np.empty((idx.size, 3))
        for s in range(0, idx.size, self.block_steps):  # one solve per block of distinct steps
            sl = slice(s, s + self.block_steps)
            sol[sl] = multilaterate(r[idx][sl], use[idx][sl], inp.anchor_pos_rel_m, warm, loss=self.loss,
                                    f_scale_m=self.f_scale_m, prior_weight=self.prior_weight)
            warm = sol[sl][-1]
        seg = np.cumsum(change) - 1
        out = sol[seg] + inp.ref_enu_m
        out[inp.t_s < inp.first_range_s] = np.nan
        return out


def _initial_guess(r: np.ndarray, use: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """A start for the first block: the best of eight horizontal starts at the mean first range."""
    full = np.flatnonzero(use.sum(axis=1) >= 3)
    if full.size == 0:
        return np.array([3.0, 0.0, 0.0])
    k = full[0]
    rr, uu = r[k:k + 1], use[k:k + 1]
    dist = float(np.mean(rr[uu]))
    best, best_cost = np.zeros(3), np.inf
    for ang in np.arange(8) * np.pi / 4:  # eight starts, not one per step
        guess = np.array([dist * np.cos(ang), dist * np.sin(ang), 0.0])
        p = multilaterate(rr, uu, anchors, guess, prior_weight=1e-4)[0]
        cost = float(np.sum((np.linalg.norm(p - anchors[uu[0]], axis=1) - rr[0][uu[0]]) ** 2))
        if cost < best_cost - 1e-9:
            best, best_cost = p, cost
    return best
