"""Position-error statistics of Table IV, one definition for every method.

The error of an estimate at grid step ``k`` is the Euclidean distance ``||p_hat(t_k) - p(t_k)||`` [m] to
the truth interpolated at ``t_k``, over the scored steps (:meth:`TrackInput.eval_mask`: truth known, at
or after the first valid range). ``rmse_2d_m`` uses the east and north components only, ``rmse_v_m``
the vertical one only.
"""

from __future__ import annotations

import numpy as np

STAT_KEYS = ("rmse_m", "rmse_2d_m", "rmse_v_m", "mae_m", "p50_m", "p95_m")


def error_stats(est_enu_m: np.ndarray, truth_enu_m: np.ndarray, mask: np.ndarray | None = None) -> dict[str, float]:
    """RMSE, horizontal and vertical RMSE, MAE, median and 95th percentile [m] of the position error.

    ``est_enu_m`` and ``truth_enu_m`` are (K, 3) [m]; ``mask`` (K,) selects the scored steps. Steps
    where either is NaN are not scored; an estimate that is NaN on a scored step counts as missing
    and is reported in ``n_missing``.
    """
    est = np.asarray(est_enu_m, dtype=float)
    truth = np.asarray(truth_enu_m, dtype=float)
    m = np.all(np.isfinite(truth), axis=1) if mask is None else (np.asarray(mask, bool)
                                                                 & np.all(np.isfinite(truth), axis=1))
    have = np.all(np.isfinite(est), axis=1)
    use = m & have
    if not np.any(use):
        return {k: float("nan") for k in STAT_KEYS} | {"n_steps": 0, "n_missing": int(m.sum())}
    d = est[use] - truth[use]
    e = np.linalg.norm(d, axis=1)
    e2 = np.linalg.norm(d[:, :2], axis=1)
    return {
        "rmse_m": float(np.sqrt(np.mean(e**2))),
        "rmse_2d_m": float(np.sqrt(np.mean(e2**2))),
        "rmse_v_m": float(np.sqrt(np.mean(d[:, 2] ** 2))),
        "mae_m": float(np.mean(e)),
        "p50_m": float(np.percentile(e, 50)),
        "p95_m": float(np.percentile(e, 95)),
        "n_steps": int(use.sum()),
        "n_missing": int((m & ~have).sum()),
    }
