"""The antenna sway (``uwb.antenna_sway_*``) from the time structure of the LOS residuals.

The LOS residual of a real run, once its range law and its (run, anchor) mean are removed, is not white:
on the four Hanyang walks its autocorrelation is 0.94-0.95 one attempt (0.1 s) apart and falls about
exponentially with the time between the attempts (0.57-0.64 at 1 s, 0.35-0.48 at 2 s, 0-0.3 at 5 s),
and the four anchors' residuals move together (correlation 0.75-0.92). A white LOS error of the same
spread gives trackers ranges whose errors average out, which the real ones do not. The generator's
antenna sway (:func:`physynth.models.uwb.antenna_sway`) is that slow part: a 3-D Ornstein-Uhlenbeck
offset of the antenna, seen by every anchor along its line of sight.

Fit: the LOS residuals of every (run, anchor) sequence are paired up to :data:`MAX_LAG_S` s apart, and the
pairs pooled in cells by time apart (bins of :data:`LAG_BIN_S` s), distance the tag travelled between them
(bins of :data:`LAG_BIN_M` m, from the truth velocity) and angle it turned (edges :data:`TURN_EDGES_RAD` rad,
from the truth body rate, or the direction of travel). The ``time`` clock: log C(dt) = log s^2 - dt / tau
fitted to the autocovariance by least squares weighted by the pairs, over 0.1-:data:`FIT_MAX_LAG_S` s.
The ``motion`` clock: the semivariogram gamma = E (x_i - x_j)^2 / 2 of the cells, var0 - gamma = s^2
exp(-(d / length + a / turn)), s^2 by weighted least squares at each point of a grid of length and turn
(no turn term, the ``distance`` clock, unless it removes :data:`MIN_TURN_GAIN` of the error). The clock
kept is the one whose model matches the cells' semivariogram better (pair-weighted squared error;
differences, so that a stop's pairs measure how much the error changed during it, not its one level); a
tie keeps the time clock. The sway's std is s (the std along a line of sight of an isotropic offset, per
axis); the white rest var0 - s^2 stays in the LOS std. Kept when the slow part carries at least
:data:`MIN_SLOW_SHARE` of var0 and its scale spans at least two bins; otherwise 0 (white LOS errors, as
before) with a note.

On the four shared Hanyang walks the motion clock wins (``python tools/sway_clock_check.py``; its
semivariogram error 4.4e-7 m^4 against 9.7e-7 for the time clock; length 20 m, turn 0.40 rad): the error
holds while the walker stands (pairs 0.2-3 s apart with under 5 cm travelled stay at the white floor,
0.0003 m^2, where the time clock predicts 0.0008-0.0026) and changes most where the walker turns (0.5-1 m
travelled: 0.0009 m^2 going straight, 0.0042 turning 0.3-0.6 rad, 0.0085 beyond 1 rad). A walker's slow
ranging error belongs to how the tag is carried towards each anchor (the body's shadow, the antenna's
pattern), not to the clock: on a carrier that stops, turns or moves faster, it follows the motion.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

LAG_BIN_S = 0.1
"""Width of the time-difference bins of the autocovariance [s]."""
MAX_LAG_S = 3.0
"""Longest time difference whose pairs are summed [s]."""
FIT_MAX_LAG_S = 2.0
"""Longest time difference the exponential is fitted to [s] (beyond it the (run, anchor) mean removal
bends the autocovariance down)."""
LAG_BIN_M = 0.1
"""Width of the travelled-distance-difference bins [m] (the ``distance`` clock)."""
MAX_LAG_M = 3.0
MIN_SLOW_SHARE = 0.2
"""Smallest share of the LOS variance the slow part must carry to be kept."""
MIN_PAIRS_PER_BIN = 50
MIN_CELL_PAIRS = 20
"""Fewest pairs of a (time, distance, angle) cell that the clocks are compared on."""
MIN_TURN_GAIN = 0.05
"""Share of the distance clock's semivariogram error the turn term must remove to be kept."""
"""Fewest pairs of a (time, distance, angle) cell that the clocks are compared on."""
MAX_ROW_LAG = 200
"""Rows apart whose pairs are summed at most (a bound on the work; MAX_LAG_S usually ends it first)."""


TURN_EDGES_RAD = np.array([0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0])
"""Edges of the angle-turned bins of the autocovariance cells [rad] (the ``motion`` clock)."""
LENGTH_GRID_M = np.geomspace(0.1, 100.0, 31)
TURN_GRID_RAD = np.append(np.geomspace(0.03, 30.0, 25), np.inf)
"""Scales the ``motion`` clock is fitted over (inf: no turn term, the ``distance`` clock)."""


@dataclass
class _Cells:
    """Pair sums per (time-difference, distance-difference, angle-turned) cell of the LOS residuals."""

    products: np.ndarray
    sq_diffs: np.ndarray
    counts: np.ndarray
    dist: np.ndarray  # sum of the pairs' travelled distances [m]
    turn: np.ndarray  # sum of the pairs' angles turned [rad]
    c0: float = 0.0
    n0: int = 0
    clocked: bool = True

    @classmethod
    def empty(cls) -> _Cells:
        shape = (int(round(MAX_LAG_S / LAG_BIN_S)) + 1, int(round(MAX_LAG_M / LAG_BIN_M)) + 2, TURN_EDGES_RAD.size + 1)
        return cls(*(np.zeros(shape) for _ in range(5)))

    def add(self, x: np.ndarray, t: np.ndarray, c: np.ndarray | None, h: np.ndarray | None) -> None:
        nb, nc, nh = self.counts.shape
        x = x - x.mean()
        self.c0 += float(x @ x)
        self.n0 += x.size
        for k in range(1, min(MAX_ROW_LAG, x.size)):  # rows k apart, while any pair is within MAX_LAG_S
            b = np.floor((t[k:] - t[:-k]) / LAG_BIN_S + 0.5).astype(np.int64)
            m = b < nb
            if not m.any():
                break
            dc = np.abs(c[k:] - c[:-k])[m] if c is not None else np.zeros(int(m.sum()))
            dh = np.abs(h[k:] - h[:-k])[m] if h is not None else np.zeros(int(m.sum()))
            bc = np.minimum(np.floor(dc / LAG_BIN_M + 0.5), nc - 1).astype(np.int64)  # last: beyond MAX_LAG_M
            cell = (b[m] * nc + bc) * nh + np.searchsorted(TURN_EDGES_RAD, dh, side="right")
            for arr, w in ((self.products, x[k:][m] * x[:-k][m]), (self.sq_diffs, (x[k:][m] - x[:-k][m]) ** 2),
                           (self.counts, None), (self.dist, dc), (self.turn, dh)):
                arr += np.bincount(cell, weights=w, minlength=arr.size).reshape(arr.shape)


def _cells(seqs: Iterable[tuple[np.ndarray, ...]]) -> _Cells:
    """The cells of (run, anchor) sequences (residual, time[, distance travelled[, angle turned]])."""
    out = _Cells.empty()
    for seq in seqs:
        x, t = seq[0], seq[1]
        c = seq[2] if len(seq) > 2 else None
        out.clocked = out.clocked and c is not None
        if x.size >= 10:
            out.add(x, t, c, seq[3] if len(seq) > 3 else None)
    out.clocked = out.clocked and out.n0 > 0
    return out


def _exp_fit(lag: np.ndarray, sums: np.ndarray, counts: np.ndarray, fit_max: float, first: int
             ) -> tuple[float, float] | None:
    """(s^2, scale) of C(lag) = s^2 exp(-lag / scale) by least squares on log C weighted by the pairs, over
    the bins from ``first`` up to ``fit_max`` with enough pairs and C > 0; None with fewer than three."""
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sums / counts
    use = (np.arange(lag.size) >= first) & (lag <= fit_max + 1e-9) & (counts >= MIN_PAIRS_PER_BIN) & (cov > 0)
    if use.sum() < 3:
        return None
    sw = np.sqrt(counts[use])
    a = np.stack([np.ones(use.sum()), -lag[use]], axis=1)
    (log_s2, inv_scale), *_ = np.linalg.lstsq(a * sw[:, None], np.log(cov[use]) * sw, rcond=None)
    return float(np.exp(log_s2)), (float(1.0 / inv_scale) if inv_scale > 0 else np.inf)


def _variogram(cells: _Cells, var0: float) -> tuple[np.ndarray, ...]:
    """The cells the clocks are compared on (pairs 0-FIT_MAX_LAG_S apart, enough of them): semivariogram
    gamma = E (x_i - x_j)^2 / 2 (differences: a stop's pairs measure how much the error changed during
    it, not its one noisy level), pairs, mean time, distance and angle apart, and var0 - gamma."""
    n = cells.counts
    lag_t = (np.arange(n.shape[0]) * LAG_BIN_S)[:, None, None] + 0 * n
    use = (n >= MIN_CELL_PAIRS) & (lag_t > 0) & (lag_t <= FIT_MAX_LAG_S + 1e-9)
    w = n[use]
    gamma = 0.5 * cells.sq_diffs[use] / w
    return gamma, w, lag_t[use], cells.dist[use] / w, cells.turn[use] / w, var0 - gamma


def _variogram_mse(target: np.ndarray, w: np.ndarray, x: np.ndarray, s2: float) -> float:
    """Pair-weighted mean squared error of the semivariogram var0 - s^2 exp(-x) (``target``: var0 - gamma)."""
    return float((w * (target - s2 * np.exp(-x)) ** 2).sum() / w.sum())


def _motion_fit(cells: _Cells, var0: float) -> tuple[float, float, float, float] | None:
    """(s^2, length, turn, mse) of the ``motion`` clock, var0 - gamma = s^2 exp(-(d / length + a / turn)),
    over the grids LENGTH_GRID_M x TURN_GRID_RAD with s^2 by weighted least squares at each point."""
    _, w, _, d, a, target = _variogram(cells, var0)
    if w.size < 3:
        return None
    best: dict[bool, tuple[float, float, float, float]] = {}  # by whether the turn term is on
    for length in LENGTH_GRID_M:
        x_d = d / length
        for turn in TURN_GRID_RAD:
            e = np.exp(-(x_d + a / turn))
            s2 = float(np.clip((w * target * e).sum() / (w * e * e).sum(), 0.0, var0))
            mse = float((w * (target - s2 * e) ** 2).sum() / w.sum())
            key = bool(np.isfinite(turn))
            if key not in best or mse < best[key][3]:
                best[key] = (s2, float(length), float(turn), mse)
    # the turn term only where it earns its parameter: MIN_TURN_GAIN less error than the distance alone
    return best[True] if best[True][3] < (1.0 - MIN_TURN_GAIN) * best[False][3] else best[False]


def _method() -> str:
    """The module's "Fit:" paragraph in plain words: each constant it names by its value, no markup."""
    text = __doc__.split("Fit: ", 1)[1].split("\n\n")[0].replace("\n", " ")

    def value(m: re.Match) -> str:
        v = globals()[m.group(1)]
        return ", ".join(f"{x:g}" for x in np.ravel(v)) if np.ndim(v) else f"{v:g}"

    return re.sub(r":data:`(\w+)`", value, text).replace("``", "")


def fit_antenna_sway(seqs: Iterable[tuple[np.ndarray, ...]]) -> dict[str, Any]:
    """Sway std [m] and its clock from LOS residual sequences (residual [m], time [s][, distance
    travelled [m], angle turned [rad]]) of one anchor in one run, each with its range law removed.
    Returns a dict with ``identifiable``, ``clock`` (``time``, ``distance`` or ``motion``), ``std_m``,
    ``tau_s`` (time) or ``length_m`` and ``turn_rad`` (motion; distance: no turn), the white remainder
    ``white_std_m``, the binned autocorrelation and each clock's fit."""
    cells = _cells(seqs)
    c0, n0 = cells.c0, cells.n0
    out: dict[str, Any] = {"method": _method(),
                           "n_rows": n0, "lag_bin_s": LAG_BIN_S}
    if n0 < 100:
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None, "why": "fewer than 100 LOS rows"}
    var0 = c0 / n0
    sums, counts = cells.products.sum(axis=(1, 2)), cells.counts.sum(axis=(1, 2))
    lag = np.arange(sums.size) * LAG_BIN_S
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sums / counts
    out["autocorrelation"] = {f"{dt:.1f}": (None if not np.isfinite(c) else round(float(c / var0), 4))
                              for dt, c in zip(lag[1:], cov[1:], strict=True)}
    fits: dict[str, dict[str, float]] = {}
    time_fit = _exp_fit(lag, sums, counts, FIT_MAX_LAG_S, 1)
    if time_fit is not None and np.isfinite(time_fit[1]):
        s2, tau = min(time_fit[0], var0), time_fit[1]
        _, w, lag_t, _, _, target = _variogram(cells, var0)
        fits["time"] = {"s2": s2, "tau_s": tau,
                        "mse_m4": _variogram_mse(target, w, lag_t / tau, s2) if w.size else np.inf}
    motion = _motion_fit(cells, var0) if cells.clocked else None
    if motion is not None:
        s2, length, turn, mse = motion
        fits["distance" if np.isinf(turn) else "motion"] = {"s2": s2, "length_m": length, "turn_rad": turn,
                                                            "mse_m4": mse}
    if not fits:
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None,
                "why": "the LOS residuals are not positively correlated over a few bins"}
    clock = min(fits, key=lambda k: (fits[k]["mse_m4"], k != "time"))  # a tie: the time clock, as before
    f = fits[clock]
    share = f["s2"] / var0
    out.update(var_m2=var0, slow_share=share, clock=clock,
               fits={k: {"std_m": float(np.sqrt(v["s2"])), **{q: (None if not np.isfinite(z) else float(z))
                                                              for q, z in v.items() if q != "s2"}}
                     for k, v in fits.items()})
    scale = f["tau_s"] / LAG_BIN_S if clock == "time" else f["length_m"] / LAG_BIN_M
    if not (scale >= 2 and share >= MIN_SLOW_SHARE):
        return {**out, "identifiable": False, "std_m": 0.0, "tau_s": None,
                "why": f"no slow part to fit (share {share:.2f}, {clock} clock): white LOS errors kept"}
    scales = ({"tau_s": f["tau_s"]} if clock == "time" else
              {"tau_s": None, "length_m": f["length_m"], "turn_rad": None if clock == "distance" else f["turn_rad"]})
    return {**out, "identifiable": True, "std_m": float(np.sqrt(f["s2"])), **scales,
            "white_std_m": float(np.sqrt(max(var0 - f["s2"], 0.0)))}
