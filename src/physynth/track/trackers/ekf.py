"""``ekf``: an extended Kalman filter on the grid, with range updates gated by a chi-square test.

State ``[p (3), v (3)]`` in the trace's relative ENU frame [m, m/s]. Between grid steps (``dt = 1/rate``):

- constant velocity: white acceleration of spectral density ``accel_psd_m2ps3`` [m^2 s^-3] per axis;
- IMU-driven (``use_imu`` and the trace has IMU): the bin-mean acceleration is the control input and
  the process noise is the accelerometer's (``imu_accel_psd_m2ps3``).

Every fresh range of a step is one scalar update ``r = ||p - age_i v - a_i|| + e``, ``e ~ N(0,
range_std_m^2)``, where ``age_i`` (the AoI at the step, < one grid step) dates the range within its bin;
an update whose normalised innovation squared exceeds the ``gate_prob`` quantile of chi-square(1) is
rejected. After ``reset_after`` consecutive rejections the position covariance is re-inflated (the
filter has lost track). The filter starts at the first multilateration fix (:mod:`.ls`).

The recursion is sequential by nature (one small update per fresh range); everything per step is a
6x6 matrix product, about 2 s for a 250 s run at 100 Hz.
"""

from __future__ import annotations

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

        ls_pos = LsTracker(block_steps=32).predict(inp) - inp.ref_enu_m
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
