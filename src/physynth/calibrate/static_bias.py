"""Range-proportional bias from static range sweeps (the Hanyang ``Static_measurements``).

Each sweep file holds ~13 s of ranging at one known distance; the signed error of a file is the
median of ``range_m - true_distance_m`` (robust to its few outliers). The bias slope is the
least-squares line through the per-file medians against the true distance, with one intercept per
antenna height (the antenna pattern shifts the offset, not the clock-scale slope).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pandas as pd

from ._base import CalibrationError


def fit_static_range_bias(sweeps: str | os.PathLike | pd.DataFrame, *, environment: str = "LOS") -> dict[str, Any]:
    """Slope [m per m] of the static range error against distance, with its standard error.

    Parameters
    ----------
    sweeps
        The ``Static_measurements`` folder (read with :func:`physynth.importers.import_hanyang_static`)
        or the table it returns.
    environment
        ``"LOS"``, ``"NLOS"`` or ``"all"``.
    """
    if isinstance(sweeps, pd.DataFrame):
        df = sweeps
    else:
        from ..io.importers import import_hanyang_static

        df, _ = import_hanyang_static(sweeps)
    if environment != "all":
        df = df[df["environment"] == environment]
    if df.empty:
        raise CalibrationError(f"no static sweep rows for environment {environment}")
    err = df["range_m"].to_numpy() - df["true_distance_m"].to_numpy()
    g = df.assign(err=err).groupby("file").agg(err=("err", "median"), d=("true_distance_m", "first"),
                                                h=("height_m", "first"), n=("err", "size")).reset_index()
    heights = np.unique(g["h"].to_numpy())
    hidx = np.searchsorted(heights, g["h"].to_numpy())
    x = np.zeros((len(g), heights.size + 1))
    x[np.arange(len(g)), hidx] = 1.0
    x[:, -1] = g["d"].to_numpy()
    y = g["err"].to_numpy()
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    res = y - x @ coef
    dof = max(len(g) - x.shape[1], 1)
    s2 = float(res @ res / dof)
    cov = np.linalg.inv(x.T @ x) * s2
    return {
        "range_bias_per_m": float(coef[-1]),
        "std_error": float(np.sqrt(cov[-1, -1])),
        "environment": environment,
        "n_files": int(len(g)),
        "n_rows": int(g["n"].sum()),
        "distance_range_m": [float(g["d"].min()), float(g["d"].max())],
        "residual_std_m": float(np.sqrt(s2)),
        "intercept_per_height_m": {f"{h:.3f}": float(c) for h, c in zip(heights, coef[:-1], strict=True)},
        "method": "LS through per-file median errors vs true distance, one intercept per antenna height",
    }
