"""``ls``: robust multilateration per grid step.

At each grid step the position minimises the robust sum over the anchors whose newest range is younger
than ``max_aoi_s`` of ``f_scale^2 rho((||p - a_i|| - r_i)^2 / f_scale^2)`` (``rho`` the ``loss``:
``soft_l1`` by default, as in ``scipy.optimize.least_squares``) plus the same robust cost of a weak pull
``prior_weight * (p - p_warm)`` towards the warm start (the solution of the previous block of steps),
which keeps a step with fewer than three usable ranges where it was. With a height prior
(``TrackInput.height``) every step is solved a second time from its solution of the ranges alone, with the
vertical pulled towards the known height with weight ``range_std_m / height.std_m`` (a height measurement
as good as its spread, against ranges of ``range_std_m``).

Steps whose usable ranges are identical to the previous step's (ranges change at ~10 Hz, the grid runs
at 100 Hz) share its solution. The distinct steps are taken in blocks of ``block_steps``; every step of
a block is warm-started from (and pulled towards) the previous block's last solution. Only that chain of
block ends is solved one block after the other; every other step is then solved in one batch
(:func:`multilaterate`: trust-region Newton on all steps at once, each step with its own trust radius
and convergence test, converged to ``STEP_TOL_M`` = 1e-8 m), so there is no Python loop per step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import PhySynthError
from ..inputs import TrackInput
from .base import ProgressFn

LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
"""Robust losses rho(z) of ``scipy.optimize.least_squares``, z = (residual / f_scale)^2."""

STEP_TOL_M = 1e-8
"""A step has converged when its proposed Newton step (after the trust radius) is shorter than this [m]."""
INITIAL_RADIUS_M = 10.0
"""First trust radius of every step [m]: doubled after an accepted step, a quarter of the step after a
rejected one."""
MAX_ITER = 200
"""Iterations of the batched solver at most (a well-posed step converges in 5-20)."""


def _loss(z: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rho(z), rho'(z) and the Gauss-Newton weight max(rho' + 2 z rho'', 0) of ``loss``, elementwise."""
    if loss == "linear":
        one = np.ones_like(z)
        return z, one, one
    if loss == "soft_l1":
        t = 1.0 + z
        s = np.sqrt(t)
        return 2.0 * (s - 1.0), 1.0 / s, 1.0 / (t * s)
    if loss == "huber":
        big = z > 1.0
        sz = np.sqrt(np.where(big, z, 1.0))
        return np.where(big, 2.0 * sz - 1.0, z), np.where(big, 1.0 / sz, 1.0), np.where(big, 0.0, 1.0)
    if loss == "cauchy":
        t = 1.0 + z
        return np.log1p(z), 1.0 / t, np.maximum((1.0 - z) / (t * t), 0.0)
    if loss == "arctan":
        t = 1.0 + z * z
        return np.arctan(z), 1.0 / t, np.maximum((1.0 - 3.0 * z * z) / (t * t), 0.0)
    raise PhySynthError(f"unknown loss '{loss}' (choose from {', '.join(LOSSES)})")


def cost_terms(p: np.ndarray, ranges: np.ndarray, use: np.ndarray, anchors: np.ndarray, warm: np.ndarray,
               fs: float, w: np.ndarray, loss: str) -> tuple[np.ndarray, ...]:
    """Per-step robust cost (N,) at positions ``p`` (N, 3) and what the Newton step needs there: unit
    vectors u (N, A, 3), the weights of u u^T (N, A) and of I (N,) in the Hessian of the ranges, the
    gradient weights of u (N, A), and the prior's gradient (N, 3) and Hessian diagonal (N, 3).

    ``ranges``/``use`` (N, A): the ranges [m] and which of them count; ``anchors`` (A, 3); ``warm`` (N, 3)
    the prior's centre, ``w`` (3,) its weight per axis; ``fs`` the robust loss's scale [m] and ``loss`` its
    name (:data:`LOSSES`). The cost :func:`multilaterate` minimises, step by step."""
    diff = p[:, None, :] - anchors[None]  # (N, A, 3)
    d = np.maximum(np.sqrt(np.einsum("nai,nai->na", diff, diff)), 1e-9)
    f = np.where(use, d - ranges, 0.0)
    fp = w * (p - warm)
    rho, rho1, wgn = _loss(f * f / fs**2, loss)
    rho_p, rho1_p, wgn_p = _loss(fp * fp / fs**2, loss)
    cost = 0.5 * fs**2 * ((rho * use).sum(axis=1) + rho_p.sum(axis=1))
    g_a = rho1 * f * use
    curv = g_a / d  # the curvature of a range: rho' f / d (I - u u^T)
    return (cost, diff / d[..., None], wgn * use - curv, curv.sum(axis=1), g_a, w * rho1_p * fp,
            (w * w) * wgn_p)


def _newton_step(h: np.ndarray, g: np.ndarray, floor: float) -> np.ndarray:
    """-H^-1 g for symmetric (N, 3, 3) ``h``, with eigenvalues below ``floor`` raised to it.

    Where H - floor I is positive definite (leading minors, checked in closed form) the closed-form
    inverse; elsewhere (negative curvature across a ring of solutions) the eigendecomposition."""
    a, b, c = h[:, 0, 0], h[:, 0, 1], h[:, 0, 2]
    e, f, k = h[:, 1, 1], h[:, 1, 2], h[:, 2, 2]
    m1 = a - floor
    m2 = m1 * (e - floor) - b * b
    det_m = (m1 * ((e - floor) * (k - floor) - f * f) - b * (b * (k - floor) - f * c)
             + c * (b * f - (e - floor) * c))
    pd = (m1 > 0) & (m2 > 0) & (det_m > 0)
    # symmetric 3x3 inverse by cofactors (Cramer's rule), elementwise over the steps
    c00, c01, c02 = e * k - f * f, c * f - b * k, b * f - c * e
    c11, c12, c22 = a * k - c * c, b * c - a * f, a * e - b * b
    det = a * c00 + b * c01 + c * c02
    g0, g1, g2 = g[:, 0], g[:, 1], g[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        dx = -np.stack([c00 * g0 + c01 * g1 + c02 * g2, c01 * g0 + c11 * g1 + c12 * g2,
                        c02 * g0 + c12 * g1 + c22 * g2], axis=1) / det[:, None]
    if not pd.all():
        ev, vec = np.linalg.eigh(h[~pd])
        gi = g[~pd]
        dx[~pd] = -np.einsum("nij,nj->ni", vec, np.einsum("nji,nj->ni", vec, gi) / np.maximum(ev, floor))
    return dx


def multilaterate(ranges_m: np.ndarray, use: np.ndarray, anchor_pos_m: np.ndarray, x0_m: np.ndarray, *,
                  loss: str = "soft_l1", f_scale_m: float = 0.3,
                  prior_weight: float | np.ndarray = 1e-2) -> np.ndarray:
    """Positions (N, 3) [m] from ranges (N, A) [m] (``use`` (N, A) selects them) to anchors (A, 3) [m].

    Each step minimises its own robust cost (module docstring), pulled towards ``x0_m`` ((3,) or (N, 3)
    [m]), which is also the initial guess, with ``prior_weight`` (one weight, or one per axis: a known
    height is a strong pull of the vertical). Newton steps batched over the steps: the Hessian
    includes the curvature of the ranges (a tag in line with its anchors sits in a flat valley that
    Gauss-Newton crosses only slowly), its eigenvalues floored at half the prior's curvature; every step
    keeps its own trust radius (:data:`INITIAL_RADIUS_M`), accepts a step only when its cost does not
    rise, and leaves the batch when its step is shorter than :data:`STEP_TOL_M`.
    """
    ranges = np.asarray(ranges_m, float)
    use = np.asarray(use, bool)
    anchors = np.asarray(anchor_pos_m, float)
    n = ranges.shape[0]
    warm_all = np.array(np.broadcast_to(np.asarray(x0_m, float), (n, 3)))
    p_all = warm_all.copy()
    fs = float(f_scale_m)
    w = np.broadcast_to(np.asarray(prior_weight, float), (3,)).copy()
    floor = 0.5 * float(w.min()) ** 2  # eigenvalues of the Hessian at least half the prior's weakest curvature
    todo = np.arange(n)  # the working set: steps not yet converged, compressed as they finish
    p, warm, r, us = p_all, warm_all, ranges, use
    cost, *terms = cost_terms(p, r, us, anchors, warm, fs, w, loss)
    radius = np.full(n, INITIAL_RADIUS_M)
    eye = np.eye(3)
    for _ in range(MAX_ITER):
        u, hw, hi, g_a, g_p, h_p = terms
        h = np.matmul(u.transpose(0, 2, 1) * hw[:, None, :], u) + (hi[:, None] + h_p)[:, :, None] * eye
        g = np.einsum("na,nai->ni", g_a, u) + g_p
        dx = _newton_step(h, g, floor)
        step = np.sqrt(np.einsum("ni,ni->n", dx, dx))
        dx *= np.minimum(1.0, radius / np.maximum(step, 1e-300))[:, None]
        step = np.minimum(step, radius)
        p_new = p + dx
        c_new, *t_new = cost_terms(p_new, r, us, anchors, warm, fs, w, loss)
        ok = c_new <= cost
        p = np.where(ok[:, None], p_new, p)
        cost = np.where(ok, c_new, cost)
        terms = [np.where(ok.reshape((-1,) + (1,) * (t.ndim - 1)), tn, t) for t, tn in zip(terms, t_new, strict=True)]
        radius = np.where(ok, np.maximum(radius, 2.0 * step), step / 4.0)
        done = step < STEP_TOL_M
        if done.any():
            p_all[todo[done]] = p[done]
            keep = ~done
            todo, p, warm, r, us, cost, radius = (a[keep] for a in (todo, p, warm, r, us, cost, radius))
            terms = [t[keep] for t in terms]
            if todo.size == 0:
                break
    p_all[todo] = p
    return p_all


def _loss_one(z: float, loss: str) -> tuple[float, float, float]:
    """:func:`_loss` of one value, in plain floats."""
    if loss == "soft_l1":
        t = 1.0 + z
        s = math.sqrt(t)
        return 2.0 * (s - 1.0), 1.0 / s, 1.0 / (t * s)
    if loss == "linear":
        return z, 1.0, 1.0
    if loss == "huber":
        if z > 1.0:
            sz = math.sqrt(z)
            return 2.0 * sz - 1.0, 1.0 / sz, 0.0
        return z, 1.0, 1.0
    if loss == "cauchy":
        t = 1.0 + z
        return math.log1p(z), 1.0 / t, max((1.0 - z) / (t * t), 0.0)
    if loss == "arctan":
        t = 1.0 + z * z
        return math.atan(z), 1.0 / t, max((1.0 - 3.0 * z * z) / (t * t), 0.0)
    raise PhySynthError(f"unknown loss '{loss}' (choose from {', '.join(LOSSES)})")


def _terms_one(p: list[float], rs: list[float], an: list[list[float]], warm: list[float], fs: float,
               w: list[float], loss: str) -> tuple[float, list[tuple[float, ...]], list[tuple[float, float, float]]]:
    """:func:`cost_terms` of one step in plain floats: cost, per range (f, d, ux, uy, uz, rho', weight)
    and per axis of the prior (fp, rho', weight)."""
    cost = 0.0
    rows = []
    for r, a in zip(rs, an, strict=True):
        ex, ey, ez = p[0] - a[0], p[1] - a[1], p[2] - a[2]
        d = max(math.sqrt(ex * ex + ey * ey + ez * ez), 1e-9)
        f = d - r
        rho, rho1, wgn = _loss_one(f * f / (fs * fs), loss)
        cost += rho
        rows.append((f, d, ex / d, ey / d, ez / d, rho1, wgn))
    prior = []
    for c in range(3):
        fp = w[c] * (p[c] - warm[c])
        rho, rho1, wgn = _loss_one(fp * fp / (fs * fs), loss)
        cost += rho
        prior.append((fp, rho1, wgn))
    return 0.5 * fs * fs * cost, rows, prior


def _solve_one(rs: list[float], an: list[list[float]], warm: list[float], fs: float, w: list[float],
               loss: str) -> list[float]:
    """:func:`multilaterate` of one step (the same iteration in plain floats: no array overhead for the
    chain of block ends, which is solved one step after the other)."""
    floor = 0.5 * min(w) ** 2
    p = list(warm)
    cost, rows, prior = _terms_one(p, rs, an, warm, fs, w, loss)
    radius = INITIAL_RADIUS_M
    for _ in range(MAX_ITER):
        h = [[0.0] * 3 for _ in range(3)]
        g = [0.0, 0.0, 0.0]
        csum = 0.0
        for f, d, ux, uy, uz, rho1, wgn in rows:
            curv = rho1 * f / d
            csum += curv
            u = (ux, uy, uz)
            c = wgn - curv
            for i in range(3):
                g[i] += rho1 * f * u[i]
                for j in range(3):
                    h[i][j] += c * u[i] * u[j]
        for i, (fp, rho1p, wgnp) in enumerate(prior):
            h[i][i] += csum + w[i] * w[i] * wgnp
            g[i] += w[i] * rho1p * fp
        m1 = h[0][0] - floor
        m2 = m1 * (h[1][1] - floor) - h[0][1] * h[1][0]
        m = [[h[i][j] - (floor if i == j else 0.0) for j in range(3)] for i in range(3)]
        det_m = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                 + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
        if m1 > 0 and m2 > 0 and det_m > 0:  # Cramer's rule
            (a, b, c), (d_, e, f_), (g_, h_, k) = h
            co = (e * k - f_ * h_, -(d_ * k - f_ * g_), d_ * h_ - e * g_)
            det = a * co[0] + b * co[1] + c * co[2]
            inv = ((co[0], -(b * k - c * h_), b * f_ - c * e),
                   (co[1], a * k - c * g_, -(a * f_ - c * d_)),
                   (co[2], -(a * h_ - b * g_), a * e - b * d_))
            dx = [-(inv[i][0] * g[0] + inv[i][1] * g[1] + inv[i][2] * g[2]) / det for i in range(3)]
        else:
            ev, vec = np.linalg.eigh(np.array(h))
            dx = list(-(vec @ ((vec.T @ np.array(g)) / np.maximum(ev, floor))))
        step = math.sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2])
        if step > radius:
            dx = [x * (radius / step) for x in dx]
            step = radius
        p_new = [p[0] + dx[0], p[1] + dx[1], p[2] + dx[2]]
        c_new, rows_new, prior_new = _terms_one(p_new, rs, an, warm, fs, w, loss)
        if c_new <= cost:
            p, cost, rows, prior = p_new, c_new, rows_new, prior_new
            radius = max(radius, 2.0 * step)
        else:
            radius = step / 4.0
        if step < STEP_TOL_M:
            break
    return p


@dataclass(slots=True, kw_only=True)
class LsTracker:
    """Robust multilateration (see the module docstring). Distances [m], ages [s]."""

    max_aoi_s: float = 0.5
    loss: str = "soft_l1"
    f_scale_m: float = 0.3
    prior_weight: float = 1e-2
    block_steps: int = 64
    range_std_m: float = 0.15
    """Ranging noise [m] the height pseudo-measurement is weighed against (its weight ``range_std_m /
    height.std_m``, a range's being 1)."""
    name: str = "ls"

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> LsTracker:
        """Nothing to learn."""
        return self

    def predict(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) ENU [m]: one multilateration per grid step (NaN before the first range)."""
        return self.predict_rel(inp) + inp.ref_enu_m

    def predict_rel(self, inp: TrackInput, n_steps: int | None = None) -> np.ndarray:
        """(n, 3) [m] relative to ``inp.ref_enu_m`` on the first ``n_steps`` grid steps (default all).

        A step's solution depends on the steps before it and on the first step with three usable ranges
        (the start of the first block), so a prefix costs a prefix's time.
        """
        n_steps = inp.n_steps if n_steps is None else int(n_steps)
        r_d, use_d, idx, change, warms = self._blocks(inp, n_steps)
        sol = self._with_height(inp, r_d, use_d, multilaterate(
            r_d, use_d, inp.anchor_pos_rel_m, warms[np.arange(idx.size) // self.block_steps], loss=self.loss,
            f_scale_m=self.f_scale_m, prior_weight=self.prior_weight))
        out = sol[np.cumsum(change) - 1]
        out[inp.t_s[:n_steps] < inp.first_range_s] = np.nan
        return out

    def solve_step(self, inp: TrackInput, k: int) -> np.ndarray:
        """(3,) [m]: ``predict_rel(inp)[k]`` alone (the chain of block ends up to step ``k``, then one
        solve), for a step at or after the first range."""
        r_d, use_d, idx, _, warms = self._blocks(inp, k + 1)
        j = idx.size - 1  # step k's distinct step, solved as in the batch of predict_rel
        first = multilaterate(r_d[j:], use_d[j:], inp.anchor_pos_rel_m, warms[j // self.block_steps], loss=self.loss,
                              f_scale_m=self.f_scale_m, prior_weight=self.prior_weight)
        return self._with_height(inp, r_d[j:], use_d[j:], first)[0]

    def _with_height(self, inp: TrackInput, r_d: np.ndarray, use_d: np.ndarray, sol: np.ndarray) -> np.ndarray:
        """The solutions ``sol`` (D, 3) of the ranges alone, each solved again with the height term from
        itself at the known height (:meth:`weights`); unchanged without a height prior. In two stages
        because a height held from the start takes a dimension from the solver's way out of a wrong basin
        (the warm start of a block lies where the previous block ended)."""
        if inp.height is None:
            return sol
        start = sol.copy()
        start[:, 2] = inp.height_rel_m
        return multilaterate(r_d, use_d, inp.anchor_pos_rel_m, start, loss=self.loss, f_scale_m=self.f_scale_m,
                             prior_weight=self.weights(inp))

    def weights(self, inp: TrackInput) -> np.ndarray:
        """(3,) the pull of each axis towards its warm start: ``prior_weight``, and for the vertical with a
        height prior ``range_std_m / height.std_m`` (towards the prior's height)."""
        w = np.full(3, float(self.prior_weight))
        if inp.height is not None:
            w[2] = self.range_std_m / inp.height.std_m
        return w

    def _blocks(self, inp: TrackInput, n_steps: int):
        """The distinct steps of the first ``n_steps`` (ranges (D, A), use (D, A), their grid indices
        (D,), the change mask (n_steps,)) and the warm start of every block (the chain of block ends)."""
        use_all = np.isfinite(inp.range_m) & (inp.aoi_s <= self.max_aoi_s)
        r_all = np.where(use_all, inp.range_m, 0.0)
        anchors = inp.anchor_pos_rel_m
        use, r = use_all[:n_steps], r_all[:n_steps]
        key = np.where(use, r, -1.0)
        change = np.ones(n_steps, dtype=bool)
        change[1:] = np.any(key[1:] != key[:-1], axis=1)
        idx = np.flatnonzero(change)
        r_d, use_d = r[idx], use[idx]
        # the chain of block ends: block b starts from the last solution of block b - 1
        warms = np.empty((-(-idx.size // self.block_steps), 3))
        warms[0] = _initial_guess(r_all, use_all, anchors)  # from the first step with three ranges, wherever
        w = [float(self.prior_weight)] * 3
        for b, e in enumerate(np.arange(self.block_steps - 1, idx.size, self.block_steps)[: warms.shape[0] - 1]):
            warms[b + 1] = _solve_step(r_d[e], use_d[e], anchors, warms[b], self, w)
        return r_d, use_d, idx, change, warms


def _solve_step(r: np.ndarray, use: np.ndarray, anchors: np.ndarray, warm: np.ndarray, tr: LsTracker,
                w: list[float]) -> np.ndarray:
    """One step (ranges (A,), use (A,)) from ``warm`` (3,) with the options of ``tr`` and the per-axis
    pulls ``w`` (plain floats)."""
    return np.array(_solve_one(r[use].tolist(), anchors[use].tolist(), warm.tolist(), float(tr.f_scale_m),
                               w, tr.loss))


def _initial_guess(r: np.ndarray, use: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """A start for the first block: the best of eight horizontal starts at the mean first range."""
    full = np.flatnonzero(use.sum(axis=1) >= 3)
    if full.size == 0:
        return np.array([3.0, 0.0, 0.0])
    k = full[0]
    rr, uu = r[k], use[k]
    dist = float(np.mean(rr[uu]))
    ang = np.arange(8) * np.pi / 4  # eight starts, solved as one batch
    guess = np.stack([dist * np.cos(ang), dist * np.sin(ang), np.zeros(8)], axis=1)
    p = multilaterate(np.tile(rr, (8, 1)), np.tile(uu, (8, 1)), anchors, guess, prior_weight=1e-4)
    cost = np.sum((np.linalg.norm(p[:, None, :] - anchors[uu][None], axis=2) - rr[uu]) ** 2, axis=1)
    best, best_cost = np.zeros(3), np.inf
    for j in range(8):  # the first of the best, as one after the other
        if cost[j] < best_cost - 1e-9:
            best, best_cost = p[j], float(cost[j])
    return best
