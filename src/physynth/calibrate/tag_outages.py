"""Tag outages jointly with the per-anchor outages (:func:`fit_tag_outages`, step 4 of
:mod:`physynth.calibrate.availability_fit`): every dark run of at least ``TAG_OUTAGE_MIN_S`` is a tag
outage or an overlap of per-anchor outages, decided by EM over the joint likelihood of the per-anchor
chains and the tag chain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import expit

from .attempts import AttemptTable
from .dropout_outage import from_rates, outage_chain

TAG_OUTAGE_MIN_S = 1.0
"""Dark runs (no in-range anchor heard) at least this long [s] are candidate tag outages; shorter ones are
left to coincident dropouts and outages (the tag durations are fitted left-truncated here)."""


def dark_runs(tab: AttemptTable, in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of bursts where no anchor is heard, each with at least one burst where an anchor is in range.

    Bursts without any in-range attempt do not end a run (they say nothing about the tag). Returns
    (start index, end index exclusive, censored) of each run; censored runs touch the data's ends.
    """
    any_heard = tab.heard.any(axis=1)
    any_in = (in_range & tab.attempted).any(axis=1)
    x = np.concatenate([[0], (~any_heard).astype(np.int8), [0]])
    d = np.diff(x)
    s, e = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    n_in = np.concatenate([[0], np.cumsum(any_in & ~any_heard)])
    keep = n_in[e] > n_in[s]
    s, e = s[keep], e[keep]
    cens = (s == 0) | (e == any_heard.size)
    return s, e, cens


@dataclass(frozen=True, slots=True)
class AnchorSequence:
    """One anchor's attempts in one trace: burst index of each attempt, code 1 heard / 0 missed / -1 out of range."""

    trace: int
    anchor_id: str
    burst: np.ndarray
    code: np.ndarray


def anchor_sequences(trace_anchor_ids: Sequence[Sequence[str]], tabs: Sequence[AttemptTable],
                      in_range: Sequence[np.ndarray]) -> list[AnchorSequence]:
    out = []
    for i, (ids, tab, ok) in enumerate(zip(trace_anchor_ids, tabs, in_range, strict=True)):
        for j, aid in enumerate(ids):  # one pass per anchor
            att = np.flatnonzero(tab.attempted[:, j])
            code = np.where(ok[att, j], np.where(tab.heard[att, j], 1, 0), -1).astype(np.int8)
            out.append(AnchorSequence(trace=i, anchor_id=aid, burst=att, code=code))
    return out


def _log_vbw(b: np.ndarray, v: np.ndarray, w: np.ndarray, m: np.ndarray) -> np.ndarray:
    """log(v B^m w) for a non-negative 2x2 matrix B and integer powers m (N,), in log space (no underflow)."""
    m = np.asarray(m, dtype=float)
    tr, det = np.trace(b), np.linalg.det(b)
    disc = max(tr * tr / 4.0 - det, 0.0)
    l1, l2 = tr / 2.0 + np.sqrt(disc), tr / 2.0 - np.sqrt(disc)  # l1 >= |l2| (Perron-Frobenius)
    vw, vbw = float(v @ w), float(v @ b @ w)
    l1 = max(l1, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        if l1 - l2 < 1e-9 * l1:  # repeated eigenvalue: v B^m w = l^(m-1) (m vBw - (m-1) l vw)
            val = np.where(m == 0, vw, (m * vbw - (m - 1) * l1 * vw) / l1)
        else:
            r = l2 / l1
            c1, c2 = (vbw - l2 * vw) / (l1 - l2), (l1 * vw - vbw) / (l1 - l2)
            val = c1 + c2 * np.sign(r) ** m * np.abs(r) ** m
        return m * np.log(l1) + np.log(np.maximum(val, 1e-300))


def _run_logp(alpha: float, beta: float, pd: float, kind: str, m: np.ndarray) -> np.ndarray:
    """Log-probability of runs of m missed attempts of one anchor (the kinds of :class:`~.dropout_outage.RunStats`).

    internal: heard, m misses, heard (the first heard not counted); leading: block start, m misses,
    heard; trailing: heard, m misses, block end; full: block start, m misses, block end (m = 0: no block).
    """
    a, dm, dh, pi = outage_chain(alpha, beta, pd)
    b = a @ dm
    up, one = np.array([1.0, 0.0]), np.ones(2)
    m = np.asarray(m, dtype=np.int64)
    mm1 = np.maximum(m - 1, 0)
    if kind == "internal":
        return _log_vbw(b, up, a @ dh, m)
    if kind == "trailing":
        return _log_vbw(b, up, one, m)
    if kind == "leading":
        return np.where(m == 0, np.log(max(float(pi @ dh), 1e-300)), _log_vbw(b, pi @ dm, a @ dh, mm1))
    if kind == "full":
        return np.where(m == 0, 0.0, _log_vbw(b, pi @ dm, one, mm1))
    raise ValueError(kind)


def _chain_of_fit(fit: dict[str, Any], burst_rate_hz: float) -> tuple[float, float, float]:
    """(alpha, beta, dropout) per attempt interval of a per-anchor fit (alpha = 0: no outages)."""
    pd = float(np.clip(fit.get("dropout_prob", 0.0), 1e-9, 1 - 1e-9))
    if fit.get("identifiable") and fit.get("outage_onset_prob", 0.0) > 0 and fit.get("outage_mean_s"):
        al, be = from_rates(fit["outage_onset_prob"] * burst_rate_hz, fit["outage_mean_s"], fit["attempt_period_s"])
        return al, be, pd
    return 0.0, 1.0, pd


def run_neighbours(seq: AnchorSequence, s: np.ndarray, e: np.ndarray, masked: np.ndarray) -> dict[str, np.ndarray]:
    """Where the anchor's run of misses through each dark run [s, e) begins and ends (attempt indices).

    ``prev`` / ``nxt``: its last / next attempt with a code other than "missed" before / from the run
    (-1 / n when none), whether those were heard, and ``use``: the anchor is in link range over the
    whole run and attempted in it (an anchor out of range during part of run k says nothing about it).
    ``masked`` (bursts) marks the dark runs currently attributed to the tag: they bound the runs.
    """
    burst, code0 = seq.burst, seq.code
    code = np.where(masked[burst], -1, code0)
    ps, pe = np.searchsorted(burst, s), np.searchsorted(burst, e)  # its attempts inside [s, e)
    oor = np.concatenate([[0], np.cumsum(code0 == -1)])
    nz = np.flatnonzero(code != 0)
    n = code.size
    ip = np.searchsorted(nz, ps) - 1
    has_prev = ip >= 0
    prev = np.where(has_prev, nz[np.maximum(ip, 0)] if nz.size else -1, -1)
    inx = np.searchsorted(nz, pe)
    has_next = inx < nz.size
    nxt = np.where(has_next, nz[np.minimum(inx, nz.size - 1)] if nz.size else n, n)
    return {"ps": ps, "pe": pe, "prev": prev, "nxt": nxt, "use": (pe > ps) & (oor[pe] == oor[ps]),
            "left_heard": has_prev & (code[np.maximum(prev, 0)] == 1),
            "right_heard": has_next & (code[np.minimum(nxt, n - 1)] == 1)}


def split_logp(chain: tuple[float, float, float], heard: np.ndarray, m: np.ndarray, side: str) -> np.ndarray:
    """Log-probability of the piece of an anchor's run of misses on one side (``side``) of a tag outage.

    ``left``: m misses after a heard attempt (or the block start) up to the outage; ``right``: m misses
    from the outage's end to a heard attempt (or the block end).
    """
    al, be, pd = chain
    cut = "trailing" if side == "left" else "leading"
    return np.where(heard, _run_logp(al, be, pd, cut, m), _run_logp(al, be, pd, "full", m))


def whole_logp(chain: tuple[float, float, float], lh: np.ndarray, rh: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Log-probability of an anchor's whole run of m misses through a dark run (no tag outage)."""
    al, be, pd = chain
    out = np.zeros(m.shape)
    for lft in (False, True):  # the four kinds of run
        for rgt in (False, True):
            sel = (lh == lft) & (rh == rgt)
            if sel.any():
                kind = {(True, True): "internal", (True, False): "trailing", (False, True): "leading",
                        (False, False): "full"}[(lft, rgt)]
                out[sel] = _run_logp(al, be, pd, kind, m[sel])
    return out


def _tag_log_odds_parts(p: np.ndarray, q: np.ndarray, n_bursts: int, alpha: float, beta: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """The tag chain's log-odds of "off exactly over [p, q), up around it" against "up throughout",
    split as T_p(p) + T_q(q) (it depends on the outage's length only linearly)."""
    lo_a, lo_1a = np.log(max(alpha, 1e-300)), np.log1p(-min(alpha, 1 - 1e-12))
    lo_b, lo_1b = np.log(max(beta, 1e-300)), np.log1p(-min(beta, 1 - 1e-12))
    pi_off = alpha / (alpha + beta)
    d = lo_1b - lo_1a
    at0 = p == 0
    t_p = (np.where(at0, np.log(max(pi_off, 1e-300)) + lo_1a - np.log1p(-min(pi_off, 1 - 1e-12)), lo_a)
           - p * d - lo_1b - lo_1a)
    t_q = np.where(q < n_bursts, lo_b, lo_1a) + q * d
    return t_p, t_q


def tag_log_odds(s: np.ndarray, e: np.ndarray, n_bursts: int, alpha: float, beta: float) -> np.ndarray:
    """log P(tag off exactly over [s, e), up around it) - log P(tag up throughout), per burst-grid run."""
    t_p, t_q = _tag_log_odds_parts(s, e, n_bursts, alpha, beta)
    return t_p + t_q


def boundary_positions(s: np.ndarray, e: np.ndarray, min_len: int) -> tuple[np.ndarray, ...]:
    """Every possible start and end of a tag outage of at least ``min_len`` bursts inside each dark run.

    Starts p in [s_k, e_k - min_len] and ends q in [s_k + min_len, e_k] of each dark run k, returned as
    (p, run of p, q, run of q), flat over the runs.
    """
    n_pos = np.maximum(e - s - min_len + 1, 0)
    run = np.repeat(np.arange(s.size), n_pos)
    off = np.arange(run.size) - np.repeat(np.cumsum(n_pos) - n_pos, n_pos)
    return s[run] + off, run, s[run] + min_len + off, run


def _anchor_boundary_terms(seq: AnchorSequence, s: np.ndarray, e: np.ndarray, masked: np.ndarray,
                           chain: tuple[float, float, float], pos: tuple[np.ndarray, ...]
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One anchor's log-likelihood terms of a tag outage over [p, q) inside each dark run [s, e).

    Its attempts in [p, q) are unobserved; its misses from the dark run's start to p end a trailing
    piece, those from q to the run's end begin a leading one: f(p) + g(q). Returns (f at every start of
    ``pos``, g at every end, the log-probability of the whole run without tag outage), zero where the
    anchor says nothing about the run.
    """
    nb = run_neighbours(seq, s, e, masked)
    p, rp, q, rq = pos
    m1 = np.searchsorted(seq.burst, p) - nb["prev"][rp] - 1
    m2 = nb["nxt"][rq] - np.searchsorted(seq.burst, q)
    m0 = nb["nxt"] - nb["prev"] - 1
    use = nb["use"]
    f = np.where(use[rp], split_logp(chain, nb["left_heard"][rp], m1, "left"), 0.0)
    g = np.where(use[rq], split_logp(chain, nb["right_heard"][rq], m2, "right"), 0.0)
    whole = np.where(use, whole_logp(chain, nb["left_heard"], nb["right_heard"], m0), 0.0)
    return f, g, whole


def _tag_posterior(s: np.ndarray, e: np.ndarray, n_bursts: int, f: np.ndarray, g: np.ndarray, whole: np.ndarray,
                   pos: tuple[np.ndarray, ...], tag_chain: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Log-odds that each dark run holds a tag outage, and the outage's expected length [bursts] if so.

    The outage may begin after the run's start and end before its end (the anchors' own outages and
    dropouts then fill the edges: the run is longer than the tag outage). Summed over every [p, q)
    with q - p >= the minimum length: the terms separate as A(p) + B(q), so the sum over p <= q - min
    is a running log-sum (one pass per run, over its bursts).
    """
    p, rp, q, rq = pos
    t_p, t_q = _tag_log_odds_parts(p, q, n_bursts, *tag_chain)
    a_all, b_all = f + t_p, g + t_q
    odds, length = np.full(s.size, -np.inf), (e - s).astype(float)
    bounds = np.searchsorted(rp, np.arange(s.size + 1))  # rp and rq share the same run blocks
    for k in np.flatnonzero(np.diff(bounds) > 0):  # one pass per dark run, vectorised over its bursts
        sl = slice(bounds[k], bounds[k + 1])
        a, b = a_all[sl], b_all[sl]  # start j pairs with ends j' >= j (q - p >= min_len)
        pre = np.logaddexp.accumulate(a)  # log sum of exp(a) over starts up to j
        suf = np.logaddexp.accumulate(b[::-1])[::-1]  # log sum of exp(b) over ends from j
        z = float(np.logaddexp.reduce(b + pre))
        e_q = float(np.sum(q[sl] * np.exp(b + pre - z)))
        e_p = float(np.sum(p[sl] * np.exp(a + suf - z)))
        odds[k] = z - float(whole[k])
        length[k] = e_q - e_p
    return odds, length


def tag_m_step(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]], w: list[np.ndarray],
                period: float, lengths: list[np.ndarray] | None = None) -> dict[str, Any]:
    """The EM's M-step: onset rate and mean of exponential tag outages seen only above TAG_OUTAGE_MIN_S.

    ``w`` weights each dark run by the probability that it is a tag outage (0 or 1 for a hard split);
    ``lengths`` (bursts, per dark run) are the tag outages' expected lengths inside the runs (the E-step's),
    else the runs' own lengths.
    """
    d_min = TAG_OUTAGE_MIN_S
    dur = (np.concatenate(lengths) * period if lengths is not None
           else np.concatenate([(e - s) * period for s, e, _ in dark]))
    cens = np.concatenate([c for _, _, c in dark])
    # an outage under way when the trace begins has no onset in it, but its end is seen (the exponential
    # forgets: what is left of it is exponential with the same mean); one still under way at the end
    # has an onset and no end
    started = np.concatenate([s > 0 for s, _, _ in dark])
    ended = np.concatenate([e < t.t_s.size for (_, e, _), t in zip(dark, tabs, strict=True)])
    wt = np.concatenate(w).astype(float)
    hard = wt > 0.5
    onsets = float(np.sum(wt[started]))
    up_bursts = float(sum(t.t_s.size for t in tabs) - np.sum(wt * dur / period))
    out: dict[str, Any] = {"min_duration_s": d_min, "n_outages": int((hard & ~cens).sum()),
                           "n_censored": int((hard & cens).sum()), "events": onsets,
                           "up_bursts": up_bursts, "effective_up_bursts": up_bursts,
                           "durations_s": dur[hard & ~cens].tolist(), "censored_s": dur[hard & cens].tolist()}
    if wt.sum() < 0.5:
        out["onset_prob"] = 0.0
        return out
    # exponential durations seen only above d_min: the excess D - d_min is exponential with the same mean
    # (every attributed stretch counts as exposure, every seen end as an event), and only a share
    # exp(-d_min / mean) of the outages is long enough to be attributed
    mean_s = max(float(np.sum(wt * (dur - d_min).clip(0))) / max(float(np.sum(wt[ended])), 0.5), period)
    seen = float(np.exp(-d_min / mean_s))
    out.update(mean_s=mean_s, effective_up_bursts=up_bursts * seen,
               onset_prob=float(onsets / max(up_bursts * seen, 1)))
    return out


def _masks(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]],
           z: list[np.ndarray]) -> list[np.ndarray]:
    """Bursts inside the dark runs flagged in ``z``, per trace."""
    masks = []
    for tab, (s, e, _), zz in zip(tabs, dark, z, strict=True):
        m = np.zeros(tab.t_s.size + 1, dtype=np.int64)
        np.add.at(m, s[zz], 1)
        np.add.at(m, e[zz], -1)
        masks.append(np.cumsum(m)[:-1] > 0)
    return masks


def tag_e_step(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]], cand: list[np.ndarray],
                pos: list[tuple[np.ndarray, ...]], seqs: Sequence[AnchorSequence], masks: list[np.ndarray],
                chains: dict[str, tuple[float, float, float]], tag_chain: tuple[float, float]
                ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The EM's E-step: per trace, each dark run's log-odds of holding a tag outage and its expected length.

    The log-odds are -inf for runs shorter than the minimum; the expected length [bursts] is the run's
    own length where it is not a candidate.
    """
    n_pos = [p[0].size for p in pos]
    f = [np.zeros(n) for n in n_pos]
    g = [np.zeros(n) for n in n_pos]
    whole = [np.zeros(int(c.sum())) for c in cand]
    for sq in seqs:  # one pass per anchor and trace
        s, e, _ = dark[sq.trace]
        c = cand[sq.trace]
        if not c.any():
            continue
        fa, ga, wa = _anchor_boundary_terms(sq, s[c], e[c], masks[sq.trace], chains[sq.anchor_id], pos[sq.trace])
        f[sq.trace] += fa
        g[sq.trace] += ga
        whole[sq.trace] += wa
    odds, lengths = [], []
    for i, (tab, (s, e, _), c) in enumerate(zip(tabs, dark, cand, strict=True)):
        o, ln = np.full(s.size, -np.inf), (e - s).astype(float)
        if c.any():
            o[c], ln[c] = _tag_posterior(s[c], e[c], tab.t_s.size, f[i], g[i], whole[i], pos[i], tag_chain)
        odds.append(o)
        lengths.append(ln)
    return odds, lengths


TAG_EM_MAX_ITER = 30
"""EM iterations of the tag attribution (it stops when no attribution and no tag parameter changes)."""

TAG_EM_RTOL = 1e-3
"""Relative change of the tag onset and mean below which the EM has converged."""

TAG_LR_MIN = 10.0
"""Likelihood-ratio statistic a tag process needs over independent per-anchor outages alone."""


def fit_tag_outages(tabs: Sequence[AttemptTable], dark: Sequence[tuple[np.ndarray, ...]],
                    seqs: Sequence[AnchorSequence], fits: dict[str, dict[str, Any]],
                    refit: Any, burst_rate_hz: float) -> tuple[dict[str, Any], list[np.ndarray], Any, Any]:
    """Tag outages and per-anchor outages jointly: which dark runs are tag outages (EM).

    Model: every anchor alternates up/outage on its own (the per-anchor chain of
    :func:`~.dropout_outage.fit_dropout_outage`); a tag process of the same kind, on the burst grid, silences every
    anchor while it lasts. A *dark run* (no anchor heard, >= TAG_OUTAGE_MIN_S) is either a tag outage
    or holds a tag outage of at least TAG_OUTAGE_MIN_S, over the whole run or part of it (the anchors'
    own outages filling the edges). E-step: for each dark run the log-odds of the two, summed over every
    placement [p, q) of the tag outage in the run: the tag chain's term (off exactly over [p, q) vs up
    throughout) plus, per anchor in link range over the run, the exact likelihood of its run of misses
    through the dark run whole (no tag outage) or cut by [p, q); its posterior probability of holding a
    tag outage is expit(log-odds), with the outage's expected length. M-step: tag onset and mean from
    the dark runs weighted by that probability, of those expected lengths (left-truncated at
    TAG_OUTAGE_MIN_S); per-anchor fits with the runs of probability > 0.5 unobserved (``refit``, only
    when that set changes). Starts from every dark run attributed to the tag. The tag process is kept
    when the classification likelihood (tag chain plus per-anchor fits, runs split at 0.5) beats the
    per-anchor fits alone by TAG_LR_MIN. Returns (tag report, excluded bursts per trace, per-anchor
    stats, per-anchor fits); per-anchor stats are None when no tag process is kept.
    """
    period = 1.0 / burst_rate_hz
    d_min_bursts = TAG_OUTAGE_MIN_S * burst_rate_hz - 1e-9
    cand = [(e - s) >= d_min_bursts for s, e, _ in dark]
    pos = [boundary_positions(s[c], e[c], int(np.ceil(d_min_bursts))) for (s, e, _), c in zip(dark, cand, strict=True)]
    lengths: list[np.ndarray] | None = None
    no_ex = [np.zeros(t.t_s.size, dtype=bool) for t in tabs]
    n_cand = int(sum(c.sum() for c in cand))
    ll_indep = float(sum(f.get("log_likelihood", 0.0) for f in fits.values()))
    if not n_cand:
        tag = tag_m_step(tabs, dark, [np.zeros(c.size) for c in cand], period)
        tag["note"] = f"no run of >= {TAG_OUTAGE_MIN_S:.3g} s without any in-range anchor: no tag outage"
        return tag, no_ex, None, None
    w = [c.astype(float) for c in cand]
    z = [c.copy() for c in cand]
    z_fitted: list[np.ndarray] | None = None
    history: list[float] = []
    cur_fits, stats_t, prev = fits, None, None
    masks = no_ex
    for _ in range(TAG_EM_MAX_ITER):
        # M-step: per-anchor fits when the set of tag outages changed, tag process from the weights
        if z_fitted is None or not all(np.array_equal(a, b) for a, b in zip(z, z_fitted, strict=True)):
            masks = _masks(tabs, dark, z)
            if any(zz.any() for zz in z):
                stats_t, cur_fits = refit(masks, cur_fits)
            else:
                stats_t, cur_fits = None, fits
            z_fitted = [zz.copy() for zz in z]
        tag = tag_m_step(tabs, dark, w, period, lengths)
        history.append(round(tag["events"], 2))
        if not tag["onset_prob"]:
            break
        par = np.array([tag["onset_prob"], tag["mean_s"]])
        if prev is not None and np.all(np.abs(par - prev) <= TAG_EM_RTOL * prev):
            break
        prev = par
        al_t, be_t = from_rates(tag["onset_prob"] * burst_rate_hz, tag["mean_s"], period)
        # E-step: over where in each dark run the tag outage begins and ends
        odds, lengths = tag_e_step(tabs, dark, cand, pos, seqs, masks,
                                    {a: _chain_of_fit(f, burst_rate_hz) for a, f in cur_fits.items()}, (al_t, be_t))
        w = [np.where(c, expit(o), 0.0) for o, c in zip(odds, cand, strict=True)]
        z = [ww > 0.5 for ww in w]
    n_tag = int(sum(zz.sum() for zz in z_fitted or z))
    ll_tag = 0.0
    if n_tag and tag["onset_prob"]:
        al_t, be_t = from_rates(tag["onset_prob"] * burst_rate_hz, tag["mean_s"], period)
        # tag chain: up -> up on every transition, plus each attributed run's log-odds against staying up
        ll_tag = float(sum((tab.t_s.size - 1) * np.log1p(-al_t) + np.sum(tag_log_odds(s[zz], e[zz], tab.t_s.size,
                                                                                        al_t, be_t))
                           for tab, (s, e, _), zz in zip(tabs, dark, z_fitted or z, strict=True)))
    ll_joint = float(sum(f.get("log_likelihood", 0.0) for f in cur_fits.values())) + ll_tag
    lr = 2.0 * (ll_joint - ll_indep) if n_tag else 0.0
    tag.update(method=("EM over the dark runs (no in-range anchor heard) of at least min_duration_s: each is a tag "
                       "outage or an overlap of per-anchor outages, by the joint likelihood of the per-anchor "
                       "up/outage chains and the tag chain; exponential tag durations truncated at min_duration_s; "
                       "events = sum of the runs' tag probabilities"),
               n_candidates=n_cand, em_iterations=len(history), events_per_iteration=history,
               lr_statistic=float(lr))
    if n_tag == 0 or lr < TAG_LR_MIN:
        tag = tag_m_step(tabs, dark, [np.zeros(c.size) for c in cand], period)
        tag.update(n_candidates=n_cand, lr_statistic=float(lr),
                   note=(f"{n_cand} dark runs of >= {TAG_OUTAGE_MIN_S:.3g} s, explained by overlapping per-anchor "
                         f"outages (tag process LR {lr:.1f} < {TAG_LR_MIN:g}): no tag outage"))
        return tag, no_ex, None, None
    return tag, masks, stats_t, cur_fits
