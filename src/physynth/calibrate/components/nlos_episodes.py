"""Component ``nlos_episodes``: how long an anchor stays in each NLOS mode, and whether the mode's
offset is held over an episode.

Episodes are runs of consecutive rows of one anchor most likely in that mode; short ones (gross
outliers) are pooled over modes and anchors; a fragmented mode near the LOS peak gets its episode
length from the LOS / NLOS-mode Markov chain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...scenario import ChannelParams, NlosMode, UwbParams
from .._base import rounded
from ..anchor_channels import Channels
from ..component import CalibrationContext, Component
from ..report import ReportBuilder
from ..uwb_fit import MixtureFit, ModeFit, fit_mode_dwell


def nlos_run_lengths(flags: list[np.ndarray]) -> np.ndarray:
    lengths = []
    for f in flags:
        x = np.concatenate([[0], f.astype(np.int8), [0]])
        d = np.diff(x)
        lengths.append(np.flatnonzero(d == -1) - np.flatnonzero(d == 1))
    return np.concatenate(lengths) if lengths else np.zeros(0, np.int64)

MIN_MODE_EPISODES = 2
"""A mixture mode gets its own NLOS episode length from at least this many episodes (else uwb.nlos_dwell_s)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeEpisodes:
    """The episodes of one NLOS mode: runs of consecutive rows of one anchor most likely in that mode."""

    lengths: np.ndarray  # (E,) rows per episode
    within_dev_m: np.ndarray  # residuals minus their episode's median, rows of episodes of >= 2 rows
    within_dev_rel: np.ndarray  # the same divided by the std of the episode's mode (pools modes of any width)

    @property
    def n_within(self) -> int:
        return int(self.within_dev_m.size)

    @property
    def within_std_m(self) -> float | None:
        """Robust (MAD) scatter of the residuals inside an episode: a few merged episodes do not count."""
        if self.within_dev_m.size == 0:
            return None
        return float(1.4826 * np.median(np.abs(self.within_dev_m)))

    @property
    def within_std_rel(self) -> float | None:
        """Within-episode scatter as a fraction of the mode's std (MAD): small when the offset is held."""
        if self.within_dev_rel.size == 0:
            return None
        return float(1.4826 * np.median(np.abs(self.within_dev_rel)))


def mode_episodes(residual_m: np.ndarray, flags: list[np.ndarray], modes: Sequence[ModeFit]) -> list[ModeEpisodes]:
    """Episodes of each mode, with the spread of the residuals inside an episode (is the offset held?)."""
    lengths = _mode_runs(residual_m, flags, modes, keep_ids=True)
    out = []
    for mode, (run_len, run_id) in zip(modes, lengths, strict=True):
        if run_id is None or run_len.size == 0:
            out.append(ModeEpisodes(lengths=run_len, within_dev_m=np.zeros(0), within_dev_rel=np.zeros(0)))
            continue
        r = np.asarray(residual_m)[run_id >= 0]
        ids = run_id[run_id >= 0]
        counts = np.bincount(ids)
        multi = counts[ids] >= 2
        order = np.lexsort((r, ids))  # rows sorted by episode, then value: the median of each episode
        r_s, id_s = r[order], ids[order]
        starts = np.searchsorted(id_s, np.arange(counts.size))
        med = 0.5 * (r_s[np.minimum(starts + (counts - 1) // 2, r_s.size - 1)]
                     + r_s[np.minimum(starts + counts // 2, r_s.size - 1)])
        dev = r[multi] - med[ids[multi]]
        out.append(ModeEpisodes(lengths=run_len, within_dev_m=dev, within_dev_rel=dev / mode.std_m))
    return out


def _mode_runs(residual_m: np.ndarray, flags: list[np.ndarray], modes: Sequence[ModeFit], *, keep_ids: bool = False
               ) -> list[Any]:
    """Run lengths of consecutive NLOS rows in the same mixture mode (most likely mode per row), per mode.

    With ``keep_ids``: per mode (lengths, run id of every row (N,), -1 for rows of other modes or LOS).
    """
    if not modes or not flags:
        return [(np.zeros(0, np.int64), None) if keep_ids else np.zeros(0, np.int64) for _ in modes]
    w = np.array([m.weight for m in modes])
    mu = np.array([m.mean_m for m in modes])
    sd = np.array([m.std_m for m in modes])
    r = np.asarray(residual_m)
    best = np.argmax(np.log(w)[None, :] - np.log(sd)[None, :] - 0.5 * ((r[:, None] - mu) / sd) ** 2, axis=1)
    out: list[list[np.ndarray]] = [[] for _ in modes]
    run_id = [np.full(r.size, -1, dtype=np.int64) for _ in modes]
    n_runs = [0] * len(modes)
    start = 0
    for f in flags:  # one pass per trace, vectorised over its rows
        lab = np.where(f, best[start:start + f.size], -1)
        edges = np.flatnonzero(np.diff(lab)) + 1
        seg_start = np.concatenate([[0], edges])
        seg_len = np.diff(np.concatenate([seg_start, [lab.size]]))
        seg_lab = lab[seg_start] if lab.size else lab
        seg_of_row = np.repeat(np.arange(seg_start.size), seg_len)
        for j in range(len(modes)):
            sel = seg_lab == j
            out[j].append(seg_len[sel])
            if keep_ids and sel.any():
                local = np.cumsum(sel) - 1 + n_runs[j]  # run number of each segment of mode j
                rows = np.flatnonzero(lab == j)
                run_id[j][start + rows] = local[seg_of_row[rows]]
                n_runs[j] += int(sel.sum())
        start += f.size
    lengths = [np.concatenate(x) if x else np.zeros(0, np.int64) for x in out]
    return [(x, i) for x, i in zip(lengths, run_id, strict=True)] if keep_ids else lengths

SHORT_EPISODE_MAX_ROWS = 5.0
"""Modes whose episodes last at most this many rows on average are *short* (gross outliers)."""


def is_short(ep: ModeEpisodes) -> bool:
    return ep.lengths.size < MIN_MODE_EPISODES or float(ep.lengths.mean()) <= SHORT_EPISODE_MAX_ROWS


def pool_episodes(eps: Sequence[ModeEpisodes]) -> ModeEpisodes:
    """Episodes of several modes as one sample."""
    lengths = np.concatenate([e.lengths for e in eps]) if eps else np.zeros(0, np.int64)
    dev = np.concatenate([e.within_dev_m for e in eps]) if eps else np.zeros(0)
    rel = np.concatenate([e.within_dev_rel for e in eps]) if eps else np.zeros(0)
    return ModeEpisodes(lengths=lengths, within_dev_m=dev, within_dev_rel=rel)

HELD_MAX_STD_RATIO = 0.3
"""A mode's offset is *held* over an episode when the residuals inside its episodes scatter by less than
this fraction of the mode's std (one reflector or one wrong range per episode, not a fresh draw per row)."""

FIXED_MAX_EXCESS_ROWS = 1
"""Short episodes have a *fixed* length K (the modal length, K >= 2) when 90 % of them last at most
K + this many rows; exponential episodes give geometric lengths, whose mode is always 1."""


def episode_shape(mode: ModeFit, ep: ModeEpisodes, attempt_period_s: float, burst_period_s: float, *,
                   short: bool) -> dict[str, Any]:
    """Episode length law and offset holding of one NLOS mode, from its episodes.

    Exponential episodes (default) get the geometric MLE of their mean. Short episodes (``short``: the
    pooled episodes of the short modes) of nearly constant length (:data:`FIXED_MAX_EXCESS_ROWS`, at
    least :data:`MIN_MODE_EPISODES` + 1 episodes) are a wrong range the radio repeats for K bursts: K
    is the most common episode length in rows (lost attempts shorten some episodes, never lengthen
    them) and the episode lasts K burst periods. Their offset is held when the within-episode scatter
    passes :data:`HELD_MAX_STD_RATIO`.
    """
    n = ep.lengths
    out: dict[str, Any] = {"n_episodes": int(n.size), "dwell_s": None, "fixed_dwell": False, "held_jitter_m": None,
                           "within_episode_std_m": ep.within_std_m, "within_episode_std_rel": ep.within_std_rel}
    if n.size < MIN_MODE_EPISODES:
        return out
    counts = np.bincount(n.astype(np.int64))
    k = int(np.flatnonzero(counts == counts.max())[-1])  # modal length (ties: the longer)
    p90 = float(np.percentile(n, 90))
    out["length_mean_rows"], out["length_modal_rows"], out["length_p90_rows"] = float(n.mean()), k, p90
    if short and n.size > MIN_MODE_EPISODES and k >= 2 and p90 <= k + FIXED_MAX_EXCESS_ROWS:
        out["fixed_dwell"] = True
        out["hold_bursts"] = k
        out["dwell_s"] = k * burst_period_s
    else:
        out["dwell_s"] = dwell_from_runs(n, attempt_period_s)
    if short and ep.within_std_rel is not None and ep.n_within >= MIN_MODE_EPISODES \
            and ep.within_std_rel < HELD_MAX_STD_RATIO and ep.within_std_m < HELD_MAX_STD_RATIO * mode.std_m:
        out["held_jitter_m"] = max(ep.within_std_m, 1e-3)
    return out


def hmm_mode_dwell(chan: Channels, aid: str, f: MixtureFit, shapes: list[dict[str, Any]], short: list[bool],
                    default_s: float) -> dict[str, Any] | None:
    """Episode lengths of an anchor's fragmented NLOS modes by the LOS / NLOS-mode chain (in place).

    A mode whose classified episodes are *short* (at most SHORT_EPISODE_MAX_ROWS rows on average) but
    not of a fixed length may be a mode close to the LOS peak whose episodes the row classification
    cuts into fragments: its ``dwell_s`` in ``shapes`` is replaced by the maximum-likelihood mean of
    :func:`fit_mode_dwell` (the run-length estimate, or ``default_s``, is its start and stays in
    ``dwell_s_runs``); the other modes are held at their run-length or fixed lengths. Returns the
    fit's diagnostics (None when no mode qualifies).
    """
    if not f.modes or f.nlos_prob <= 0 or aid not in chan.per_anchor_rows or not chan.per_anchor_t.get(aid):
        return None
    free = np.array([sh_short and not sh["fixed_dwell"] for sh, sh_short in zip(shapes, short, strict=True)])
    if not free.any():
        return None
    start = np.array([sh["dwell_s"] or default_s for sh in shapes], dtype=float)
    ra, ga, _ = chan.per_anchor_rows[aid]
    ts = chan.per_anchor_t[aid]
    sizes = np.array([x.size for x in ts])
    new_run = np.zeros(ra.size, dtype=bool)
    first = np.cumsum(np.concatenate([[0], sizes[:-1]]))[sizes > 0]
    new_run[first] = True
    out = fit_mode_dwell(ra, ga, np.concatenate(ts), new_run, f, start, free)
    for sh, tau, fr in zip(shapes, out["dwell_s"], free, strict=True):
        if fr:
            sh["dwell_s_runs"] = sh["dwell_s"]
            sh["dwell_s"] = float(tau)
    return {**out, "dwell_s": out["dwell_s"].tolist(), "start_s": start.tolist(), "free": free.tolist(),
            "method": "ML of the LOS / NLOS-mode Markov chain with the mixture densities as emissions"}


def dwell_from_runs(lengths: np.ndarray, period_s: float) -> float | None:
    """Mean NLOS episode [s] from run lengths n >= 1 of samples every ``period_s`` (geometric MLE)."""
    if lengths.size == 0:
        return None
    mean_n = float(lengths.mean())
    if mean_n <= 1.0 + 1e-9:
        return period_s / 10.0
    return float(-period_s / np.log(1.0 - 1.0 / mean_n))


def pooled_nlos_dwell(ids: Sequence[str], flags: dict[str, list[np.ndarray]], periods: dict[str, float]
                       ) -> tuple[dict[str, float | None], np.ndarray, float | None, float]:
    """NLOS dwell per anchor and one value for the generator, pooled over anchors:
    (per-anchor dwell, all NLOS run lengths, pooled dwell or None, dwell used)."""
    runs_all, per_anchor_dwell = [], {}
    for aid in ids:
        lengths = nlos_run_lengths(flags[aid])
        per_anchor_dwell[aid] = dwell_from_runs(lengths, periods[aid])
        runs_all.append(lengths)
    all_runs = np.concatenate(runs_all) if runs_all else np.zeros(0)
    dwell = dwell_from_runs(all_runs, float(np.mean(list(periods.values()))))
    nlos_dwell = dwell if dwell is not None else UwbParams().nlos_dwell_s
    return per_anchor_dwell, all_runs, dwell, nlos_dwell


def episodes_and_short_pool(ids: Sequence[str], chan: Channels, rep: ReportBuilder
                             ) -> tuple[dict[str, list[ModeEpisodes]], ModeEpisodes]:
    """Episodes of every mode per anchor, and the short ones pooled over modes and anchors (reported
    under ``short_nlos_episodes``)."""
    flags, mix = chan.flags, chan.mix
    # episodes of every mode; the short ones (gross outliers: a device behaviour, a few per anchor) are
    # pooled over modes and anchors to learn their length law and whether their offset is held
    empty = ModeEpisodes(lengths=np.zeros(0, np.int64), within_dev_m=np.zeros(0), within_dev_rel=np.zeros(0))
    episodes_of = {aid: (mode_episodes(chan.per_anchor_rows[aid][0], flags[aid], mix[aid].modes)
                         if aid in chan.per_anchor_rows else [empty] * len(mix[aid].modes)) for aid in ids}
    short_pool = pool_episodes([e for eps in episodes_of.values() for e in eps if is_short(e)])
    rep.sections["short_nlos_episodes"] = {
        "rule": f"modes whose episodes last at most {SHORT_EPISODE_MAX_ROWS} rows on average, or with fewer "
                f"than {MIN_MODE_EPISODES} episodes, share one episode law fitted on all their episodes",
        "n_episodes": int(short_pool.lengths.size),
        "length_histogram_rows": np.bincount(short_pool.lengths.astype(np.int64)).tolist()
        if short_pool.lengths.size else [],
        "within_episode_std_m": short_pool.within_std_m, "within_episode_std_rel": short_pool.within_std_rel}
    return episodes_of, short_pool


def anchor_nlos_modes(chan: Channels, aid: str, f: MixtureFit, episodes: list[ModeEpisodes],
                       short_pool: ModeEpisodes, period_s: float, burst_rate: float, nlos_dwell: float
                       ) -> tuple[list[NlosMode], list[dict[str, Any]], Any]:
    """An anchor's NLOS modes, each with its own episode length: (modes, episode shapes, HMM dwell)."""
    # each mode keeps its own episode length (an episode keeps one reflector): a long, small offset at
    # rest and short gross outliers are different processes
    shapes = [episode_shape(m, short_pool if is_short(e) else e, period_s, 1.0 / burst_rate,
                             short=is_short(e))
              for m, e in zip(f.modes, episodes, strict=True)]
    hmm_dwell = hmm_mode_dwell(chan, aid, f, shapes, [is_short(e) for e in episodes], nlos_dwell)
    modes = [NlosMode(weight=rounded(m.weight, 4), mean_m=rounded(m.mean_m, 5), std_m=rounded(m.std_m, 4),
                      dwell_s=None if sh["dwell_s"] is None else rounded(sh["dwell_s"], 4),
                      fixed_dwell=sh["fixed_dwell"],
                      held_jitter_m=None if sh["held_jitter_m"] is None else rounded(sh["held_jitter_m"], 4))
             for m, sh in zip(f.modes, shapes, strict=True)]
    if not modes:
        modes = ChannelParams().nlos_modes
    return modes, shapes, hmm_dwell


@dataclass(frozen=True, slots=True, kw_only=True)
class NlosEpisodes:
    """The NLOS episodes of every anchor: the dwell per anchor and pooled, each mode's episodes, the short pool."""

    periods_s: dict[str, float]  # each anchor's attempt period
    per_anchor_dwell_s: dict[str, float | None]
    all_runs: np.ndarray  # every NLOS run length
    dwell_s: float | None  # pooled over the anchors (None: no NLOS episode)
    nlos_dwell_s: float  # the generator's uwb.nlos_dwell_s
    episodes_of: dict[str, list[ModeEpisodes]]
    short_pool: ModeEpisodes


def _fit(ctx: CalibrationContext) -> NlosEpisodes:
    ids, chan = ctx.inputs.anchor_ids, ctx.fitted["ranging"].channels
    av = ctx.fitted["link_availability"].per_anchor
    periods = {a: av[a]["dropout_outage"]["attempt_period_s"] for a in ids}
    per_anchor_dwell, all_runs, dwell, nlos_dwell = pooled_nlos_dwell(ids, chan.flags, periods)
    episodes_of, short_pool = episodes_and_short_pool(ids, chan, ctx.report)
    return NlosEpisodes(periods_s=periods, per_anchor_dwell_s=per_anchor_dwell, all_runs=all_runs, dwell_s=dwell,
                        nlos_dwell_s=nlos_dwell, episodes_of=episodes_of, short_pool=short_pool)


COMPONENT = Component(
    name="nlos_episodes", needs=("ranging", "link_availability"), fit=_fit,
    data="each anchor's rows classified LOS or NLOS mode, in time order per run",
    fits="uwb.nlos_dwell_s, each NLOS mode's dwell_s, fixed_dwell, held_jitter_m")
