"""Dropout and outage of one anchor by exact maximum likelihood of the alternating up / outage process
sampled at the attempts (a two-state hidden Markov chain over the runs of missed attempts;
:func:`fit_dropout_outage`, step 3 of :mod:`physynth.calibrate.availability_fit`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, logit

OBSERVED_OUTAGE_MIN_MISSES = 2
"""Descriptive outage table: runs of at least this many consecutive missed attempts."""


@dataclass(slots=True)
class RunStats:
    """Run-length statistics of one anchor's observed attempt blocks (pooled over traces)."""

    internal: list[np.ndarray] = field(default_factory=list)  # misses between two heard attempts
    leading: list[np.ndarray] = field(default_factory=list)  # misses before the first heard of a block
    trailing: list[np.ndarray] = field(default_factory=list)  # misses after the last heard of a block
    full: list[np.ndarray] = field(default_factory=list)  # blocks without any heard attempt
    n_attempts: int = 0
    n_heard: int = 0
    span_s: float = 0.0
    durations_s: list[np.ndarray] = field(default_factory=list)  # descriptive: gaps of runs >= 2 misses
    censored_s: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        def cat(x: list[np.ndarray]) -> np.ndarray:
            return np.concatenate(x).astype(np.int64) if x else np.zeros(0, np.int64)

        return cat(self.internal), cat(self.leading), cat(self.trailing), cat(self.full)


def add_runs(stats: RunStats, t_s: np.ndarray, code: np.ndarray) -> None:
    """Add one anchor's attempt sequence: code 1 heard, 0 missed, -1 unobserved (splits blocks)."""
    obs = code >= 0
    if not obs.any():
        return
    stats.n_attempts += int(obs.sum())
    stats.n_heard += int((code == 1).sum())
    start_flag = obs & ~np.concatenate([[False], obs[:-1]])
    end_flag = obs & ~np.concatenate([obs[1:], [False]])
    b_start, b_end = np.flatnonzero(start_flag), np.flatnonzero(end_flag) + 1
    block = np.cumsum(start_flag) - 1  # block id of each (observed) position
    heard_idx = np.flatnonzero(code == 1)
    hb = block[heard_idx]
    # internal runs: consecutive heard positions in the same block
    same = np.diff(hb) == 0
    stats.internal.append((np.diff(heard_idx) - 1)[same])
    gaps_t = np.diff(t_s[heard_idx])[same]
    m_int = (np.diff(heard_idx) - 1)[same]
    stats.durations_s.append(gaps_t[m_int >= OBSERVED_OUTAGE_MIN_MISSES])
    # first / last heard per block
    first = np.full(b_start.size, -1)
    last = np.full(b_start.size, -1)
    if heard_idx.size:
        uniq, fi = np.unique(hb, return_index=True)
        first[uniq] = heard_idx[fi]
        _, li = np.unique(hb[::-1], return_index=True)
        last[uniq] = heard_idx[::-1][li]
    has = first >= 0
    stats.leading.append((first - b_start)[has])
    trail = (b_end - 1 - last)[has]
    stats.trailing.append(trail)
    cens = trail >= OBSERVED_OUTAGE_MIN_MISSES
    stats.censored_s.append((t_s[np.minimum(b_end - 1, t_s.size - 1)] - t_s[last])[has][cens])
    stats.full.append((b_end - b_start)[~has])
    stats.span_s += float(np.sum(t_s[b_end - 1] - t_s[b_start]))


def _matpow_rows(b: np.ndarray, v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """v B^m for a 2x2 matrix B, a row vector v (2,) and integer powers m (N,) -> (N, 2) (Sylvester)."""
    tr, det = np.trace(b), np.linalg.det(b)
    disc = max(tr * tr / 4.0 - det, 0.0)
    l1, l2 = tr / 2.0 + np.sqrt(disc), tr / 2.0 - np.sqrt(disc)
    vb = v @ b
    m = m.astype(float)
    if abs(l1 - l2) < 1e-12:
        # repeated eigenvalue: B^m = l^(m-1) (m B - (m-1) l I)
        lm1 = np.where(m > 0, l1 ** np.maximum(m - 1, 0), 0.0)
        return np.where(m[:, None] == 0, v, lm1[:, None] * (m[:, None] * vb - (m - 1)[:, None] * l1 * v))
    p1, p2 = l1**m, l2**m
    return ((p1[:, None] * (vb - l2 * v) - p2[:, None] * (vb - l1 * v)) / (l1 - l2))


def outage_chain(alpha: float, beta: float, pd: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    a = np.array([[1.0 - alpha, alpha], [beta, 1.0 - beta]])
    dm = np.diag([pd, 1.0])
    dh = np.array([1.0 - pd, 0.0])
    pi = np.array([beta, alpha]) / (alpha + beta) if alpha + beta > 0 else np.array([1.0, 0.0])
    return a, dm, dh, pi


def _hmm_loglik(alpha: float, beta: float, pd: float, runs: tuple[np.ndarray, ...]) -> float:
    internal, leading, trailing, full = runs
    a, dm, dh, pi = outage_chain(alpha, beta, pd)
    b = a @ dm
    up = np.array([1.0, 0.0])
    ahd = a @ dh
    ll = 0.0
    if internal.size:
        vals, cnt = np.unique(internal, return_counts=True)
        ll += float(np.sum(cnt * np.log(np.maximum(_matpow_rows(b, up, vals) @ ahd, 1e-300))))
    if leading.size:
        vals, cnt = np.unique(leading, return_counts=True)
        start = pi @ dm  # leading run l >= 1: pi Dm B^(l-1) A Dh 1; l = 0: pi Dh 1
        p = np.where(vals == 0, pi @ dh, _matpow_rows(b, start, np.maximum(vals - 1, 0)) @ ahd)
        ll += float(np.sum(cnt * np.log(np.maximum(p, 1e-300))))
    if trailing.size:
        vals, cnt = np.unique(trailing, return_counts=True)
        ll += float(np.sum(cnt * np.log(np.maximum(_matpow_rows(b, up, vals).sum(axis=1), 1e-300))))
    if full.size:
        vals, cnt = np.unique(full, return_counts=True)
        p = _matpow_rows(b, pi @ dm, np.maximum(vals - 1, 0)).sum(axis=1)
        ll += float(np.sum(cnt * np.log(np.maximum(p, 1e-300))))
    return ll


def _to_rates(alpha: float, beta: float, period_s: float) -> tuple[float, float]:
    """(onset rate [1/s], outage mean [s]) of the continuous process whose T-step matrix has alpha, beta."""
    s = alpha + beta
    if alpha <= 0:
        return 0.0, float("inf")
    total = -np.log(max(1.0 - s, 1e-300)) / period_s
    lam = alpha / s * total
    nu = beta / s * total
    return float(lam), float(1.0 / nu) if nu > 0 else float("inf")


def from_rates(lam: float, mean_s: float, period_s: float) -> tuple[float, float]:
    nu = 1.0 / mean_s
    s = lam + nu
    f = 1.0 - np.exp(-s * period_s)
    return lam / s * f, nu / s * f


def fit_dropout_outage(stats: RunStats, period_s: float, burst_rate_hz: float,
                       start: dict[str, Any] | None = None) -> dict[str, Any]:
    """ML dropout probability, outage onset per burst and outage mean from run-length statistics.

    ``start``: an earlier fit of the same anchor (on slightly different data) to start the search from.
    """
    runs = stats.arrays()
    n_att, n_heard = stats.n_attempts, stats.n_heard
    out: dict[str, Any] = {"n_attempts": n_att, "n_heard": n_heard, "attempt_period_s": period_s}
    if n_att == 0:
        out.update(identifiable=False, why="no attempt within link range to fit dropouts and outages on")
        return out
    miss_frac = 1.0 - n_heard / n_att
    # dropout-only model (alpha = 0): closed form
    pd0 = float(np.clip(miss_frac, 1e-9, 1 - 1e-9))
    ll0 = (n_att - n_heard) * np.log(pd0) + n_heard * np.log(1 - pd0)

    def nll(theta: np.ndarray) -> float:
        al, be, pd = expit(theta)
        return -_hmm_loglik(al, be, pd, runs)

    best = None
    starts = [(0.01, 0.3, 0.5 * miss_frac), (0.001, 0.05, 0.8 * miss_frac), (0.05, 0.6, 0.1 * miss_frac),
              (1e-4, 0.005, 0.5 * miss_frac)]
    if start is not None and start.get("identifiable") and start.get("outage_onset_prob", 0.0) > 0:
        a0, b0 = from_rates(start["outage_onset_prob"] * burst_rate_hz, start["outage_mean_s"], period_s)
        starts = [(a0, b0, start["dropout_prob"]), starts[0]]
    for a0, b0, d0 in starts:  # a few starts of a 3-parameter optimisation
        x0 = logit(np.clip([a0, b0, d0], 1e-6, 1 - 1e-6))
        res = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-7, "fatol": 1e-9, "maxiter": 4000})
        if best is None or res.fun < best.fun:
            best = res
    alpha, beta, pd = (float(x) for x in expit(best.x))
    lr = 2.0 * (-best.fun - ll0)
    lam, mean_s = _to_rates(alpha, beta, period_s)
    out.update(log_likelihood=float(-best.fun), log_likelihood_dropout_only=float(ll0), lr_outage=float(lr),
               missed_frac=miss_frac)
    if lr < 10.0:
        out.update(identifiable=False, dropout_prob=pd0, outage_onset_prob=0.0, outage_mean_s=None,
                   why=f"no evidence of outages beyond independent dropouts (LR {lr:.1f} < 10)")
        out["dropout_prob_se"] = float(np.sqrt(pd0 * (1 - pd0) / n_att))
        return out
    onset = lam / burst_rate_hz
    span_s = n_att * period_s  # the time this anchor was observed, over all runs
    if not mean_s <= span_s:  # longer, or infinite (the outage state never left)
        # the outages outlast the recording (one covers a whole run, none ends): the likelihood keeps
        # growing with the mean, which the data bounds only from below; keep the recorded span
        out.update(identifiable=True, dropout_prob=pd, outage_onset_prob=onset, outage_mean_s=span_s,
                   outage_mean_censored=True, outage_mean_ml_s=float(min(mean_s, 1e300)),
                   why=(f"the outages outlast the recording: mean outage length set to the {span_s:.0f} s "
                        "observed (a lower bound)"))
        return out
    out.update(identifiable=True, dropout_prob=pd, outage_onset_prob=onset, outage_mean_s=mean_s)
    out.update(_hmm_standard_errors(pd, onset, mean_s, period_s, burst_rate_hz, runs))
    return out


def _hmm_standard_errors(pd: float, onset: float, mean_s: float, period_s: float, burst_rate_hz: float,
                         runs: tuple[np.ndarray, ...]) -> dict[str, float]:
    """Standard errors from the inverse numerical Hessian of the log-likelihood in log-parameters."""
    x0 = np.log([max(pd, 1e-9), onset, mean_s])

    def ll(x: np.ndarray) -> float:
        p, o, m = np.exp(x)
        if p >= 1:
            return -1e300
        al, be = from_rates(o * burst_rate_hz, m, period_s)
        return _hmm_loglik(al, be, p, runs)

    h = 1e-3
    n = 3
    hess = np.zeros((n, n))
    f0 = ll(x0)
    for i in range(n):  # 3 x 3 finite differences
        for j in range(i, n):
            ei, ej = np.eye(n)[i] * h, np.eye(n)[j] * h
            if i == j:
                v = (ll(x0 + ei) - 2 * f0 + ll(x0 - ei)) / h**2
            else:
                v = (ll(x0 + ei + ej) - ll(x0 + ei - ej) - ll(x0 - ei + ej) + ll(x0 - ei - ej)) / (4 * h * h)
            hess[i, j] = hess[j, i] = v
    try:
        cov = np.linalg.inv(-hess)
        rel = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        rel = np.full(n, np.nan)
    if pd < 1e-6:
        rel[0] = np.nan
    return {"dropout_prob_se": float(pd * rel[0]), "outage_onset_prob_se": float(onset * rel[1]),
            "outage_mean_s_se": float(mean_s * rel[2])}
