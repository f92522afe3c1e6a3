"""Range bias from static range sweeps (the Hanyang ``Static_measurements``).

Each sweep file holds ~13 s of ranging at one known distance; the signed error of a file is the
median of ``range_m - true_distance_m`` (robust to its few outliers). Two slopes are fitted by least
squares through the per-file medians, with one intercept per antenna height (the antenna pattern
shifts the offset, not the slope): against the true distance (``range_bias_per_m``, a clock-scale
error) and against its log10 (``range_bias_per_decade_m``, the received-power bias); the residual rms
of each says which law the sweeps follow.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pandas as pd

from ..models.uwb import range_decades
from ._base import CalibrationError


def fit_static_range_bias(sweeps: str | os.PathLike | pd.DataFrame, *, environment: str = "LOS") -> dict[str, Any]:
    """Slopes of the static range error against distance [m per m] and log10 distance [m per decade].

    Parameters
    ----------
    sweeps
        The ``Static_measurements`` folder (read with :func:`physynth.io.importers.import_hanyang_static`)
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
    y = g["err"].to_numpy()
    slopes, ses, rms, intercepts = {}, {}, {}, {}
    for key, regressor in (("range_bias_per_m", g["d"].to_numpy()),
                           ("range_bias_per_decade_m", range_decades(g["d"].to_numpy()))):
        x[:, -1] = regressor
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        res = y - x @ coef
        s2 = float(res @ res / max(len(g) - x.shape[1], 1))
        slopes[key] = float(coef[-1])
        ses[key] = float(np.sqrt((np.linalg.inv(x.T @ x) * s2)[-1, -1]))
        rms[key] = float(np.sqrt(s2))
        intercepts[key] = {f"{h:.3f}": float(c) for h, c in zip(heights, coef[:-1], strict=True)}
    return {
        **slopes,
        "std_error": ses["range_bias_per_m"],
        "std_errors": ses,
        "environment": environment,
        "n_files": int(len(g)),
        "n_rows": int(g["n"].sum()),
        "distance_range_m": [float(g["d"].min()), float(g["d"].max())],
        "residual_std_m": rms["range_bias_per_m"],
        "residual_std_per_law_m": rms,
        "intercept_per_height_m": intercepts["range_bias_per_m"],
        "intercept_per_height_per_law_m": intercepts,
        "method": "LS through per-file median errors vs true distance (range_bias_per_m) and vs log10 of it "
                  "(range_bias_per_decade_m), one intercept per antenna height",
    }
