"""The antenna sway (``uwb.antenna_sway_*``) from the time structure of the LOS residuals.

The LOS residual of a real run, once its range law and its (run, anchor) mean are removed, is not white:
on the four Hanyang walks its autocorrelation is 0.94-0.95 one attempt (0.1 s) apart and falls about
exponentially with the time between the attempts (0.57-0.64 at 1 s, 0.35-0.48 at 2 s, 0-0.3 at 5 s),
and the four anchors' residuals move together (correlation 0.75-0.92). A white LOS error of the same
spread gives trackers ranges whose errors average out, which the real ones do not. The generator's
antenna sway (:func:`physynth.models.uwb.antenna_sway`) is that slow part: a 3-D Ornstein-Uhlenbeck
offset of the antenna, seen by every anchor along its line of sight.

Fit: the autocovariance C(dt) of the LOS residuals, pooled over anchors and runs from pairs of rows of
one (run, anchor) sequence up to :data:`MAX_LAG_S` apart, binned by their time difference in bins of
:data:`LAG_BIN_S`; then log C(dt) = log s^2 - dt / tau by least squares weighted by the pairs per bin,
over the bins with C > 0 up to :data:`FIT_MAX_LAG_S`. The sway's std is s (the std along a line of sight
of an isotropic offset, per axis), its correlation time tau; the white rest C(0) - s^2 stays in the LOS
std. Kept when the slow part carries at least :data:`MIN_SLOW_SHARE` of C(0) and tau spans at least two
bins; otherwise 0 (white LOS errors, as before) with a note.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

LAG_BIN_S = 0.1
"""Width of the time-difference bins of the autocovariance [s]."""
MAX_LAG_S = 3.0
"""Longest time difference whose pairs are summed [s]."""
FIT_MAX_LAG_S = 2.0
"""Longest time difference the exponential is fitted to [s] (beyond it the (run, anchor) mean removal
bends the autocovariance down)."""
MIN_SLOW_SHARE = 0.2
"""Smallest share of the LOS variance the slow part must carry to be kept."""
MIN_PAIRS_PER_BIN = 50
MAX_ROW_LAG = 200
"""Rows apart whose pairs are summed at most (a bound on the work; MAX_LAG_S usually ends it first)."""


def _autocovariance(seqs: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, float, int]:
    """(sum of products, pair counts) per time-difference bin, sum of squares and rows, pooled."""
    nb = int(round(MAX_LAG_S / LAG_BIN_S)) + 1
    sums, counts, c0, n0 = np.zeros(nb), np.zeros(nb), 0.0, 0
    for x, t in seqs:  # one (run, anchor) sequence at a time
        if x.size < 10:
            continue
        x = x - x.mean()
        c0 += float(x @ x)
        n0 += x.size
        for k in range(1, min(MAX_ROW_LAG, x.size)):  # rows k apart, while any pair is within MAX_LAG_S
            dt = t[k:] - t[:-k]
            b = np.floor(dt / LAG_BIN_S + 0.5).astype(np.int64)
            m = b < nb
            if not m.any():
                break
            sums += np.bincount(b[m], weights=x[k:][m] * x[:-k][m], minlength=nb)[:nb]
            counts += np.bincount(b[m], minlength=nb)[:nb]
    return sums, counts, c0, n0


def fit_antenna_sway(seqs: Iterable[tuple[np.ndarray, np.ndarray]]) -> dict[str, Any]:
    """Sway std [m] and correlation time [s] from LOS residual sequences (residual [m], time [s]) of one
    anchor in one run, each with its range law removed. Returns a dict with ``identifiable``,
    ``std_m``, ``tau_s``, the white remainder ``white_std_m`` and the binned autocorrelation."""
    sums, counts, c0, n0 = _autocovariance(seqs)
    out: dict[str, Any] = {"method": __doc__.split("Fit: ", 1)[1].split("\n\n")[0].replace("\n", " "),
                           "n_rows": n0, "lag_bin_s": LAG_BIN_S}
    if n0 < 100:
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None, "why": "fewer than 100 LOS rows"}
    var0 = c0 / n0
    lag = np.arange(sums.size) * LAG_BIN_S
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sums / counts
    out["autocorrelation"] = {f"{dt:.1f}": (None if not np.isfinite(c) else round(float(c / var0), 4))
                              for dt, c in zip(lag[1:], cov[1:], strict=True)}
    use = (lag > 0) & (lag <= FIT_MAX_LAG_S + 1e-9) & (counts >= MIN_PAIRS_PER_BIN) & (cov > 0)
    if use.sum() < 3:
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None,
                "why": "the LOS residuals are not positively correlated over a few bins"}
    w = counts[use]
    a = np.stack([np.ones(use.sum()), -lag[use]], axis=1)
    sw = np.sqrt(w)
    (log_s2, inv_tau), *_ = np.linalg.lstsq(a * sw[:, None], np.log(cov[use]) * sw, rcond=None)
    s2 = float(np.exp(log_s2))
    tau = float(1.0 / inv_tau) if inv_tau > 0 else np.inf
    share = s2 / var0
    out.update(var_m2=var0, slow_share=share)
    if not (np.isfinite(tau) and tau >= 2 * LAG_BIN_S and share >= MIN_SLOW_SHARE):
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None if not np.isfinite(tau) else tau,
                "why": f"no slow part to fit (share {share:.2f}, tau {tau:.3g} s): white LOS errors kept"}
    s2 = min(s2, var0)
    return {**out, "identifiable": True, "std_m": float(np.sqrt(s2)), "tau_s": tau,
            "white_std_m": float(np.sqrt(max(var0 - s2, 0.0)))}
