"""``ekf``: an extended Kalman filter on the grid, with range updates gated by a chi-square test.

State ``[p (3), v (3)]`` in the trace's relative ENU frame [m, m/s]. Between grid steps (``dt = 1/rate``):

- constant velocity: white acceleration of spectral density ``accel_psd_m2ps3`` [m^2 s^-3] per axis;
- IMU-driven (``use_imu`` and the trace has IMU): the bin-mean acceleration is the control input and
  the process noise is the accelerometer's (``imu_accel_psd_m2ps3``).

Every fresh range of a step is one scalar update ``r = ||p - age_i v - a_i|| + e``, ``e ~ N(0,
range_std_m^2)``, where ``age_i`` (the AoI at the step, < one grid step) dates the range within its bin;
an update whose normalised innovation squared exceeds the ``gate_prob`` quantile of chi-square(1) is
rejected. With a height prior (``TrackInput.height``, :mod:`physynth.track.height`) every update step ends
with one linear update of the vertical position towards the known height (variance ``height.std_m^2``,
never gated): anchors at nearly one height, or far away, leave the vertical to it. After ``reset_after``
consecutive rejections the position covariance is re-inflated (the
filter has lost track). The filter starts at the first multilateration fix (:mod:`.ls`).

Between two steps with a fresh range nothing but the prediction happens, so the filter jumps from one
such step to the next in closed form (F(T), Q(T) and the IMU control over T, exact: the composition of
the grid steps in between) and fills the steps in between vectorised from the last updated state. Only
the scalar updates run one after the other (a few thousand per trace, the one Python loop; in plain
floats): about 0.1 s for a 104 s cable-car trace with six anchors. ``tests/track_reference.py`` keeps
the per-step recursion it equals to 1e-9.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..inputs import TrackInput
from .base import ProgressFn
from .ls import LsTracker


@dataclass(slots=True, kw_only=True)
class EkfTracker:
    """Constant-velocity (or IMU-driven) EKF with chi-square gating; see the module docstring."""

    accel_psd_m2ps3: float = 0.5
    imu_accel_psd_m2ps3: float = 0.05
    range_std_m: float = 0.15
    gate_prob: float = 0.997
    reset_after: int = 20
    init_pos_std_m: float = 2.0
    init_vel_std_mps: float = 1.0
    use_imu: bool = True
    fit_range_std: bool = True
    max_coast_s: float = math.inf
    """Longest time [s] the output is extrapolated past the last range update; after it the position is
    held (the filter's own state still propagates in full). ``inf``: the constant-velocity (or IMU) path
    all the way, which carries the filter far off in a long outage of a tag that stopped."""
    reinit_m: float = 3.0
    """The filter restarts at the ``ls`` position when, for ``reinit_steps`` update steps in a row, it has been
    more than this far [m] from it (and more than three of its own position standard deviations), its
    position misfits the step's ranges (rms residual over two ``range_std_m``) and the multilateration's
    fits them at least twice as well: far from a compact or flat anchor layout a filter can lose the path
    and settle where its gate rejects every range. Where the ranges cannot tell the two apart (three
    anchors: the mirror image across their plane) it keeps its own. ``inf``: never."""
    reinit_steps: int = 10
    name: str = "ekf"

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> EkfTracker:
        """Set ``range_std_m`` to the robust spread (1.4826 MAD) of the training range residuals."""
        if not self.fit_range_std:
            return self
        res = []
        for inp in inputs:
            ok = inp.fresh & np.isfinite(inp.range_m) & np.all(np.isfinite(inp.pos_rel_m), axis=1)[:, None]
            k, a = np.nonzero(ok)
            geo = np.linalg.norm(inp.pos_rel_m[k] - inp.anchor_pos_rel_m[a], axis=1)
            res.append(inp.range_m[k, a] - geo)
        r = np.concatenate(res) if res else np.array([])
        if r.size > 20:
            self.range_std_m = float(max(1.4826 * np.median(np.abs(r - np.median(r))), 0.02))
        return self

    def predict(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) ENU [m] filtered positions (NaN before the first fix)."""
        return self.predict_rel(inp) + inp.ref_enu_m

    def predict_rel(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) [m] filtered positions relative to ``inp.ref_enu_m`` (NaN before the first fix)."""
        return self.predict_rel_var(inp)[0]

    def predict_rel_var(self, inp: TrackInput) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) [m] filtered positions relative to ``inp.ref_enu_m`` and (K,) the variance [m^2] of their
        vertical (NaN before the first fix).

        Between update steps the vertical variance grows as the prediction does, from the last update's
        ``P_zz + 2 T P_zv + T^2 P_vv + q T^3 / 3`` (T the time since it; held, like the position, past
        ``max_coast_s``)."""
        out = np.full((inp.n_steps, 3), np.nan)
        var = np.full(inp.n_steps, np.nan)
        fresh_any = inp.fresh.any(axis=1)
        started = np.flatnonzero((inp.t_s >= inp.first_range_s) & fresh_any
                                 & (np.isfinite(inp.range_m).sum(axis=1) >= 3))
        if started.size == 0:
            return out, var
        k0 = int(started[0])
        x0 = LsTracker(block_steps=32).solve_step(inp, k0)
        upd = k0 + np.flatnonzero(fresh_any[k0:])  # steps with a fresh range; upd[0] == k0
        ls = LsTracker().predict_rel(inp)[upd] if math.isfinite(self.reinit_m) else None
        states, pz = self.filter_updates(inp, k0, x0, upd, ls)
        # every step from the last update step's state, propagated without noise (vectorised)
        steps = np.arange(k0, inp.n_steps)
        j = np.searchsorted(upd, steps, side="right") - 1
        dt = 1.0 / inp.rate_hz
        if math.isfinite(self.max_coast_s):
            steps = np.minimum(steps, upd[j] + int(round(self.max_coast_s * inp.rate_hz)))
        pos_c, _ = self._control(inp, upd[j], steps)
        t = (steps - upd[j]) * dt
        out[k0:] = states[j, :3] + t[:, None] * states[j, 3:] + pos_c
        var[k0:] = pz[j, 0] + 2.0 * t * pz[j, 1] + t * t * pz[j, 2] + self._q(inp) * t**3 / 3.0
        return out, var

    def _q(self, inp: TrackInput) -> float:
        """The process noise density [m^2 s^-3] of this input (the IMU's when it drives the filter)."""
        return self.imu_accel_psd_m2ps3 if (self.use_imu and inp.acc_mps2 is not None) else self.accel_psd_m2ps3

    def _control(self, inp: TrackInput, m: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Effect on position and velocity (each (N, 3)) of the IMU control between steps ``m`` and ``k``.

        ``x_{j} = F(dt) x_{j-1} + [dt^2/2; dt] a_j`` for j = m+1 .. k gives ``dv = dt sum a_j`` and
        ``dp = dt^2 sum (k - j + 1/2) a_j``, from cumulative sums S(j) = sum_{i<=j} a_i and
        D(j) = sum_{i<=j} S(i): ``sum (k - j + 1) a_j = D(k) - D(m) - (k - m) S(m)``. Zero without IMU.
        """
        if not (self.use_imu and inp.acc_mps2 is not None):
            z = np.zeros((np.size(m), 3))
            return z, z
        s_cum, d_cum = _acc_sums(inp)
        dt = 1.0 / inp.rate_hz
        ds = s_cum[k] - s_cum[m]
        dp = dt * dt * (d_cum[k] - d_cum[m] - (k - m)[:, None] * s_cum[m] - 0.5 * ds)
        return dp, dt * ds

    def filter_updates(self, inp: TrackInput, k0: int, x0: np.ndarray, upd: np.ndarray,
                       ls: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """States (len(upd), 6) after the range updates (and the height update, with a height prior) of
        each step of ``upd``, and (len(upd), 3) their ``P_zz, P_zv, P_vv`` of the vertical: the filter
        started at step ``k0`` (``upd[0]``) at position ``x0`` (3,) [m, relative to ``inp.ref_enu_m``] at
        rest. ``ls`` (len(upd), 3): a multilateration at the update steps, where the filter restarts when
        it has lost the path (``reinit_m``); None: no restart. :meth:`predict_rel_var` runs it from the
        first fix.

        Between two update steps T = n dt apart the filter is linear: one jump with F(T) = [[I, T I],
        [0, I]], Q(T) = q [[T^3/3 I, T^2/2 I], [T^2/2 I, T I]] (the exact composition of n grid steps)
        and the control of :meth:`_control`. The scalar range updates run one after the other (the
        accepted per-range loop: a few thousand per trace), in plain floats: at this size a Python
        float is faster than a NumPy call, and nothing is allocated per update but the 6-vector P h.
        """
        dt = 1.0 / inp.rate_hz
        q = self._q(inp)
        height = inp.height_rel_m
        var_h = None if inp.height is None else inp.height.std_m ** 2
        gate = float(chi2.ppf(self.gate_prob, df=1))
        var_r = self.range_std_m**2
        reset = self.init_pos_std_m**2
        n_upd = upd.size
        gaps = np.diff(upd) * dt  # the jumps between consecutive update steps
        dp, dv = self._control(inp, upd[:-1], upd[1:])
        # the fresh ranges of the update steps, in step then anchor order (as the reference loop)
        rows, cols = np.nonzero(inp.fresh[upd])
        first = np.searchsorted(rows, np.arange(n_upd + 1))
        r_list = inp.range_m[upd[rows], cols].tolist()
        age_list = inp.aoi_s[upd[rows], cols].tolist()
        anchors = inp.anchor_pos_rel_m
        a_rows = [anchors[c] for c in cols.tolist()]

        x = [float(v) for v in x0] + [0.0, 0.0, 0.0]
        p0 = np.diag([self.init_pos_std_m**2] * 3 + [self.init_vel_std_mps**2] * 3).tolist()
        p = [row[:] for row in p0]
        states = np.empty((n_upd, 6))
        pz = np.empty((n_upd, 3))
        rejected = 0
        apart = 0  # update steps in a row far from the multilateration ``ls``
        ls_l = ls.tolist() if ls is not None else None
        reinit2 = self.reinit_m ** 2
        gaps_l, dp_l, dv_l = gaps.tolist(), dp.tolist(), dv.tolist()
        rng3, rng6 = range(3), range(6)
        for j in range(n_upd):  # sequential by nature: one jump, then the scalar updates of the step
            if j:
                t = gaps_l[j - 1]
                dpj, dvj = dp_l[j - 1], dv_l[j - 1]
                for i in rng3:
                    x[i] += t * x[i + 3] + dpj[i]
                    x[i + 3] += dvj[i]
                q3, q2, q1 = q * t**3 / 3.0, q * t * t / 2.0, q * t
                for i in rng3:  # P <- F(T) P F(T)^T + Q(T), block by block
                    pi, pv = p[i], p[i + 3]
                    for k in rng3:
                        a, b, c, e = pi[k], pi[k + 3], pv[k], pv[k + 3]
                        pi[k] = a + t * (b + c) + t * t * e
                        pi[k + 3] = b + t * e
                        pv[k] = c + t * e
                    pi[i] += q3
                    pi[i + 3] += q2
                    pv[i] += q2
                    pv[i + 3] += q1
            for u in range(first[j], first[j + 1]):
                age = age_list[u]  # the range was measured ``age`` before the step: p - v * age
                an = a_rows[u]
                e0, e1, e2 = x[0] - age * x[3] - an[0], x[1] - age * x[4] - an[1], x[2] - age * x[5] - an[2]
                d = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) or 1e-9
                h0, h1, h2 = e0 / d, e1 / d, e2 / d
                h3, h4, h5 = -age * h0, -age * h1, -age * h2
                ph = [r[0] * h0 + r[1] * h1 + r[2] * h2 + r[3] * h3 + r[4] * h4 + r[5] * h5 for r in p]
                s = h0 * ph[0] + h1 * ph[1] + h2 * ph[2] + h3 * ph[3] + h4 * ph[4] + h5 * ph[5] + var_r
                nu = r_list[u] - d
                if nu * nu / s > gate:
                    rejected += 1
                    if rejected >= self.reset_after:
                        for i in rng3:
                            p[i][i] += reset
                        rejected = 0
                    continue
                rejected = 0
                for i in rng6:
                    gi = ph[i] / s  # the gain
                    x[i] += gi * nu
                    row = p[i]
                    for k in rng6:
                        row[k] -= gi * ph[k]
            if var_h is not None:  # the known height: a linear update of p_z (h = e_z), never gated
                pzr = [r[2] for r in p]  # P e_z
                s = pzr[2] + var_h
                nu = height - x[2]
                for i in rng6:
                    gi = pzr[i] / s
                    x[i] += gi * nu
                    row = p[i]
                    for k in rng6:
                        row[k] -= gi * pzr[k]
            if ls_l is not None:
                lj = ls_l[j]
                d2 = (x[0] - lj[0]) ** 2 + (x[1] - lj[1]) ** 2 + (x[2] - lj[2]) ** 2
                far = d2 > reinit2 and d2 > 9.0 * (p[0][0] + p[1][1] + p[2][2])
                if far:  # and the ranges of this step say the multilateration is right, not only elsewhere
                    se_x = se_l = 0.0
                    for u in range(first[j], first[j + 1]):
                        an, r = a_rows[u], r_list[u]
                        se_x += (math.dist(x[:3], an) - r) ** 2
                        se_l += (math.dist(lj, an) - r) ** 2
                    n_r = max(first[j + 1] - first[j], 1)
                    far = se_x > 4.0 * var_r * n_r and se_l < 0.25 * se_x
                apart = apart + 1 if far else 0
                if apart >= self.reinit_steps and lj[0] == lj[0]:  # not NaN: restart there
                    x = [lj[0], lj[1], lj[2], 0.0, 0.0, 0.0]
                    p = [row[:] for row in p0]
                    apart = 0
            states[j] = x
            pz[j] = (p[2][2], p[2][5], p[5][5])
        return states, pz


def _acc_sums(inp: TrackInput) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative sums S(j) = sum_{i<=j} a_i and D(j) = sum_{i<=j} S(i) of the bin-mean acceleration (K, 3)."""
    s_cum = np.cumsum(np.nan_to_num(inp.acc_mps2, nan=0.0), axis=0)
    return s_cum, np.cumsum(s_cum, axis=0)
