"""Calibration of the UWB model: time offset, burst schedule, per-anchor LOS/NLOS ranging errors.

Conventions are the generator's (:mod:`physynth.models.uwb`):

- stamps lag true time: ``stamp = true time + uwb.time_offset_s``, so the residual of a row is
  ``range - |p(stamp - offset) - a_i|``;
- LOS error ``N(los_mean_m + range_bias_per_m * r + range_bias_per_decade_m * log10(r), los_std_m^2)``
  with r the true range in metres; the calibration fits one of the two range terms (``law``: ``"log"``,
  the received-power bias, by default; ``"linear"``, a clock-scale error); NLOS rows
  *replace* it by a Gaussian-mixture offset (no range bias), with long-run probability ``nlos_prob``
  and episodes of mean ``nlos_dwell_s``;
- the tag ranges in bursts at ``burst_rate_hz``; anchor j is ranged ``j * slot_s`` after the burst
  start; ``rate_hz / burst_rate_hz`` is the probability that an anchor is attempted in a burst.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from ..bounds import BOUNDS
from ..models.uwb import los_error_mean, range_decades, range_error_log_components
from ..records import Trace, untrusted_truth
from ._base import CalibrationError, Fit, trace_label

OFFSET_COARSE_S = (-1.0, 1.0, 0.01)
"""Coarse grid of candidate time offsets (start, stop, step) [s]."""
OFFSET_FINE_HALF_S = 0.03
OFFSET_FINE_STEP_S = 0.001
MAX_NLOS_MODES = 3
"""Largest number of Gaussian NLOS modes tried (the order is chosen by BIC)."""
LOS_LIKE_SIGMAS = 2.0
"""An NLOS mode whose mean lies within this many LOS sigmas of the LOS mean (at the median range) is
not an offset distribution but a reshaping of the LOS peak (narrower core, heavier tails); a mixture
with such a mode is not accepted, whatever its width."""
MIN_ANCHOR_ROWS = 30
"""Fewer valid rows than this and an anchor keeps the pooled (default) channel."""
GRID_BIN_S = 0.01
RANGE_BIAS_LAWS = ("log", "linear")
"""How the LOS mean error grows with the true range r: ``log``, gamma log10(r / 1 m) (received-power
bias: the path loss grows 20 dB per decade of range; on the Hanyang static sweeps, 2-60 m, it leaves
2.7 cm rms about the per-file medians against 4.7 cm for a straight line in r, docs/calibration.md);
``linear``, beta r (a clock-scale error)."""
"""Bin width of the evaluation grid the grid-equivalent slot is matched to [s] (docs/data-and-metrics.md, section 3)."""


# --------------------------------------------------------------------------------------------------
# Residuals and the time offset
# --------------------------------------------------------------------------------------------------


def geometric_range(trace: Trace, t_s: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """|p_truth(t) - a_i| [m] for times ``t_s`` (any shape) and anchor indices of the same shape."""
    pos = trace.truth.position_at(t_s)
    return np.linalg.norm(pos - trace.anchors.pos_enu_m[anchor], axis=-1)


@dataclass(frozen=True, slots=True, kw_only=True)
class Residuals:
    """Valid rows of one trace with the time offset applied: residual, true-range estimate, anchor, time."""

    residual_m: np.ndarray
    range_m: np.ndarray
    anchor: np.ndarray
    t_s: np.ndarray
    range_rate_mps: np.ndarray  # d/dt of the geometric range at t - offset
    trusted: np.ndarray | None = None  # the truth at t - offset is trusted (``records.untrusted_truth``)


GROSS_RESIDUAL_M = (BOUNDS["channel.nlos_modes[].mean_m"].lo, BOUNDS["channel.nlos_modes[].mean_m"].hi)
"""Residuals outside the physical range of an NLOS excess (-100 .. 1000 m) are no ranging error the model
can have (a radio's error code such as 65535, a corrupt value): left out of every fit and counted
(:func:`gross_residual_count`, the report's ``gross_residuals``)."""


def _is_gross(r: np.ndarray) -> np.ndarray:
    return (r < GROSS_RESIDUAL_M[0]) | (r > GROSS_RESIDUAL_M[1])


def gross_residual_count(trace: Trace, offset_s: float) -> int:
    """Valid rows inside the truth span whose residual lies outside :data:`GROSS_RESIDUAL_M`."""
    u = trace.uwb
    ok = u.valid
    r = u.range_m[ok] - geometric_range(trace, u.t_s[ok] - offset_s, u.anchor[ok].astype(np.intp))
    return int(np.count_nonzero(_is_gross(r[np.isfinite(r)])))


def corrected_residuals(trace: Trace, offset_s: float, rate_step_s: float = 0.02) -> Residuals:
    """Residuals ``range - |p(t - offset) - a_i|`` of the valid rows inside the truth span, gross ones
    (:data:`GROSS_RESIDUAL_M`) left out."""
    u = trace.uwb
    ok = u.valid
    t, a = u.t_s[ok], u.anchor[ok].astype(np.intp)
    g = geometric_range(trace, t - offset_s, a)
    gd = (geometric_range(trace, t - offset_s + rate_step_s, a)
          - geometric_range(trace, t - offset_s - rate_step_s, a)) / (2.0 * rate_step_s)
    r = u.range_m[ok] - g
    keep = np.isfinite(r) & np.isfinite(gd)
    keep[keep] = ~_is_gross(r[keep])
    return Residuals(residual_m=r[keep], range_m=g[keep], anchor=a[keep], t_s=t[keep], range_rate_mps=gd[keep],
                     trusted=~untrusted_truth(trace.meta, t[keep] - offset_s))


def _mad_curve(trace: Trace, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per anchor: (count (A,), squared robust sigma (A, K) over offsets, row index arrays).

    The robust sigma is 1.4826 x the median absolute deviation from the anchor's median residual.
    """
    u = trace.uwb
    ok = u.valid
    t, a, rng = u.t_s[ok], u.anchor[ok].astype(np.intp), u.range_m[ok]
    n_a = len(trace.anchors)
    counts = np.zeros(n_a)
    mad2 = np.full((n_a, offsets.size), np.nan)
    for i in range(n_a):  # one pass per anchor, vectorised over offsets x rows
        rows = a == i
        if rows.sum() < 5:
            continue
        tq = t[rows][None, :] - offsets[:, None]
        r = rng[rows][None, :] - geometric_range(trace, tq, np.full(tq.shape, i))
        good = np.all(np.isfinite(r), axis=0)
        r = r[:, good]
        if r.shape[1] < 5:
            continue
        med = np.median(r, axis=1, keepdims=True)
        mad2[i] = (1.4826 * np.median(np.abs(r - med), axis=1)) ** 2
        counts[i] = r.shape[1]
    return counts, mad2, offsets


def _pooled(curves: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    num = sum(np.nansum(c[:, None] * m, axis=0) for c, m in curves)
    den = sum(float(c[np.isfinite(m).all(axis=1)].sum()) for c, m in curves)
    return np.sqrt(num / den)


def _parabolic_min(x: np.ndarray, y: np.ndarray) -> float:
    k = int(np.nanargmin(y))
    if 0 < k < x.size - 1 and np.all(np.isfinite(y[k - 1:k + 2])):
        y0, y1, y2 = y[k - 1], y[k], y[k + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            return float(x[k] + 0.5 * (y0 - y2) / den * (x[1] - x[0]))
    return float(x[k])


def fit_time_offset(traces: Sequence[Trace], *, per_anchor: bool = True) -> Fit[float]:
    """The UWB time offset (stamp = true time + offset) that minimises the pooled robust residual spread.

    For every candidate offset on a coarse grid (-1 to +1 s, 10 ms) and then a fine grid (1 ms) around
    the coarse minimum, the truth is interpolated at ``stamp - offset``; the spread is the
    count-weighted RMS over anchors (and runs) of 1.4826 x MAD of each anchor's residuals. The
    minimum is refined by a parabola. Per-run and per-anchor minima are reported; the standard error
    comes from the spread of the per-run offsets (several runs) or of five time blocks (one run).
    """
    labels = [trace_label(t, i) for i, t in enumerate(traces)]
    coarse = np.arange(OFFSET_COARSE_S[0], OFFSET_COARSE_S[1] + 1e-9, OFFSET_COARSE_S[2])
    curves = [_mad_curve(t, coarse)[:2] for t in traces]
    pooled = _pooled(curves)
    if not np.isfinite(pooled).any():
        raise CalibrationError("no UWB rows inside the ground-truth time span: cannot compute residuals")
    k0 = int(np.nanargmin(pooled))
    fine = np.arange(coarse[k0] - OFFSET_FINE_HALF_S, coarse[k0] + OFFSET_FINE_HALF_S + 1e-9, OFFSET_FINE_STEP_S)
    fine_curves = [_mad_curve(t, fine)[:2] for t in traces]
    pooled_fine = _pooled(fine_curves)
    best = _parabolic_min(fine, pooled_fine)
    spread_min, spread_max = float(np.nanmin(pooled)), float(np.nanmax(pooled))
    identifiable = spread_max - spread_min > 0.02 * spread_min  # exact ranges: spread 0 at every offset
    per_run = {lab: _parabolic_min(coarse, _pooled([c])) for lab, c in zip(labels, curves, strict=True)}
    per_anchor: dict[str, float] = {}
    if per_anchor:
        ids: list[str] = []
        for t in traces:
            ids += [a for a in t.anchors.ids if a not in ids]
        for aid in ids:
            parts = []
            for t, (c, m) in zip(traces, fine_curves, strict=True):
                if aid in t.anchors.ids:
                    j = t.anchors.index(aid)
                    if np.isfinite(m[j]).all():
                        parts.append((c[j:j + 1], m[j:j + 1]))
            if parts:
                per_anchor[aid] = _parabolic_min(fine, _pooled(parts))
    if len(traces) >= 2:
        vals = np.array(list(per_run.values()))
        se = float(np.std(vals, ddof=1) / np.sqrt(vals.size))
        se_method = "std of the per-run offsets / sqrt(n_runs)"
    else:
        se, se_method = _block_se(traces[0], fine), "std of the offsets of 5 time blocks / sqrt(5)"
    n = int(sum(c.sum() for c, _ in fine_curves))
    diag: dict[str, Any] = {
        "offset_s": best if identifiable else 0.0,
        "std_error_s": se,
        "std_error_method": se_method,
        "convention": "stamp = true time + offset (positive: the UWB stamps lag the truth)",
        "spread_at_offset_m": float(np.interp(best, fine, pooled_fine)),
        "spread_at_zero_m": float(np.interp(0.0, coarse, pooled)),
        "search_curve": {"offset_s": [round(float(x), 4) for x in coarse],
                         "robust_spread_m": [round(float(x), 5) for x in pooled]},
        "per_run_s": per_run,
        "per_anchor_s": per_anchor,
        "n_residuals": n,
        "identifiable": bool(identifiable),
    }
    if not identifiable:
        diag["note"] = ("the residual spread does not depend on the offset (static tag?): offset not "
                        "identifiable, 0 used")
    return Fit(params=diag["offset_s"], n_samples=n, diagnostics=diag)


def _block_se(trace: Trace, grid: np.ndarray, n_blocks: int = 5) -> float:
    u = trace.uwb
    t = u.t_s[u.valid]
    if t.size < 50:
        return float("nan")
    edges = np.quantile(t, np.linspace(0, 1, n_blocks + 1))
    vals = []
    for b in range(n_blocks):  # five blocks, each vectorised
        keep = (u.t_s >= edges[b]) & (u.t_s <= edges[b + 1])
        sub = Trace(truth=trace.truth, anchors=trace.anchors,
                    uwb=type(u)(t_s=u.t_s[keep], anchor=u.anchor[keep], range_m=u.range_m[keep]))
        c, m = _mad_curve(sub, grid)[:2]
        if np.isfinite(m).any():
            vals.append(_parabolic_min(grid, _pooled([(c, m)])))
    return float(np.std(vals, ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else float("nan")


# --------------------------------------------------------------------------------------------------
# LOS / NLOS mixture
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeFit:
    """One fitted Gaussian NLOS mode: its share of the NLOS rows and its offset distribution [m]."""

    weight: float
    mean_m: float
    std_m: float


@dataclass(frozen=True, slots=True, kw_only=True)
class MixtureFit:
    """LOS regression N(mu + beta r + gamma log10 r, sigma^2) plus K Gaussian NLOS modes with total weight p
    (one of beta and gamma is fitted, the other is 0)."""

    los_mean_m: float
    range_bias_per_m: float
    los_std_m: float
    nlos_prob: float
    modes: tuple[ModeFit, ...]  # NLOS modes (weights sum to 1 within NLOS)
    log_likelihood: float
    bic: float
    n: int
    nlos_resp: np.ndarray  # posterior NLOS probability per row
    se: dict[str, float]
    converged: bool
    range_bias_per_decade_m: float = 0.0

    def los_centre(self, range_m: np.ndarray | float) -> np.ndarray:
        """Mean LOS error [m] at true ranges ``range_m``."""
        return los_error_mean(np.asarray(range_m, dtype=float), self.los_mean_m, self.range_bias_per_m,
                              self.range_bias_per_decade_m)


def robust_line(r: np.ndarray, g: np.ndarray, fit_slope: bool) -> tuple[float, float, float, np.ndarray]:
    """Iteratively trimmed least-squares line r = mu + beta g; returns mu, beta, sigma, inlier mask."""
    med = np.median(r)
    sig = max(1.4826 * np.median(np.abs(r - med)), 1e-3)
    mu, beta = med, 0.0
    inl = np.abs(r - med) < 3.0 * sig
    for _ in range(5):  # a few trimming rounds, each vectorised
        if inl.sum() < 3:
            break
        if fit_slope and np.ptp(g[inl]) > 0:
            beta, mu = np.polyfit(g[inl], r[inl], 1)
        else:
            mu, beta = float(np.mean(r[inl])), 0.0
        res = r - mu - beta * g
        sig = max(1.4826 * np.median(np.abs(res[inl])), 1e-3)
        inl = np.abs(res) < 3.0 * sig
    return float(mu), float(beta), float(sig), inl


def fit_mixture(r: np.ndarray, g: np.ndarray, k: int, *, fit_slope: bool = True, fixed_slope: float | None = None,
                max_iter: int = 300, tol: float = 1e-7, law: str = "log") -> MixtureFit | None:
    """EM fit of the LOS regression plus ``k`` NLOS Gaussian modes to residuals ``r`` at ranges ``g``.

    The LOS mean is regressed on log10(g) (``law="log"``) or on g (``"linear"``); ``fixed_slope`` is in
    the law's unit (m per decade or m per m). Returns None when ``k`` modes cannot be initialised (too
    few rows outside the LOS core).
    """
    if law not in RANGE_BIAS_LAWS:
        raise CalibrationError(f"unknown range-bias law {law!r} (choose from {', '.join(RANGE_BIAS_LAWS)})")
    n = r.size
    slope_free = fit_slope and fixed_slope is None and np.ptp(g) > 1.0
    g = range_decades(g) if law == "log" else g  # the regressor; the EM below is the same for both laws
    mu, beta, sig, inl = robust_line(r - (fixed_slope or 0.0) * g, g, slope_free)
    if fixed_slope is not None:
        beta = fixed_slope
    out = r[~inl]
    if k > 0 and out.size < 3 * k:
        return None
    p = out.size / n if k > 0 else 0.0
    if k > 0:
        qs = np.quantile(out, (np.arange(k) + 0.5) / k)
        means = qs.astype(float)
        stds = np.full(k, max(np.std(out) / k, sig))
        w = np.full(k, 1.0 / k)
        p = max(p, 1e-3)
    else:
        means = stds = w = np.zeros(0)
    ll_old = -np.inf
    converged = False
    x = np.stack([np.ones(n), g], axis=1)
    for _ in range(max_iter):  # EM iterations, each vectorised over rows
        lp = range_error_log_components(r, g, los_mean_m=mu, range_bias_per_m=beta, los_std_m=sig, nlos_prob=p,
                                        mode_weights=w, mode_mean_m=means, mode_std_m=stds)
        tot = logsumexp(lp, axis=0)
        ll = float(tot.sum())
        resp = np.exp(lp - tot)
        g0 = resp[0]
        s0 = g0.sum()
        if slope_free:
            xw = x * g0[:, None]
            coef = np.linalg.solve(x.T @ xw + 1e-12 * np.eye(2), xw.T @ r)
            mu, beta = float(coef[0]), float(coef[1])
        else:
            mu = float(np.sum(g0 * (r - beta * g)) / s0)
        sig = max(float(np.sqrt(np.sum(g0 * (r - mu - beta * g) ** 2) / s0)), 1e-4)
        if k > 0:
            rk = resp[1:]
            sk = rk.sum(axis=1)
            p = float(sk.sum() / n)
            w = sk / max(sk.sum(), 1e-300)
            means = (rk @ r) / np.maximum(sk, 1e-300)
            stds = np.sqrt(np.maximum(np.sum(rk * (r[None, :] - means[:, None]) ** 2, axis=1)
                                      / np.maximum(sk, 1e-300), 0.0))
            stds = np.maximum(stds, max(0.01, 0.2 * sig))
        if abs(ll - ll_old) < tol * n:
            converged = True
            break
        ll_old = ll
    n_par = 3 + (3 * k if k > 0 else 0) - (0 if slope_free else 1)
    nlos_resp = 1.0 - g0
    n_los = max(s0, 1.0)
    xw = x * g0[:, None]
    se = {"los_std_m": sig / np.sqrt(2.0 * n_los), "nlos_prob": float(np.sqrt(max(p * (1 - p), 0.0) / n)),
          "range_bias_per_m": 0.0, "range_bias_per_decade_m": 0.0}
    slope_key = "range_bias_per_decade_m" if law == "log" else "range_bias_per_m"
    if slope_free:
        cov = np.linalg.inv(x.T @ xw + 1e-12 * np.eye(2)) * sig**2
        se["los_mean_m"], se[slope_key] = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
    else:
        se["los_mean_m"] = sig / np.sqrt(n_los)
    modes = tuple(ModeFit(weight=float(w[j]), mean_m=float(means[j]), std_m=float(stds[j])) for j in range(k))
    if k > 0:
        se["mode_mean_m"] = [float(stds[j] / np.sqrt(max(p * w[j] * n, 1.0))) for j in range(k)]
    return MixtureFit(los_mean_m=mu, range_bias_per_m=beta if law == "linear" else 0.0, los_std_m=sig,
                      nlos_prob=p if k > 0 else 0.0, modes=modes, log_likelihood=ll, bic=-2.0 * ll + n_par * np.log(n),
                      n=n, nlos_resp=nlos_resp if k > 0 else np.zeros(n), se=se, converged=converged,
                      range_bias_per_decade_m=beta if law == "log" else 0.0)


def _los_like(fit: MixtureFit, g: np.ndarray) -> bool:
    centre = float(fit.los_centre(float(np.median(g))))
    return any(abs(m - centre) < LOS_LIKE_SIGMAS * fit.los_std_m for m in (x.mean_m for x in fit.modes))


def nlos_responsibility(fit: MixtureFit, r: np.ndarray, g: np.ndarray, los_std_m: float | None = None) -> np.ndarray:
    """Posterior NLOS probability of residuals ``r`` at ranges ``g`` under a fitted mixture (with the LOS
    peak ``los_std_m`` wide instead of the fit's when given)."""
    if not fit.modes:
        return np.zeros(r.shape)
    lp = range_error_log_components(
        r, g, los_mean_m=fit.los_mean_m, range_bias_per_m=fit.range_bias_per_m,
        los_std_m=fit.los_std_m if los_std_m is None else los_std_m,
        nlos_prob=fit.nlos_prob, mode_weights=np.array([m.weight for m in fit.modes]),
        mode_mean_m=np.array([m.mean_m for m in fit.modes]), mode_std_m=np.array([m.std_m for m in fit.modes]),
        range_bias_per_decade_m=fit.range_bias_per_decade_m)
    return 1.0 - np.exp(lp[0] - logsumexp(lp, axis=0))


def select_mixture(r: np.ndarray, g: np.ndarray, *, max_modes: int = MAX_NLOS_MODES, fit_slope: bool = True,
                   fixed_slope: float | None = None, law: str = "log", fit_mask: np.ndarray | None = None
                   ) -> tuple[MixtureFit, dict[str, Any]]:
    """Fit K = 0 .. max_modes NLOS modes and keep the lowest BIC among the admissible fits.

    A fit is not admissible when one of its NLOS modes is LOS-like (see ``LOS_LIKE_SIGMAS``) or when
    it puts less than 3 rows' worth of weight in a mode. ``fit_mask`` (boolean, like ``r``): fit on those
    rows only (those whose truth is trusted) and give every row its NLOS responsibility under that fit;
    ignored when fewer than ``MIN_ANCHOR_ROWS`` rows are left.
    """
    if fit_mask is not None and not fit_mask.all() and int(fit_mask.sum()) >= MIN_ANCHOR_ROWS:
        f, sel = select_mixture(r[fit_mask], g[fit_mask], max_modes=max_modes, fit_slope=fit_slope,
                                fixed_slope=fixed_slope, law=law)
        # rows whose truth errs: classified with the LOS peak widened by their own scatter about it
        dev = r[~fit_mask] - f.los_centre(g[~fit_mask])
        core = np.abs(dev) < 1.0
        wide = float(np.hypot(f.los_std_m, 1.4826 * np.median(np.abs(dev[core])))) if core.any() else f.los_std_m
        resp = nlos_responsibility(f, r, g)
        resp[~fit_mask] = nlos_responsibility(f, r[~fit_mask], g[~fit_mask], los_std_m=wide)
        return replace(f, nlos_resp=resp), {**sel, "n_rows_untrusted_truth": int((~fit_mask).sum()),
                                            "los_std_untrusted_truth_m": wide}
    fits: dict[int, MixtureFit] = {}
    table: dict[str, Any] = {}
    for k in range(max_modes + 1):
        f = fit_mixture(r, g, k, fit_slope=fit_slope, fixed_slope=fixed_slope, law=law)
        if f is None:
            table[str(k)] = {"bic": None, "admissible": False, "why": "too few rows outside the LOS core"}
            continue
        tiny = k > 0 and min(x.weight for x in f.modes) * f.nlos_prob * f.n < 3
        los_like = k > 0 and _los_like(f, g)
        ok = not (tiny or los_like)
        why = "LOS-like NLOS mode" if los_like else ("a mode with < 3 rows" if tiny else "")
        table[str(k)] = {"bic": f.bic, "log_likelihood": f.log_likelihood, "admissible": ok,
                         **({"why": why} if why else {})}
        if ok:
            fits[k] = f
    best = min(fits, key=lambda k: fits[k].bic)
    return fits[best], {"bic_per_order": table, "chosen_order": best}


def nlos_dwell_s(t_s: np.ndarray, is_nlos: np.ndarray, attempt_period_s: float) -> tuple[float | None, int]:
    """Mean NLOS episode duration [s] from the labelled rows of one anchor (sorted by time).

    Episodes are runs of consecutive NLOS rows; with samples every T, an exponential episode of mean
    tau covers a geometric number n >= 1 of samples with P(continue) = exp(-T / tau), hence
    tau = -T / log(1 - 1 / mean(n)). Returns (tau or None when no episode, number of episodes).
    """
    if is_nlos.size == 0 or not is_nlos.any():
        return None, 0
    x = np.concatenate([[0], is_nlos.astype(np.int8), [0]])
    d = np.diff(x)
    lengths = np.flatnonzero(d == -1) - np.flatnonzero(d == 1)
    mean_n = float(lengths.mean())
    if mean_n <= 1.0 + 1e-9:
        return attempt_period_s / 10.0, int(lengths.size)
    return float(-attempt_period_s / np.log(1.0 - 1.0 / mean_n)), int(lengths.size)


# --------------------------------------------------------------------------------------------------
# Burst schedule
# --------------------------------------------------------------------------------------------------


def burst_ids(trace: Trace) -> np.ndarray:
    """Burst index of every UWB row: the trace's own when known, else grouped by time gaps."""
    u = trace.uwb
    if len(u) and np.all(u.burst >= 0):
        return u.burst.astype(np.int64)
    t, a = u.t_s, u.anchor
    order = np.lexsort((t, a))
    d = np.diff(t[order])[np.diff(a[order]) == 0]
    d = d[d > 0]
    gap = float(np.median(d) / 2.0) if d.size else 0.05
    return np.concatenate([[0], np.cumsum(np.diff(t) > gap)]).astype(np.int64)


@dataclass(frozen=True, slots=True, kw_only=True)
class BurstSchedule:
    """Burst-level timing of one trace."""

    starts_s: np.ndarray  # burst start times (B,)
    period_s: float
    jitter_s: float
    phase_s: float  # stamp time of the clock-locked schedule's first burst after the trace start, mod period
    n_single: int  # number of one-period intervals used
    within_offset_s: np.ndarray  # row time minus its burst start (N,)
    index_span: np.ndarray  # per burst: (max - min) anchor index of its valid rows
    split: np.ndarray  # per burst: whether its valid rows fall in more than one grid bin


def burst_schedule(trace: Trace, grid_bin_s: float = GRID_BIN_S) -> BurstSchedule:
    u = trace.uwb
    b = burst_ids(trace)
    _, inv = np.unique(b, return_inverse=True)
    nb = int(inv.max()) + 1 if inv.size else 0
    start = np.full(nb, np.inf)
    np.minimum.at(start, inv, u.t_s)
    d = np.diff(start)
    d = d[d > 0]
    if d.size == 0:
        raise CalibrationError("fewer than two UWB bursts: burst rate not identifiable")
    p0 = float(np.median(d))
    mult = np.maximum(np.round(d / p0), 1.0)
    single = d[mult == 1]
    period = float(np.median(single)) if single.size else p0
    # the tag clock locks the bursts: least squares of start = a + k P over burst numbers k gives the
    # period to ~1e-8 s (a median of periods is only good to ~1e-6 s, i.e. ms of drift over a run)
    # and the phase; a second pass leaves out bursts that started late (first anchor missing). Each
    # burst is numbered from the one before (gaps are a few periods, their jitter far under half a
    # period): numbering from the first burst by the median period misnumbered bursts once the
    # median's error, times thousands of bursts, passed half a period (3 ms jitter at 23 Hz: rates
    # off by up to 0.3 %)
    k = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(np.diff(start) / period), 1.0))])
    keep = np.ones(start.size, dtype=bool)
    for _ in range(2):
        if np.count_nonzero(keep) < 3 or np.ptp(k[keep]) == 0:
            break
        slope, icpt = np.polyfit(k[keep], start[keep], 1)
        res = start - (icpt + slope * k)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res - np.median(res[keep])) <= max(3.0 * mad, 1e-5)
    else:
        period = float(slope)
    phase = float((np.median(start[keep] - period * k[keep]) - trace.t0_s) % period)
    # jitter from one anchor's consecutive bursts (same slot, so the slot offsets cancel); the
    # generator's bursts are clock-locked with independent jitter per burst, so these periods
    # scatter by sqrt(2) * jitter
    order = np.lexsort((u.t_s, u.anchor))
    a_sorted, t_sorted, b_sorted = u.anchor[order], u.t_s[order], inv[order]
    same = (a_sorted[1:] == a_sorted[:-1]) & (np.diff(b_sorted) == 1)
    dt = np.diff(t_sorted)[same]
    jit = (float(1.4826 * np.median(np.abs(dt - np.median(dt))) / np.sqrt(2.0)) if dt.size > 2 else 0.0)
    ok = u.valid
    lo = np.full(nb, np.iinfo(np.int64).max)
    hi = np.full(nb, -1)
    np.minimum.at(lo, inv[ok], u.anchor[ok].astype(np.int64))
    np.maximum.at(hi, inv[ok], u.anchor[ok].astype(np.int64))
    t0 = trace.t0_s
    k = np.ceil((u.t_s - t0) / grid_bin_s - 1e-6).astype(np.int64)
    kmin = np.full(nb, np.iinfo(np.int64).max)
    kmax = np.full(nb, np.iinfo(np.int64).min)
    np.minimum.at(kmin, inv[ok], k[ok])
    np.maximum.at(kmax, inv[ok], k[ok])
    has = hi >= 0
    return BurstSchedule(starts_s=start, period_s=period, jitter_s=jit, phase_s=phase, n_single=int(single.size),
                         within_offset_s=u.t_s - start[inv], index_span=(hi - lo)[has],
                         split=(kmax > kmin)[has])


BURST_PHASE_AGREE_SE = 5.0
"""Several runs keep their burst phase when every run's phase lies within this many of its standard
errors (2 x jitter / sqrt(its bursts): the intercept of its clock line) of the runs' circular mean ..."""
BURST_PHASE_AGREE_MIN_S = 1e-4
"""... or within this many seconds (1 % of a 10 ms grid bin), whichever is more."""


def shared_burst_phase(phases_s: Sequence[float], n_bursts: Sequence[int], period_s: float,
                       jitter_s: float) -> dict[str, Any]:
    """The burst phase the runs share, if they share one: the circular mean of their phases (modulo
    ``period_s``), kept when no run's phase lies further from it than :data:`BURST_PHASE_AGREE_SE`
    standard errors, 2 ``jitter_s`` / sqrt(the run's ``n_bursts``), nor than
    :data:`BURST_PHASE_AGREE_MIN_S`, whichever is more; else None (the generator draws one per trace).

    Runs generated from a scenario with a phase share it to their standard error (~1e-5 s); real runs
    start at random phases (the four shared Hanyang runs: 0.015, 0.058, 0.020, 0.071 s). Two runs at
    random phases pass by chance 0.4 % of the time at 10 Hz (limit 0.1 ms), 6 % at the cable-car
    presets' 23 Hz and 3 ms jitter (0.6 ms at 2500 bursts; three runs 0.2 %); a few burst jitters
    (9 ms) would pass 83 % of such pairs.
    """
    ph = np.mod(np.asarray(phases_s, dtype=float), period_s)
    centre = float(np.mod(np.angle(np.mean(np.exp(2j * np.pi * ph / period_s))) * period_s / (2.0 * np.pi),
                          period_s)) if ph.size > 1 else float(ph[0])
    centre = centre if centre < period_s else 0.0  # np.mod of a tiny negative number may round to the period
    dev = np.abs(np.mod(ph - centre + 0.5 * period_s, period_s) - 0.5 * period_s)
    limit = np.maximum(BURST_PHASE_AGREE_SE * 2.0 * jitter_s / np.sqrt(np.maximum(n_bursts, 1)),
                       BURST_PHASE_AGREE_MIN_S)
    return {"phase_s": centre if bool(np.all(dev <= limit)) else None, "max_deviation_s": float(dev.max()),
            "limit_s": [float(x) for x in limit]}


LATE_STAMP_MIN_S = 0.010
"""A delivered range stamped more than this [s] (one 10 ms grid bin) after its anchor's usual place in its
burst is a late stamp (:class:`~physynth.models.uwb.UwbParams`, ``late_burst_prob``): within-burst offsets
of the other rows spread by a millisecond or two (the slots and their jitter)."""
LATE_STAMP_SLOTS = 5.0
"""... and more than this many slots (``slot_s``, the median spacing of a burst's rows), or as many slots as
there are anchors if more: a system that ranges its N anchors in a random order moves a row by up to N - 1
slots from its place without any late stamp (the Hanyang tag ranges its four in a random order at ~1 ms
slots)."""
LATE_BURST_MIN = 10
"""Late bursts become a process of the scenario only when at least this many are seen (one stray burst is
no rate: 10 give it to about +-30 %)."""


def late_burst_fit(scheds: Sequence[BurstSchedule], traces: Sequence[Trace], slot_s: float = 0.0) -> dict[str, Any]:
    """Late bursts: those with a delivered range stamped late (:data:`LATE_STAMP_MIN_S` and
    :data:`LATE_STAMP_SLOTS` slots, or one slot per anchor if more, past its anchor's median offset in
    the burst, per run), as a share of
    the bursts with two delivered ranges or more (a burst's first range is never late, so only those
    can show it); the late rows' median delay; and how many late bursts have every range but the first
    late (the generator's late burst). ``applied`` when at least :data:`LATE_BURST_MIN` late bursts are seen."""
    n_anchors = max((len(t.anchors) for t in traces), default=0)
    threshold = max(LATE_STAMP_MIN_S, max(LATE_STAMP_SLOTS, n_anchors) * slot_s)
    n_multi, n_late_b, n_rest, excess, per_run, n_late = 0, 0, 0, [], [], 0
    for s, t in zip(scheds, traces, strict=True):
        ok = t.uwb.valid
        a, w = t.uwb.anchor[ok], s.within_offset_s[ok]
        _, b = np.unique(burst_ids(t)[ok], return_inverse=True)
        med = np.zeros(int(a.max()) + 1 if a.size else 0)
        for k in np.unique(a):  # a handful of anchors
            med[k] = np.median(w[a == k])
        e = w - med[a] if a.size else np.zeros(0)
        late = e > threshold
        rows = np.bincount(b, minlength=int(b.max()) + 1 if b.size else 0)
        late_rows = np.bincount(b[late], minlength=rows.size)
        multi = int(np.count_nonzero(rows >= 2))
        hit = late_rows > 0
        n_multi += multi
        n_late_b += int(np.count_nonzero(hit))
        n_rest += int(np.count_nonzero(hit & (late_rows == rows - 1)))
        n_late += int(np.count_nonzero(late))
        excess.append(e[late])
        per_run.append(float(np.count_nonzero(hit) / multi) if multi else None)
    ex = np.concatenate(excess) if excess else np.zeros(0)
    return {"applied": n_late_b >= LATE_BURST_MIN, "prob": n_late_b / n_multi if n_multi else 0.0,
            "n_late_bursts": n_late_b, "n_bursts_two_or_more": n_multi, "n_late_rows": n_late,
            "all_but_first_late_frac": n_rest / n_late_b if n_late_b else None,
            "delay_s": float(np.median(ex)) if ex.size else None,
            "delay_p5_p95_s": [float(np.percentile(ex, 5)), float(np.percentile(ex, 95))] if ex.size else None,
            "prob_per_run": per_run, "min_delay_s": threshold, "min_bursts": LATE_BURST_MIN}


def fit_burst_schedule(traces: Sequence[Trace]) -> Fit[dict[str, float]]:
    """Burst rate, period jitter, slot spacing and clock phase pooled over runs.

    The bursts are locked to the tag clock: the period and phase come from a least-squares line through
    the burst start times. ``slot_s`` is the direct intra-burst spacing (median time between
    consecutive rows of a burst). The phase is kept (``burst_phase_s``) when the runs share one (one run;
    runs generated from a scenario with a phase: :func:`shared_burst_phase`), else it is drawn per trace:
    how often a burst straddles two 10 ms grid bins, and so the grid availability metrics, depends on it. The
    *grid-equivalent* slot (the spacing that would give the observed fraction of split bursts under a
    random phase) is reported as a diagnostic.
    """
    scheds = [burst_schedule(t) for t in traces]
    w = np.array([s.n_single for s in scheds], dtype=float)
    periods = np.array([s.period_s for s in scheds])
    period = float(np.sum(w * periods) / w.sum()) if w.sum() > 0 else float(np.mean(periods))
    jitter = float(np.sqrt(np.sum(w * np.array([s.jitter_s for s in scheds]) ** 2) / max(w.sum(), 1)))
    split = np.concatenate([s.split for s in scheds])
    span = np.concatenate([s.index_span for s in scheds]).astype(float)
    split_frac = float(split.mean()) if split.size else 0.0
    mean_span = float(span.mean()) if span.size else 0.0
    slot_grid = split_frac * GRID_BIN_S / mean_span if mean_span > 0 else 0.0  # diagnostic only
    direct = []
    for t in traces:
        u = t.uwb
        b = burst_ids(t)
        same = np.diff(b) == 0
        direct.append(np.diff(u.t_s)[same])
    dd = np.concatenate(direct) if direct else np.zeros(0)
    slot_direct = float(np.median(dd)) if dd.size else 0.0
    # a clock alignment the runs share is kept (it decides the grid statistics); runs with unrelated
    # alignments (real recordings) leave it to the generator, which then draws one per trace
    shared = shared_burst_phase([s.phase_s for s in scheds], [s.starts_s.size for s in scheds], period, jitter)
    phase = shared["phase_s"]
    diag = {
        "burst_rate_hz": 1.0 / period,
        "period_s": period,
        "burst_jitter_s": jitter,
        "burst_phase_s": phase,
        "burst_phase_per_run_s": [s.phase_s for s in scheds],
        "burst_phase_max_deviation_s": shared["max_deviation_s"],
        "burst_phase_limit_s": shared["limit_s"],
        "slot_s": slot_direct,
        "slot_method": "direct: median time between consecutive rows of one burst",
        "slot_grid_equivalent_s": slot_grid,
        "split_burst_frac": split_frac,
        "mean_anchor_index_span": mean_span,
        "slot_direct_s": slot_direct,
        "per_run": {trace_label(t, i): {"burst_rate_hz": 1.0 / s.period_s, "jitter_s": s.jitter_s,
                                        "phase_s": s.phase_s,
                                        "split_burst_frac": float(s.split.mean()) if s.split.size else None,
                                        "n_bursts": int(s.starts_s.size)}
                    for i, (t, s) in enumerate(zip(traces, scheds, strict=True))},
        "n_bursts": int(sum(s.starts_s.size for s in scheds)),
        "late_bursts": late_burst_fit(scheds, traces, slot_direct),
    }
    late = diag["late_bursts"]
    return Fit(params={"burst_rate_hz": 1.0 / period, "burst_jitter_s": jitter, "slot_s": slot_direct,
                       "burst_phase_s": phase,
                       "late_burst_prob": late["prob"] if late["applied"] else 0.0,
                       "late_burst_delay_s": late["delay_s"] if late["applied"] else None},
               n_samples=diag["n_bursts"], diagnostics=diag)


# --------------------------------------------------------------------------------------------------
# NLOS episode lengths: hidden Markov chain over LOS and the NLOS modes
# --------------------------------------------------------------------------------------------------


def _log_norm_pdf(x: np.ndarray, m: np.ndarray | float, s: float) -> np.ndarray:
    return -0.5 * ((x - m) / s) ** 2 - np.log(s) - 0.5 * np.log(2.0 * np.pi)


def _chain_log_product(mats: np.ndarray) -> tuple[np.ndarray, float]:
    """Product M_0 M_1 ... M_{n-1} of (n, K, K) non-negative matrices by pairwise reduction, rescaled.

    Returns (product divided by exp(log scale), log scale): log2(n) vectorised levels, no loop per row.
    """
    m, log_scale = mats, 0.0
    k = mats.shape[1]
    while m.shape[0] > 1:
        if m.shape[0] % 2:
            m = np.concatenate([m, np.eye(k)[None]], axis=0)
        m = m[0::2] @ m[1::2]
        s = m.max(axis=(1, 2), keepdims=True)
        s = np.where(s > 0, s, 1.0)
        m = m / s
        log_scale += float(np.log(s).sum())
    return m[0], log_scale


def mode_dwell_loglik(tau_s: np.ndarray, log_emis: np.ndarray, dt_s: np.ndarray, nlos_prob: float,
                      weights: np.ndarray) -> float:
    """Log-likelihood of an anchor's rows under the LOS / NLOS-mode chain with mean episode ``tau_s``.

    States 0 (LOS) and 1..M (NLOS mode m): LOS -> m at rate p w_m / ((1 - p) tau_m), m -> LOS at
    1 / tau_m (the generator's episodes: stationary shares 1 - p and p w_m, no mode-to-mode switch).
    ``log_emis`` (n, M + 1) is each row's log density in each state, ``dt_s`` (n,) the time since the
    previous row (a very large value starts a new run from the stationary law).
    """
    pi = np.concatenate([[1.0 - nlos_prob], nlos_prob * weights])
    m = weights.size
    q = np.zeros((m + 1, m + 1))
    q[0, 1:] = nlos_prob * weights / ((1.0 - nlos_prob) * tau_s)
    q[1:, 0] = 1.0 / tau_s
    q[np.diag_indices(m + 1)] = -q.sum(axis=1)
    d = np.sqrt(pi)
    sym = (d[:, None] * q) / d[None, :]
    sym = 0.5 * (sym + sym.T)
    lam, u = np.linalg.eigh(sym)
    lam = np.minimum(lam, 0.0)  # a generator's eigenvalues are <= 0 (rounding aside)
    a, b = u / d[:, None], u.T * d[None, :]
    p = np.einsum("ik,nk,kj->nij", a, np.exp(np.outer(np.minimum(dt_s, 1e6), lam)), b)
    p = np.clip(p, 0.0, None)
    mx = log_emis.max(axis=1, keepdims=True)
    e = np.exp(log_emis - mx)
    first = pi * e[0]
    prod, log_scale = _chain_log_product(p[1:] * e[1:, None, :]) if e.shape[0] > 1 else (np.eye(m + 1), 0.0)
    return float(np.log(max(float(first @ prod @ np.ones(m + 1)), 1e-300)) + log_scale + mx.sum())


def fit_mode_dwell(residual_m: np.ndarray, range_m: np.ndarray, t_s: np.ndarray, new_run: np.ndarray,
                   fit: MixtureFit, start_s: np.ndarray, free: np.ndarray) -> dict[str, Any]:
    """Maximum-likelihood mean episode length of each NLOS mode from an anchor's rows (all runs).

    Run lengths of rows classified NLOS cut an episode wherever one of its rows falls on the LOS side
    (modes close to the LOS peak) and count LOS rows in the tail as episodes of one row; the chain
    over the true state, with the mixture's densities as emissions, does not. ``start_s`` (M,) starts
    the search and holds the modes not ``free`` (e.g. fixed-length episodes) at their value.
    ``new_run`` (n,) marks each run's first row.
    """
    modes = fit.modes
    w = np.array([md.weight for md in modes])
    log_emis = np.column_stack([_log_norm_pdf(residual_m, fit.los_centre(range_m), fit.los_std_m)]
                               + [_log_norm_pdf(residual_m, md.mean_m, md.std_m) for md in modes])
    dt = np.diff(t_s, prepend=t_s[0])
    dt = np.where(new_run, 1e9, np.maximum(dt, 1e-6))
    p = float(np.clip(fit.nlos_prob, 1e-6, 1 - 1e-6))
    tau0 = np.asarray(start_s, dtype=float).copy()

    def nll(x: np.ndarray) -> float:
        tau = tau0.copy()
        tau[free] = np.exp(x)
        return -mode_dwell_loglik(tau, log_emis, dt, p, w)

    x0 = np.log(tau0[free])
    if x0.size == 0:
        return {"dwell_s": tau0, "converged": True}
    # from 3 x the run-length estimate (fragmentation only shortens it); log tau within [1 ms, 100 s]
    best = minimize(nll, np.clip(x0 + np.log(3.0), np.log(1e-3), np.log(100.0)), method="Nelder-Mead",
                    bounds=[(np.log(1e-3), np.log(100.0))] * int(free.sum()),
                    options={"xatol": 0.01, "fatol": 0.05, "maxiter": 200})
    tau = tau0.copy()
    tau[free] = np.clip(np.exp(best.x), 1e-3, 1e3)
    return {"dwell_s": tau, "log_likelihood": float(-best.fun), "log_likelihood_start": float(-nll(x0)),
            "converged": bool(best.success)}
