"""The classical trackers as first written (one scipy ``least_squares`` call per block of steps; one
6x6 propagation per grid step): the references the vectorised ``physynth.track.trackers.ls`` and
``physynth.track.trackers.ekf`` are checked against (``tests/test_track_fast.py``). Kept verbatim, except
that the reference EKF takes its first fix from the package's ``ls`` (tested on its own), so that the
comparison is of the filter recursion alone."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.stats import chi2

from physynth.track.inputs import TrackInput
from physynth.track.trackers.ekf import EkfTracker
from physynth.track.trackers.ls import LsTracker


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


class ReferenceLsTracker(LsTracker):
    """The package's ``ls`` (same options) with its first ``predict``."""

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


class ReferenceEkfTracker(EkfTracker):
    """The package's ``ekf`` (same options and ``fit``) with its first, per-step ``predict``."""

    def predict(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) ENU [m] filtered positions (NaN before the first fix)."""
        dt = 1.0 / inp.rate_hz
        imu = self.use_imu and inp.acc_mps2 is not None
        q = self.imu_accel_psd_m2ps3 if imu else self.accel_psd_m2ps3
        f = np.eye(6)
        f[:3, 3:] = dt * np.eye(3)
        qm = q * np.block([[dt**3 / 3 * np.eye(3), dt**2 / 2 * np.eye(3)],
                           [dt**2 / 2 * np.eye(3), dt * np.eye(3)]])
        bu = np.vstack([dt**2 / 2 * np.eye(3), dt * np.eye(3)])
        acc = np.nan_to_num(inp.acc_mps2, nan=0.0) if imu else None
        gate = float(chi2.ppf(self.gate_prob, df=1))
        var_r = self.range_std_m**2
        anchors = inp.anchor_pos_rel_m
        out = np.full((inp.n_steps, 3), np.nan)

        ls_pos = LsTracker(block_steps=32).predict(inp) - inp.ref_enu_m  # the start: the package's ls
        started = np.flatnonzero(np.all(np.isfinite(ls_pos), axis=1) & inp.fresh.any(axis=1)
                                 & (np.isfinite(inp.range_m).sum(axis=1) >= 3))
        if started.size == 0:
            return out
        k0 = int(started[0])
        x = np.concatenate([ls_pos[k0], np.zeros(3)])
        p = np.diag([self.init_pos_std_m**2] * 3 + [self.init_vel_std_mps**2] * 3)
        rejected = 0
        fresh_rows = [np.flatnonzero(row) for row in inp.fresh]  # list of small index arrays
        for k in range(k0, inp.n_steps):  # the filter recursion: sequential by nature
            if k > k0:
                x = f @ x
                if acc is not None:
                    x = x + bu @ acc[k]
                p = f @ p @ f.T + qm
            for i in fresh_rows[k]:
                r = inp.range_m[k, i]
                age = inp.aoi_s[k, i]  # the range was measured ``age`` before t_k: p(t_k) - v * age
                diff = x[:3] - age * x[3:] - anchors[i]
                d = float(np.sqrt(diff @ diff)) or 1e-9
                h = np.zeros(6)
                h[:3] = diff / d
                h[3:] = -age * h[:3]
                ph = p @ h
                s = float(h @ ph) + var_r
                nu = r - d
                if nu * nu / s > gate:
                    rejected += 1
                    if rejected >= self.reset_after:
                        p[:3, :3] += np.eye(3) * self.init_pos_std_m**2
                        rejected = 0
                    continue
                rejected = 0
                gain = ph / s
                x = x + gain * nu
                p = p - np.outer(gain, ph)
            out[k] = x[:3]
        return out + inp.ref_enu_m
