"""The whole calibration: traces (or dataset directories) -> a Scenario and a JSON fit report.

:func:`calibrate` runs named steps, each a function that takes and returns typed records:

1. :func:`prepare_inputs` -> :class:`CalibrationInputs`: input checks, labels, anchor layouts, the
   track summary of every run (computed once, shared by the path and motion fits);
2. :func:`fit_geometry` -> :class:`GeometryFit`: path, run-to-run deformation and motion;
3. :func:`fit_timing` -> :class:`TimingFit`: UWB time offset (grid search) and burst schedule;
4. :func:`fit_ranging` -> :class:`RangingFit`: per-anchor LOS/NLOS errors pooled over runs (each run
   against its own anchor positions), the refined time offset and the run-to-run ranging offsets;
5. :func:`fit_link_availability` -> :class:`AvailabilityFit` (link range, dropout, outages, tag
   outages, rates with their Gamma posteriors);
6. :func:`assemble_channels` -> :class:`ChannelSet`: per-anchor channel parameters with NLOS modes
   and their episode lengths;
7. :func:`assemble_availability` -> :class:`AvailabilitySet`;
8. :func:`fit_imu_step` -> :class:`~physynth.models.imu.ImuParams` when IMU data is present;
9. :func:`build_scenario`: the :class:`~physynth.scenario.Scenario` from the parameter objects.

Every step writes what it fitted into one :class:`ReportBuilder`: every parameter with its standard
error or the number of samples behind it, the diagnostics that support it and the list of what could
not be identified. At the end the report's parameters are held to the scenario as written
(:func:`~physynth.calibrate.report_fields.reconcile_parameters`: a field's value is the one written, the
fit's own number beside it where they differ) and the options that changed nothing are noted. The
scenario is in the generator's own format, so it feeds ``physynth generate``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .. import __version__
from ..bounds import BOUNDS
from ..models.availability import AvailabilityOverride, RatePosterior, gamma_rate_posterior
from ..models.uwb import heading_at, pattern_features, range_decades, relative_bearing, travelled_m, turned_rad
from ..progress import ProgressCallback, no_progress
from ..records import Trace, untrusted_truth
from ..scenario import (
    AnchorSpec,
    AvailabilityParams,
    ChannelOverride,
    ChannelParams,
    ImuParams,
    MotionParams,
    NlosMode,
    PathParams,
    Scenario,
    UwbParams,
)
from ._base import CalibrationError, Fit, as_trace_list, jsonable, require_truth, rounded, trace_label
from .availability_fit import fit_availability
from .geometry import (
    AnchorPolicy,
    PathKind,
    TrackSummary,
    anchor_layout,
    fit_motion,
    fit_path,
    path_miss_warnings,
    path_with_deformation,
    spread_clip_warnings,
    summarize_track,
)
from .jitter_fit import fit_jitter
from .report_fields import reconcile_parameters, unused_option_notes
from .run_lag import fit_run_lags, los_row_blocks
from .run_spread import (
    RUN_OFFSET_BLOCK_ROWS,  # noqa: F401  (re-exported)
    RUN_OFFSET_LR_MIN,  # noqa: F401
    RUN_OFFSET_MAX_BLOCKS,  # noqa: F401
    _batch_mean_var,
    _reml_two_way,  # noqa: F401
    cell_slope,
    two_way_spread,
)
from .uwb_fit import (
    GROSS_RESIDUAL_M,
    MIN_ANCHOR_ROWS,
    RANGE_BIAS_LAWS,
    MixtureFit,
    ModeFit,
    Residuals,
    corrected_residuals,
    fit_burst_schedule,
    fit_mode_dwell,
    fit_time_offset,
    gross_residual_count,
    select_mixture,
)


# ---------------------------------------------------------------- the report
@dataclass(slots=True)
class ReportBuilder:
    """The fit report under construction: sections, parameters, what is not identifiable, warnings."""

    sections: dict[str, Any] = field(default_factory=dict)
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    not_identifiable: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def param(self, key: str, value: Any, *, se: Any = None, n: int | None = None, note: str | None = None,
              summary: bool = False, interval: Sequence[float] | None = None) -> None:
        """Record one fitted parameter (``interval``: a 90 % credible interval, e.g. of a rate)."""
        item: dict[str, Any] = {"value": value}
        if se is not None:
            item["std_error"] = se
        if interval is not None:
            item["interval_90"] = [float(x) for x in interval]
        if n is not None:
            item["n_samples"] = int(n)
        if note:
            item["note"] = note
        if summary:
            item["summary"] = True
        self.parameters[key] = item

    def to_dict(self) -> dict[str, Any]:
        out = {**self.sections, "parameters": self.parameters, "not_identifiable": self.not_identifiable}
        if self.warnings:
            out["warnings"] = self.warnings
        return jsonable(out)


@dataclass(frozen=True, slots=True, kw_only=True)
class CalibrationResult:
    """A calibrated scenario and its fit report (JSON-able dict)."""

    scenario: Scenario
    report: dict[str, Any]

    def summary_rows(self, *, fields: bool = True) -> list[tuple[str, str, str]]:
        """(parameter, value, uncertainty or samples) rows for a short terminal table: the scenario's fields
        (``fields``; their values as written, the fit's own number beside where it differs) or the fit's
        diagnostics that are no scenario field (``fields=False``)."""
        rows = []
        for key, item in self.report["parameters"].items():
            if item.get("summary") and item.get("field", True) == fields:
                rows.append((key, _fmt_value(item["value"]), _uncertainty(item)))
        return rows


def _fmt_value(v: Any) -> str:
    return " / ".join(_fmt(x) for x in v) if isinstance(v, list) else _fmt(v)


def _uncertainty(item: dict[str, Any]) -> str:
    """The uncertainty column of a summary row: the fit's own number and why the scenario differs, or
    the 90 % interval, the standard error, the sample count or the note."""
    if "fitted" in item:
        return f"fitted {_fmt_value(item['fitted'])}: {item.get('why', '')}"
    if item.get("interval_90") is not None:
        lo, hi = item["interval_90"]
        return f"90 % [{_fmt(lo)}, {_fmt(hi)}]"
    if item.get("std_error") is not None:
        return "+- " + _fmt_value(item["std_error"])
    if item.get("n_samples") is not None:
        return f"n = {item['n_samples']}"
    return item.get("note", "")


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


# ---------------------------------------------------------------- NLOS episodes
def _nlos_runs(flags: list[np.ndarray]) -> np.ndarray:
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


def _mode_episodes(residual_m: np.ndarray, flags: list[np.ndarray], modes: Sequence[ModeFit]) -> list[ModeEpisodes]:
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


MIN_WHITE_SHARE = 0.01
"""Smallest share of an anchor's LOS error variance left white (per attempt) when the antenna sway is fitted."""
SHORT_EPISODE_MAX_ROWS = 5.0
"""Modes whose episodes last at most this many rows on average are *short* (gross outliers)."""


def _is_short(ep: ModeEpisodes) -> bool:
    return ep.lengths.size < MIN_MODE_EPISODES or float(ep.lengths.mean()) <= SHORT_EPISODE_MAX_ROWS


def _pool_episodes(eps: Sequence[ModeEpisodes]) -> ModeEpisodes:
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


def _episode_shape(mode: ModeFit, ep: ModeEpisodes, attempt_period_s: float, burst_period_s: float, *,
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
        out["dwell_s"] = _dwell_from_runs(n, attempt_period_s)
    if short and ep.within_std_rel is not None and ep.n_within >= MIN_MODE_EPISODES \
            and ep.within_std_rel < HELD_MAX_STD_RATIO and ep.within_std_m < HELD_MAX_STD_RATIO * mode.std_m:
        out["held_jitter_m"] = max(ep.within_std_m, 1e-3)
    return out


def _hmm_mode_dwell(chan: _Channels, aid: str, f: MixtureFit, shapes: list[dict[str, Any]], short: list[bool],
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


def _dwell_from_runs(lengths: np.ndarray, period_s: float) -> float | None:
    """Mean NLOS episode [s] from run lengths n >= 1 of samples every ``period_s`` (geometric MLE)."""
    if lengths.size == 0:
        return None
    mean_n = float(lengths.mean())
    if mean_n <= 1.0 + 1e-9:
        return period_s / 10.0
    return float(-period_s / np.log(1.0 - 1.0 / mean_n))


# ---------------------------------------------------------------- per-anchor channels
AnchorRows = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(residual [m], geometric range [m], range rate [m/s]) of an anchor's rows, pooled over runs."""


@dataclass(frozen=True, slots=True, kw_only=True)
class _Channels:
    pooled_r: np.ndarray
    pooled_fit: MixtureFit
    pooled_sel: dict[str, Any]
    mix: dict[str, MixtureFit]
    mix_diag: dict[str, Any]
    flags: dict[str, list[np.ndarray]]
    per_anchor_rows: dict[str, AnchorRows]
    notes: list[str]
    per_anchor_t: dict[str, list[np.ndarray]] = field(default_factory=dict)  # row times per run
    per_anchor_run: dict[str, np.ndarray] = field(default_factory=dict)  # run index (into the traces) of each row
    per_anchor_c: dict[str, list[np.ndarray]] = field(default_factory=dict)  # distance travelled at the rows, per run
    per_anchor_h: dict[str, list[np.ndarray]] = field(default_factory=dict)  # angle turned at the rows, per run
    per_anchor_p: dict[str, list[np.ndarray]] = field(default_factory=dict)  # tag-pattern terms (N, 4), per run
    per_anchor_v: dict[str, list[np.ndarray]] = field(default_factory=dict)  # horizontal speed at the rows, per run

    per_anchor_trusted: dict[str, np.ndarray] = field(default_factory=dict)  # the row's truth is trusted

    def los_masks(self) -> dict[str, np.ndarray]:
        """Per anchor, the rows taken as LOS ranging: classified LOS, and with a trusted truth."""
        return {a: (self.mix[a].nlos_resp < 0.5) & self.per_anchor_trusted.get(a, True) for a in self.per_anchor_rows}


RunOffsets = dict[tuple[str, str], float]
"""(run label, anchor id) -> the run's LOS ranging offset [m] relative to the anchor's mean over runs."""


_SLOPE_FIELD = {"log": "range_bias_per_decade_m", "linear": "range_bias_per_m"}


def _slope_in_bounds(f: MixtureFit, law: str) -> bool:
    """Whether the fitted range-bias slope lies inside its physical bounds (``physynth.bounds``)."""
    b = BOUNDS[f"channel.{_SLOPE_FIELD[law]}"]
    return b.lo <= float(getattr(f, _SLOPE_FIELD[law])) <= b.hi


def _bearing_rows(trace: Trace, r: Residuals, lag: float) -> tuple[np.ndarray, np.ndarray]:
    """The tag-pattern terms (N, 4) (:func:`~physynth.models.uwb.pattern_features` of each row's anchor
    bearing relative to the truth's heading) and the truth's horizontal speed (N,) at the rows of ``r``."""
    tt = r.t_s - lag
    pos = trace.truth.position_at(tt)
    head = heading_at(tt, trace.truth.t_s, trace.truth.vel_enu_mps)
    a = trace.anchors.pos_enu_m[r.anchor]
    cos_phi, sin_phi = relative_bearing(a[:, 0] - pos[:, 0], a[:, 1] - pos[:, 1], head[:, 0], head[:, 1])
    v = np.nan_to_num(trace.truth.vel_enu_mps[:, :2])
    speed = np.interp(tt, trace.truth.t_s, np.hypot(v[:, 0], v[:, 1]))
    return pattern_features(cos_phi, sin_phi), speed


def _run_shift(t: Trace, lab: str, r: Residuals, feats: np.ndarray, run_offsets: RunOffsets | None,
               tag_pattern: Sequence[float] | None, run_slopes: RunSlopes | None) -> np.ndarray:
    """What :func:`_fit_channels` removes from each row of run ``lab``: the run's offset of the row's
    anchor, the tag pattern at the row's bearing (``feats``) and the run's tilt of the anchor's range law."""
    shift = np.zeros(r.residual_m.size)
    if run_offsets:
        per_anchor = np.array([run_offsets.get((lab, a), 0.0) for a in t.anchors.ids])
        if per_anchor.size:
            shift += per_anchor[r.anchor]
    if tag_pattern is not None and any(tag_pattern):
        shift += feats @ np.asarray(tag_pattern, dtype=float)
    for i, a in enumerate(t.anchors.ids if run_slopes else ()):
        if (lab, a) in run_slopes:
            tilt, centre = run_slopes[(lab, a)]
            m = r.anchor == i
            shift[m] += tilt * (range_decades(r.range_m[m]) - centre)
    return shift


def _fit_rows(trace: Trace, lag: float, trusted_truth: bool) -> Residuals:
    """The residual rows of a run at its lag, with their truth's trust only when it is to be used."""
    r = corrected_residuals(trace, lag)
    return r if trusted_truth else replace(r, trusted=None)


def _trusted(r: Residuals) -> np.ndarray:
    return np.ones(r.residual_m.shape, dtype=bool) if r.trusted is None else r.trusted


def _fit_channels(trs: Sequence[Trace], offset: float | Sequence[float], ids: Sequence[str], fixed_slope: float | None,
                  labels: Sequence[str], run_offsets: RunOffsets | None = None, law: str = "log",
                  tag_pattern: Sequence[float] | None = None, run_slopes: RunSlopes | None = None,
                  trusted_truth: bool = False) -> _Channels:
    """Per-anchor LOS/NLOS mixtures (and the pooled one) at a given time offset (one for all runs, or
    one per run).

    Each run's residuals are taken against its own anchor positions; ``run_offsets`` (when given) are
    subtracted from the run's rows of that anchor first, so that the mixture describes the errors
    within a run and the run-to-run part is left to ``uwb.run_*offset_std_m``; so is the tag antenna
    pattern ``tag_pattern`` (``uwb.tag_pattern_m``) at each row's bearing, and each run's tilt of an
    anchor's range law ``run_slopes`` (about the cell's own mean log range), when given. With
    ``trusted_truth`` the mixtures are fitted on the rows whose truth is trusted (the others classified
    with the LOS peak widened by their own scatter) and only those rows count as LOS ranging.
    """
    res: list[Residuals] = []
    bearing: list[tuple[np.ndarray, np.ndarray]] = []
    lags = [float(offset)] * len(trs) if np.ndim(offset) == 0 else [float(o) for o in offset]
    for t, lab, lag in zip(trs, labels, lags, strict=True):
        r = _fit_rows(t, lag, trusted_truth)
        feats, speed = _bearing_rows(t, r, lag)
        shift = _run_shift(t, lab, r, feats, run_offsets, tag_pattern, run_slopes)
        if shift.any():
            r = Residuals(residual_m=r.residual_m - shift, range_m=r.range_m, anchor=r.anchor,
                          t_s=r.t_s, range_rate_mps=r.range_rate_mps, trusted=r.trusted)
        res.append(r)
        bearing.append((feats, speed))
    pooled_r = np.concatenate([r.residual_m for r in res])
    pooled_g = np.concatenate([r.range_m for r in res])
    if pooled_r.size < MIN_ANCHOR_ROWS:
        raise CalibrationError(f"only {pooled_r.size} UWB ranges fall inside the ground-truth time span; "
                               f"at least {MIN_ANCHOR_ROWS} are needed")
    pooled_ok = np.concatenate([_trusted(r) for r in res])
    pooled_fit, pooled_sel = select_mixture(pooled_r, pooled_g, fixed_slope=fixed_slope, law=law, fit_mask=pooled_ok)
    mix: dict[str, MixtureFit] = {}
    mix_diag: dict[str, Any] = {}
    flags: dict[str, list[np.ndarray]] = {}
    rows: dict[str, AnchorRows] = {}
    times: dict[str, list[np.ndarray]] = {}
    run_of: dict[str, np.ndarray] = {}
    dist: dict[str, list[np.ndarray]] = {}
    turned: dict[str, list[np.ndarray]] = {}
    pattern_terms: dict[str, list[np.ndarray]] = {}
    speeds: dict[str, list[np.ndarray]] = {}
    trusted: dict[str, np.ndarray] = {}
    motion = [(travelled_m(t.truth.t_s, t.truth.vel_enu_mps),  # the antenna sway's motion clocks
               turned_rad(t.truth.t_s, t.truth.vel_enu_mps, t.truth.omega_body_radps)) for t in trs]
    notes: list[str] = []
    for aid in ids:  # one mixture per anchor (one physical device), pooled over the runs
        parts = [(r.residual_m[m], r.range_m[m], r.range_rate_mps[m], r.t_s[m], np.full(int(m.sum()), i),
                  np.interp(r.t_s[m] - lag, t.truth.t_s, dist), np.interp(r.t_s[m] - lag, t.truth.t_s, turn),
                  feats[m], speed[m], _trusted(r)[m])
                 for i, (t, r, lag, (dist, turn), (feats, speed))
                 in enumerate(zip(trs, res, lags, motion, bearing, strict=True))
                 if aid in t.anchors.ids for m in [r.anchor == t.anchors.index(aid)]]
        sizes = [p[0].size for p in parts]
        ra = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        ga = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
        if ra.size < MIN_ANCHOR_ROWS:
            mix[aid] = pooled_fit
            mix_diag[aid] = {"n": int(ra.size), "note": f"fewer than {MIN_ANCHOR_ROWS} ranges: pooled channel used"}
            notes.append(f"channel of {aid} (too few ranges; pooled values used)")
            flags[aid] = []
            continue
        ok = np.concatenate([p[9] for p in parts])
        f, sel = select_mixture(ra, ga, fixed_slope=fixed_slope, law=law, fit_mask=ok)
        if fixed_slope is None and not _slope_in_bounds(f, law):  # too few rows, or too narrow a span of ranges
            sel["slope_out_of_bounds"] = float(getattr(f, _SLOPE_FIELD[law]))
            f, sel2 = select_mixture(ra, ga, fixed_slope=float(getattr(pooled_fit, _SLOPE_FIELD[law])), law=law,
                                     fit_mask=ok)
            sel = {**sel2, "slope_out_of_bounds": sel["slope_out_of_bounds"], "slope": "pooled over the anchors"}
            notes.append(f"channel_per_anchor.{aid} range-bias slope ({sel['slope_out_of_bounds']:.3g}, outside the "
                         "physical range: too few ranges or too narrow a span of them; the pooled slope is used)")
        mix[aid] = f
        per_run = {}
        for t, r, lab in zip(trs, res, labels, strict=True):  # per-run robust summary (spread over runs)
            if aid in t.anchors.ids:
                x = r.residual_m[r.anchor == t.anchors.index(aid)]
                if x.size:
                    med = float(np.median(x))
                    per_run[lab] = {"n": int(x.size), "median_m": med,
                                    "robust_std_m": float(1.4826 * np.median(np.abs(x - med)))}
        mix_diag[aid] = {"n": int(ra.size), **sel, "converged": f.converged,
                         "range_span_m": [float(ga.min()), float(ga.max())], "per_run": per_run}
        bounds = np.cumsum([0] + sizes)
        flags[aid] = [f.nlos_resp[a:b] > 0.5 for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        rows[aid] = (ra, ga, np.concatenate([p[2] for p in parts]))
        times[aid] = [p[3] for p in parts]
        run_of[aid] = np.concatenate([p[4] for p in parts])
        dist[aid] = [p[5] for p in parts]
        turned[aid] = [p[6] for p in parts]
        pattern_terms[aid] = [p[7] for p in parts]
        speeds[aid] = [p[8] for p in parts]
        trusted[aid] = ok
    return _Channels(pooled_r=pooled_r, pooled_fit=pooled_fit, pooled_sel=pooled_sel, mix=mix, mix_diag=mix_diag,
                     flags=flags, per_anchor_rows=rows, notes=notes, per_anchor_t=times, per_anchor_run=run_of,
                     per_anchor_c=dist, per_anchor_h=turned, per_anchor_p=pattern_terms, per_anchor_v=speeds,
                     per_anchor_trusted=trusted)


def refine_time_offset(rows: dict[str, AnchorRows], los: dict[str, np.ndarray],
                       run_of_row: dict[str, np.ndarray] | None = None,
                       t_of_row: dict[str, list[np.ndarray]] | None = None) -> dict[str, Any] | None:
    """Least-squares correction of the time offset from the LOS rows.

    With r(offset) = range - g(t - offset), r(offset0 + d) ~ r(offset0) + g'(t) d; regressing r(offset0)
    on per-anchor intercepts and range slopes and on -g' gives d, a far more efficient estimate than
    the robust grid search. Its standard error: with ``run_of_row`` (per anchor, each row's run), a
    delete-one-block jackknife over blocks in time of each run, every anchor's rows together
    (:func:`~physynth.calibrate.run_lag.los_row_blocks`; the antenna sway is slow and common to the
    anchors, so rows taken as independent make it 3-5 times too small), at least that independent-rows
    error (``white_std_error_s``); without, the independent-rows error. Also returns, per anchor, the
    sensitivity of the LOS mean and slope to the offset.
    """
    keys = [a for a in rows if los[a].sum() > 10]
    if not keys:
        return None
    blocks_r, blocks_x = [], []
    n_a = len(keys)
    for j, a in enumerate(keys):
        r, g, gd = (x[los[a]] for x in rows[a])
        x = np.zeros((r.size, 2 * n_a + 1))
        x[:, 2 * j] = 1.0
        x[:, 2 * j + 1] = g
        x[:, -1] = -gd
        blocks_r.append(r)
        blocks_x.append(x)
    y = np.concatenate(blocks_r)
    x = np.concatenate(blocks_x)
    if np.ptp(x[:, -1]) == 0:
        return None
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    s2 = float(resid @ resid / max(y.size - x.shape[1], 1))
    white = float(np.sqrt((np.linalg.pinv(x.T @ x) * s2)[-1, -1]))
    se, n_blocks = white, 0
    if run_of_row is not None:
        block = los_row_blocks(los, run_of_row, t_of_row, keys)
        n_blocks = int(block.max()) + 1
        jack = np.array([np.linalg.lstsq(x[block != b], y[block != b], rcond=None)[0][-1]
                         for b in range(n_blocks)])  # a few blocks per run
        se = max(float(np.sqrt((n_blocks - 1) / n_blocks * np.sum((jack - jack.mean()) ** 2))), white)
    sens = {}
    for a in keys:
        r, g, gd = (v[los[a]] for v in rows[a])
        b, m = np.polyfit(g, gd, 1) if np.ptp(g) > 0 else (0.0, float(np.mean(gd)))
        h = range_decades(g)
        bd = np.polyfit(h, gd, 1)[0] if np.ptp(h) > 0 else 0.0
        sens[a] = {"d_los_mean_per_s": float(m), "d_range_bias_per_s": float(b),
                   "d_range_bias_per_decade_per_s": float(bd)}
    return {"correction_s": float(coef[-1]), "std_error_s": se, "white_std_error_s": white,
            "jackknife_blocks": n_blocks, "n_los_rows": int(y.size), "sensitivity": sens}


def _los_cells(trs: Sequence[Trace], labels: Sequence[str], chan: _Channels):
    """(run label, anchor id, LOS residuals after the anchor's range law, their true ranges, the anchor's
    LOS std) of every cell with at least :data:`MIN_ANCHOR_ROWS` LOS rows (posterior NLOS probability
    < 0.5), rows in time order."""
    for aid, (ra, ga, _) in chan.per_anchor_rows.items():
        f = chan.mix[aid]
        runs_of = [lab for t, lab in zip(trs, labels, strict=True) if aid in t.anchors.ids]
        start = 0
        for lab, nlos in zip(runs_of, chan.flags[aid], strict=True):  # the anchor's rows, run by run
            sl = slice(start, start + nlos.size)
            start += nlos.size
            x = ra[sl] - f.los_centre(ga[sl])
            if int((~nlos).sum()) >= MIN_ANCHOR_ROWS:
                yield lab, aid, x[~nlos], ga[sl][~nlos], f.los_std_m


def run_offset_table(trs: Sequence[Trace], labels: Sequence[str], chan: _Channels) -> tuple[RunOffsets, dict[str, Any]]:
    """Per-run LOS ranging offsets of every anchor and their run-to-run spreads (random effects).

    For run r and anchor a, d_ra is the mean LOS residual of the run (rows the anchor's mixture calls
    LOS, posterior NLOS probability < 0.5, after its range-proportional bias). Model:
    d_ra = mu_a + u_r + e_ra + eps_ra, with an offset u_r common to every anchor of a run
    (``run_offset_std_m``: the truth system or the tag antenna moved), a per-anchor remainder e_ra
    (``run_anchor_offset_std_m``: an anchor re-placed and re-surveyed) and the sampling error eps_ra of
    the run's mean, whose variance is estimated for each cell from its block means in time (at least
    sigma_LOS^2 / n_ra, pooled over the anchor's runs); :func:`~physynth.calibrate.run_spread.two_way_spread`
    (REML; 0 below :data:`RUN_OFFSET_LR_MIN`). The offsets returned for removal from the rows are each
    run's own d_ra minus the anchor's mean over runs, 0 when the spreads are (the best linear unbiased
    predictions, shrunk by the sampling variances, are in the report: removing those instead moved the
    left-out Hanyang medians by up to 1 cm, two of three for the worse).
    """
    raw, n_los = {}, {}
    for lab, aid, xl, _, los_std in _los_cells(trs, labels, chan):
        raw[(lab, aid)] = (float(np.mean(xl)), _batch_mean_var(xl, los_std**2 / float(xl.size)))
        n_los[(lab, aid)] = int(xl.size)
    offsets, d = two_way_spread(raw, n_los, labels, unit="m")
    diag: dict[str, Any] = {"per_run": d["per_run"], "identifiable": d["identifiable"]}
    if not d["identifiable"]:
        diag.update(why=d["why"], run_offset_std_m=0.0, run_anchor_offset_std_m=0.0)
        return {}, diag
    diag.update(n_runs=d["n_runs"], n_anchors=d["n_anchors"], run_means_m=d["run_means"],
                run_offset_std_m=d["run_std"], run_anchor_offset_std_m=d["run_anchor_std"],
                sampling_var_m2=d["sampling_var"], sampling_var_per_cell_m2=d["sampling_var_per_cell"],
                removed_offsets_m=d["removed"], blup_offsets_m=d["blup"],
                reml_lr_vs_no_spread=d["reml_lr_vs_no_spread"], significant=d["significant"],
                method=("two-way random effects (run, run x anchor) on the per-run mean LOS residuals, "
                        "REML with each cell's sampling variance (block means in time) known; removed "
                        "offsets = each run's own (anchor mean removed) when the spreads are significant, else 0"))
    return offsets, diag


RunSlopes = dict[tuple[str, str], tuple[float, float]]
"""(run label, anchor id) -> (the run's tilt of the anchor's range law relative to the anchor's mean
over runs [m per decade of range], the mean log10 range of the cell's rows it pivots about)."""


def run_slope_table(trs: Sequence[Trace], labels: Sequence[str], chan: _Channels,
                    law: str) -> tuple[RunSlopes, dict[str, Any]]:
    """Per-run tilts of every anchor's LOS range law and their run-to-run spreads (random effects).

    For run r and anchor a, b_ra is the least-squares slope of the LOS residuals (as in
    :func:`run_offset_table`) on log10 range, its sampling variance by a jackknife over blocks in time
    (:func:`~physynth.calibrate.run_spread.cell_slope`); then the same two-way REML split as the
    offsets. The tilts returned for removal pivot about each cell's own mean log range, so removing
    them leaves the cell's mean (its offset) as it was. The pivot the scenario draws about
    (``uwb.run_slope_ref_range_m``) is the pooled mean log range of the cells. Only for the log law.
    """
    if law != "log":
        return {}, {"identifiable": False, "why": "the run-to-run tilt is fitted for the log range law only",
                    "run_slope_std_m": 0.0, "run_anchor_slope_std_m": 0.0}
    raw, n_los, centres = {}, {}, {}
    for lab, aid, xl, gl, _ in _los_cells(trs, labels, chan):
        got = cell_slope(xl, range_decades(gl))
        if got is not None:
            raw[(lab, aid)], n_los[(lab, aid)], centres[(lab, aid)] = (got[0], got[1]), int(xl.size), got[2]
    tilts, d = two_way_spread(raw, n_los, labels, unit="m per decade")
    diag: dict[str, Any] = {"per_run": d["per_run"], "identifiable": d["identifiable"]}
    if not d["identifiable"]:
        diag.update(why=d["why"], run_slope_std_m=0.0, run_anchor_slope_std_m=0.0)
        return {}, diag
    ref = float(10.0 ** np.average(list(centres.values()), weights=list(n_los.values())))
    diag.update(unit="m per decade of range", n_runs=d["n_runs"], n_anchors=d["n_anchors"],
                run_means=d["run_means"], run_slope_std_m=d["run_std"], run_anchor_slope_std_m=d["run_anchor_std"],
                ref_range_m=ref, sampling_var_per_cell=d["sampling_var_per_cell"], removed_slopes=d["removed"],
                blup_slopes=d["blup"], reml_lr_vs_no_spread=d["reml_lr_vs_no_spread"],
                significant=d["significant"],
                method=("least-squares slope of each (run, anchor) cell's LOS residuals on log10 range, "
                        "jackknife over blocks in time; two-way random effects by REML as the offsets"))
    return {k: (v, centres[k]) for k, v in tilts.items() if v != 0.0}, diag


# ---------------------------------------------------------------- step records
@dataclass(frozen=True, slots=True, kw_only=True)
class CalibrationInputs:
    """Checked inputs: the UWB recordings, the IMU-only ones, labels, anchors and track summaries."""

    traces: list[Trace]
    labels: list[str]
    imu_only: list[Trace]
    imu_only_labels: list[str]
    anchors: list[AnchorSpec]
    layout: dict[str, Any]
    tracks: list[TrackSummary]

    @property
    def anchor_ids(self) -> list[str]:
        return [a.id for a in self.anchors]


@dataclass(frozen=True, slots=True, kw_only=True)
class GeometryFit:
    path: PathParams
    motion: MotionParams


@dataclass(frozen=True, slots=True, kw_only=True)
class TimingFit:
    offset_s: float  # grid-search time offset [s]
    offset_fit: Fit[float]
    burst: Fit[dict[str, float]]

    @property
    def burst_rate_hz(self) -> float:
        return rounded(float(self.burst.params["burst_rate_hz"]), 7)


@dataclass(frozen=True, slots=True, kw_only=True)
class RangingFit:
    offset_s: float  # final time offset [s]
    offset_se_s: float
    channels: _Channels
    refinement: dict[str, Any] | None
    fixed_slope: float | None
    run_offset_std_m: float
    run_anchor_offset_std_m: float
    range_bias_law: str = "log"
    offset_std_s: float = 0.0  # run-to-run spread of the lag [s]
    tag_pattern_m: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)  # uwb.tag_pattern_m (zeros: none kept)
    run_slope_std_m: float = 0.0  # run-to-run tilt of the range law [m per decade]
    run_anchor_slope_std_m: float = 0.0
    run_slope_ref_range_m: float = 10.0

    @property
    def slope_key(self) -> str:
        """The channel field the range term is fitted to."""
        return "range_bias_per_decade_m" if self.range_bias_law == "log" else "range_bias_per_m"


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilityFit:
    per_anchor: dict[str, dict[str, Any]]
    tag: dict[str, Any]
    long_outages: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelSet:
    pooled: ChannelParams
    per_anchor: dict[str, ChannelParams]
    nlos_dwell_s: float
    sway: dict[str, Any] = field(default_factory=lambda: {"identifiable": False})
    tag_nlos: dict[str, Any] = field(default_factory=lambda: {"identifiable": False})


@dataclass(frozen=True, slots=True, kw_only=True)
class AvailabilitySet:
    pooled: AvailabilityParams
    per_anchor: dict[str, AvailabilityOverride]


# ---------------------------------------------------------------- steps
def _imu_only(t: Trace) -> bool:
    """A recording with IMU samples and no UWB range (e.g. a lab trial)."""
    return not (len(t.uwb) > 0 and bool(t.uwb.valid.any())) and t.imu is not None and t.imu.t_s.size > 100


def _fingerprint(trace: Trace) -> str:
    """SHA-1 of a recording's truth, UWB and IMU samples and its anchors (not its metadata)."""
    h = hashlib.sha1("|".join(trace.anchors.ids).encode())
    arrays = [trace.truth.t_s, trace.truth.pos_enu_m, trace.uwb.t_s, trace.uwb.range_m, trace.uwb.anchor,
              trace.anchors.pos_enu_m]
    if trace.imu is not None:
        arrays += [trace.imu.t_s]
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _refuse_duplicates(trs: Sequence[Trace], labels: Sequence[str]) -> None:
    """One recording given twice would count as two runs that agree exactly: every run-to-run spread
    (speed, length, path, ranging offsets, lags) would come out 0."""
    seen: dict[str, str] = {}
    for t, lab in zip(trs, labels, strict=True):
        key = _fingerprint(t)
        if key in seen:
            raise CalibrationError(f"{lab} and {seen[key]} hold the same recording (the same run given twice?); "
                                   "each run may be given once")
        seen[key] = lab


def prepare_inputs(traces: Trace | Sequence[Trace], *, anchor_policy: AnchorPolicy = "per-run",
                   layout_from: int | str | None = None, report: ReportBuilder) -> CalibrationInputs:
    """Check the recordings, label them, set the IMU-only ones aside and read the anchor layouts."""
    trs = as_trace_list(traces)
    labels = [trace_label(t, i) for i, t in enumerate(trs)]
    if len(set(labels)) != len(labels):
        labels = [f"{lab} [{i}]" for i, lab in enumerate(labels)]
        trs = [Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, imu=t.imu, meta={**t.meta, "label": lab})
               for t, lab in zip(trs, labels, strict=True)]
    _refuse_duplicates(trs, labels)
    keep: list[int] = []
    imu_only: list[int] = []  # IMU recordings without UWB (e.g. a lab trial): they inform the IMU fit only
    for i, (t, lab) in enumerate(zip(trs, labels, strict=True)):
        require_truth(t, lab)
        has_uwb = len(t.uwb) > 0 and bool(t.uwb.valid.any())
        has_imu = t.imu is not None and t.imu.t_s.size > 100
        if not has_uwb and has_imu:
            imu_only.append(i)
            continue
        if not has_uwb:
            raise CalibrationError(f"{lab}: no UWB rows with a range and no IMU samples: nothing to calibrate on")
        if len(t.anchors) == 0:
            raise CalibrationError(f"{lab}: no anchors")
        keep.append(i)
    if not keep:
        raise CalibrationError("no recording with UWB measurements: a scenario needs at least one "
                               "(IMU-only recordings can join a UWB recording to calibrate the IMU; "
                               "alone, use physynth.calibrate.imu_fit.fit_imu)")
    uwb_trs, uwb_labels = [trs[i] for i in keep], [labels[i] for i in keep]
    anchors, layout = anchor_layout(uwb_trs, policy=anchor_policy, labels=uwb_labels, layout_from=layout_from)
    windows = {}
    for t, lab in zip(uwb_trs, uwb_labels, strict=True):
        u_t = t.uwb.t_s[t.uwb.valid]
        windows[lab] = {"uwb_starts_after_truth_s": float(u_t[0] - t.truth.t_s[0]),
                        "truth_continues_after_uwb_s": float(t.truth.t_s[-1] - u_t[-1])}
        w = windows[lab]
        if max(w["uwb_starts_after_truth_s"], w["truth_continues_after_uwb_s"]) > 2.0:
            report.warnings.append(
                f"{lab}: UWB covers only part of the truth span (first range {w['uwb_starts_after_truth_s']:+.1f} s "
                f"from the truth start, last range {w['truth_continues_after_uwb_s']:.1f} s before its end); "
                "availability is fitted on the "
                "UWB span only, so metrics of the uncropped recording count the uncovered part as missing UWB "
                "(import with crop_to_uwb to drop it)")
    report.sections.update({
        "physynth_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "recordings": uwb_labels,
        "imu_only_recordings": [labels[i] for i in imu_only],
        "anchor_layout": layout,
        "recording_windows": windows,
    })
    tracks = [summarize_track(t, lab) for t, lab in zip(uwb_trs, uwb_labels, strict=True)]
    return CalibrationInputs(traces=uwb_trs, labels=uwb_labels, imu_only=[trs[i] for i in imu_only],
                             imu_only_labels=[labels[i] for i in imu_only], anchors=anchors, layout=layout,
                             tracks=tracks)


def fit_geometry(inp: CalibrationInputs, path_kind: PathKind, report: ReportBuilder,
                 progress: ProgressCallback) -> GeometryFit:
    """Path geometry, run-to-run deformation and motion (one track summary per run, shared)."""
    trs, rep = inp.traces, report
    progress("fitting the path geometry")
    pf = fit_path(trs, path_kind, tracks=inp.tracks)
    rep.sections["path"] = pf.diagnostics
    rep.param("path.kind", pf.params.kind, n=pf.n_samples, summary=True)
    rep.param("path.length_m", pf.diagnostics["length_m"], n=pf.n_samples, summary=True)
    rep.param("path.rmse_m", pf.diagnostics["rmse_m"], n=pf.n_samples,
              note="cross-track RMSE of the truth to the fitted path", summary=True)
    rep.warnings.extend(path_miss_warnings(pf.diagnostics))
    deformed = path_with_deformation(trs, pf.params, tracks=inp.tracks)
    path = deformed.path
    rep.sections["path_perturbation"] = deformed.section
    if deformed.not_identifiable:
        rep.not_identifiable.append(deformed.not_identifiable)
    rep.param("path.perturbation.lateral_std_m", path.perturbation.lateral_std_m, n=len(trs), note=deformed.note)
    rep.param("path.perturbation.sag_std_m", path.perturbation.sag_std_m, n=len(trs), note=deformed.note)

    progress("fitting the motion")
    mf = fit_motion(trs, path_length_m=pf.diagnostics["length_m"], defaults=MotionParams(cruise_speed_mps=1.0),
                    tracks=inp.tracks)
    rep.sections["motion"] = mf.diagnostics
    mp = mf.params
    rep.param("motion.cruise_speed_mps", mp.cruise_speed_mps,
              se=mf.diagnostics.get("cruise_speed_mps_std_error"), n=len(trs), summary=True)
    rep.param("motion.profile.kind", mp.profile.kind, n=mf.n_samples,
              note=mf.diagnostics["profile_choice_reason"], summary=True)
    rep.param("motion.speed_poly_r2", mf.diagnostics["speed_poly_r2"], n=mf.n_samples)
    rep.param("motion.max_acc_mps2", mp.max_acc_mps2, n=mf.n_samples, summary=True,
              note=(f"{mf.diagnostics['max_acc']['factor']:g} x the {mf.diagnostics['max_acc']['quantile']:.1%} "
                    "quantile of the trips' acceleration"))
    for key in ("cruise_speed_spread_frac", "length_spread_frac"):
        rep.param(f"motion.{key}", getattr(mp, key), n=len(trs), note=mf.diagnostics["spread_method"])
    jitter, jdiag = fit_jitter(trs, inp.tracks, path, mp, Scenario.model_fields["truth_rate_hz"].default)
    rep.sections["motion_jitter"] = jdiag
    rep.param("motion.jitter.acc_rms_mps2", jitter.acc_rms_mps2, n=mf.n_samples, note=jdiag["method"])
    mp = mp.model_copy(update={"jitter": jitter})
    rep.warnings.extend(spread_clip_warnings(mf.diagnostics))
    for key in ("dwell_start_s", "dwell_end_s"):
        vals = [r[key] for r in mf.diagnostics["per_run"].values()]
        rep.param(f"motion.{key}", getattr(mp, key),
                  se=float(np.std(vals, ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else None, n=len(vals))
    rep.not_identifiable.extend(f"motion.{k} (one run; default kept)"
                                for k in mf.diagnostics.get("not_identifiable", []))
    return GeometryFit(path=path, motion=mp)


def fit_timing(inp: CalibrationInputs, report: ReportBuilder, progress: ProgressCallback) -> TimingFit:
    """UWB time offset (robust grid search) and the tag's burst schedule."""
    progress("searching the UWB time offset")
    of = fit_time_offset(inp.traces)
    report.sections["time_offset"] = of.diagnostics
    offset = float(of.params)
    report.param("uwb.time_offset_s", offset, se=of.diagnostics["std_error_s"], n=of.n_samples, summary=True)
    if not of.diagnostics["identifiable"]:
        report.not_identifiable.append("uwb.time_offset_s (residual spread independent of the offset)")
    progress("fitting the burst schedule")
    bf = fit_burst_schedule(inp.traces)
    report.sections["burst_schedule"] = bf.diagnostics
    timing = TimingFit(offset_s=offset, offset_fit=of, burst=bf)
    report.param("uwb.burst_rate_hz", timing.burst_rate_hz, n=bf.n_samples, summary=True)
    report.param("uwb.burst_jitter_s", bf.params["burst_jitter_s"], n=bf.n_samples)
    report.param("uwb.slot_s", bf.params["slot_s"], n=bf.n_samples, note=bf.diagnostics["slot_method"])
    report.param("uwb.burst_phase_s", bf.params["burst_phase_s"], n=bf.n_samples,
                 note=("clock alignment " + ("of the single run" if len(inp.traces) == 1 else "shared by the runs"))
                 if bf.params["burst_phase_s"] is not None
                 else "several runs: drawn per trace")
    late = bf.diagnostics["late_bursts"]
    if late["applied"]:
        report.param("uwb.late_burst_prob", late["prob"], n=late["n_bursts_two_or_more"],
                     note=f"{late['n_late_bursts']} bursts with ranges stamped over {late['min_delay_s'] * 1e3:g} ms "
                          "after their slot")
        report.param("uwb.late_burst_delay_s", late["delay_s"], n=late["n_late_rows"], note="median")
    return timing


def fit_ranging(inp: CalibrationInputs, timing: TimingFit, *, static: dict[str, Any] | None,
                range_bias: Literal["dynamic", "static"], report: ReportBuilder,
                law: str = "log", tag_pattern: bool = False, run_slopes: bool = False,
                trusted_truth: bool = False) -> RangingFit:
    """Per-anchor LOS/NLOS mixtures pooled over runs, the refined time offset and run-to-run offsets.

    ``law``: how the LOS mean grows with the range (:data:`~physynth.calibrate.uwb_fit.RANGE_BIAS_LAWS`).
    ``tag_pattern``: apply the tag antenna pattern the fit keeps (always fitted and reported).
    ``run_slopes``: remove and generate the run-to-run tilts of the range law (:func:`run_slope_table`;
    always fitted and reported).
    ``trusted_truth``: fit the mixtures on the ranges whose truth the recording trusts
    (``records.TRUTH_UNTRUSTED_KEY``) and take only those as LOS ranging rows (the share is always reported).
    """
    trs, labels, ids = inp.traces, inp.labels, inp.anchor_ids
    report.sections["truth_quality"] = {"trusted_truth": bool(trusted_truth), "untrusted_share_of_truth": {
        lab: float(np.mean(untrusted_truth(t.meta, t.truth.t_s))) for t, lab in zip(trs, labels, strict=True)}}
    if range_bias == "static" and static is None:
        raise CalibrationError("range_bias='static' needs static_sweeps (the Static_measurements folder)")
    key = "range_bias_per_decade_m" if law == "log" else "range_bias_per_m"
    fixed_slope = static[key] if (static is not None and range_bias == "static") else None
    of = timing.offset_fit
    offset = timing.offset_s
    gross = {lab: gross_residual_count(t, offset) for t, lab in zip(trs, labels, strict=True)}
    report.sections["gross_residuals"] = {"per_run": gross, "limits_m": list(GROSS_RESIDUAL_M)}
    if any(gross.values()):
        report.warnings.append(f"{sum(gross.values())} range(s) lie outside {GROSS_RESIDUAL_M[0]:g} .. "
                               f"{GROSS_RESIDUAL_M[1]:g} m of the truth's distance (a radio's error code, a "
                               "corrupt value): left out of every ranging fit")
    chan = _fit_channels(trs, offset, ids, fixed_slope, labels, law=law, trusted_truth=trusted_truth)
    ref = refine_time_offset(chan.per_anchor_rows, chan.los_masks(), chan.per_anchor_run, chan.per_anchor_t)
    tsec = report.sections["time_offset"]
    tsec["grid_offset_s"] = offset
    tsec["refinement"] = ref
    refined = bool(of.diagnostics["identifiable"] and ref is not None)
    if refined:
        offset = offset + ref["correction_s"]
        se_off = float(np.hypot(ref["std_error_s"], of.diagnostics["std_error_s"] if len(trs) >= 2 else 0.0))
        tsec["offset_s"] = offset
        tsec["std_error_s"] = se_off
        report.param("uwb.time_offset_s", offset, se=se_off, n=of.n_samples, summary=True,
                     note="grid search on the robust spread, refined by least squares on the LOS rows")
    else:
        se_off = float(of.diagnostics["std_error_s"])
    lags: float | list[float] = offset
    lag_std = 0.0
    spread = fit_run_lags(chan.per_anchor_rows, chan.los_masks(), chan.per_anchor_run, len(trs),
                          t_of_row=chan.per_anchor_t)
    tsec["run_spread"] = _lag_spread_section(spread, labels, timing.offset_s)
    if spread is not None and spread["significant"] and of.diagnostics["identifiable"]:
        # the centre stays the pooled estimate above; each run is taken at it plus its own deviation
        dev = spread["correction_s"] - spread["mean_correction_s"]
        lags = [offset if np.isnan(d) else offset + float(d) for d in dev]
        lag_std = spread["spread_s"]
        tsec["run_spread"]["lags_used_s"] = dict(zip(labels, lags, strict=True))
        report.param("uwb.time_offset_std_s", lag_std, n=len(trs), summary=True,
                     note="run-to-run spread of the lag (DerSimonian-Laird over the runs' own lags)")
        chan = _fit_channels(trs, lags, ids, fixed_slope, labels, law=law,  # each run at its own lag
                             trusted_truth=trusted_truth)
    elif len(trs) >= 2:
        report.param("uwb.time_offset_std_s", 0.0, n=len(trs),
                     note="the runs' lags do not differ beyond their errors (Cochran's Q)")
    run_offsets, off_diag = run_offset_table(trs, labels, chan)
    report.sections["run_offsets"] = off_diag
    tilts, slope_diag = run_slope_table(trs, labels, chan, law)
    slope_diag["applied"] = bool(run_slopes and slope_diag["identifiable"] and slope_diag["significant"])
    report.sections["run_slopes"] = slope_diag
    if not slope_diag["applied"]:
        tilts = {}
    pattern = _tag_pattern(chan, report, apply=tag_pattern)  # each sequence's level and range law projected out
    if refined or run_offsets or tilts or any(pattern):  # again: each run's offsets and tilts, the pattern removed
        chan = _fit_channels(trs, lags if lag_std > 0 else offset, ids, fixed_slope, labels,
                             run_offsets=run_offsets, law=law, tag_pattern=pattern, run_slopes=tilts,
                             trusted_truth=trusted_truth)
    if off_diag["identifiable"]:
        s_run, s_anchor = off_diag["run_offset_std_m"], off_diag["run_anchor_offset_std_m"]
        note = "run-to-run spread of the per-run mean LOS residual (two-way random effects)"
        report.param("uwb.run_offset_std_m", s_run, n=off_diag["n_runs"], note=note, summary=True)
        report.param("uwb.run_anchor_offset_std_m", s_anchor, n=off_diag["n_runs"] * off_diag["n_anchors"],
                     note=note, summary=True)
    else:
        s_run = s_anchor = 0.0
        report.not_identifiable.append("uwb.run_offset_std_m, uwb.run_anchor_offset_std_m (one run; 0 kept)")
    slope_std = _report_run_slopes(slope_diag, report)
    report.not_identifiable.extend(chan.notes)
    return RangingFit(offset_s=offset, offset_se_s=se_off, channels=chan, refinement=ref, fixed_slope=fixed_slope,
                      run_offset_std_m=s_run, run_anchor_offset_std_m=s_anchor, range_bias_law=law,
                      offset_std_s=lag_std, tag_pattern_m=pattern, **slope_std)


def _report_run_slopes(diag: dict[str, Any], report: ReportBuilder) -> dict[str, float]:
    """Report the run-to-run tilts of the range law as the scenario gets them (0 unless applied; the
    fitted values in the notes); the RangingFit fields (none when not applied)."""
    if not diag["identifiable"]:
        report.not_identifiable.append(f"uwb.run_slope_std_m, uwb.run_anchor_slope_std_m ({diag['why']}; 0 kept)")
        return {}
    applied = diag["applied"]
    status = ("generated" if applied else "not generated unless run_slopes=True" if diag["significant"]
              else "not significant: 0")
    for key, n in (("run_slope_std_m", diag["n_runs"]), ("run_anchor_slope_std_m", diag["n_runs"] * diag["n_anchors"])):
        report.param(f"uwb.{key}", diag[key] if applied else 0.0, n=n, summary=True,
                     note=(f"run-to-run spread of the per-run slope of the LOS residuals on log10 range (two-way "
                           f"random effects, REML likelihood ratio {diag['reml_lr_vs_no_spread']:.1f}); fitted "
                           f"{diag[key]:.4f} m per decade: {status}"))
    if not applied:
        return {}
    report.param("uwb.run_slope_ref_range_m", diag["ref_range_m"], n=diag["n_runs"],
                 note="the pooled mean log range of the LOS rows the tilts pivot about")
    return {"run_slope_std_m": diag["run_slope_std_m"], "run_anchor_slope_std_m": diag["run_anchor_slope_std_m"],
            "run_slope_ref_range_m": diag["ref_range_m"]}


def _tag_pattern(chan: _Channels, rep: ReportBuilder, *, apply: bool) -> tuple[float, ...]:
    """``uwb.tag_pattern_m`` from the LOS rows of every (run, anchor) sequence
    (:func:`physynth.calibrate.tag_pattern.fit_tag_pattern`), reported; zeros when not kept or not
    ``apply``."""
    from .tag_pattern import fit_tag_pattern

    def sequences():
        for aid, (ra, ga, _) in chan.per_anchor_rows.items():
            start, runs = 0, chan.per_anchor_run[aid]
            for nlos, t, f, v in zip(chan.flags[aid], chan.per_anchor_t[aid], chan.per_anchor_p[aid],
                                     chan.per_anchor_v[aid], strict=True):
                sl = slice(start, start + nlos.size)
                run = int(runs[start]) if nlos.size else 0
                start += nlos.size
                keep = ~nlos
                yield ra[sl][keep], ga[sl][keep], f[keep], t[keep], v[keep], run

    fit = {**fit_tag_pattern(sequences()), "applied": False}
    rep.sections["tag_pattern"] = fit
    if not fit["identifiable"]:
        rep.not_identifiable.append(f"uwb.tag_pattern_m ({fit['why']})")
        return (0.0, 0.0, 0.0, 0.0)
    se = ", ".join(f"{1e3 * x:.1f}" for x in fit["std_error_m"])
    fit["applied"] = bool(apply and fit["kept"])
    coef = [rounded(c, 4) if fit["applied"] else 0.0 for c in fit["coef_m"]]
    status = ("kept and applied" if fit["applied"] else "kept, not generated unless tag_pattern=True"
              if fit["kept"] else "not kept")
    rep.param("uwb.tag_pattern_m", coef, n=fit["n_rows"], summary=True,
              note=(f"range bias vs the anchor's bearing from the heading, cos/sin/cos2/sin2; fitted "
                    f"{', '.join(f'{1e3 * c:.1f}' for c in fit['fitted_coef_m'])} mm (se {se} mm), Wald "
                    f"{fit['wald']:.1f} (threshold {fit['wald_min']}): {status}"))
    return tuple(coef)


def _lag_spread_section(spread: dict[str, Any] | None, labels: Sequence[str], grid_offset_s: float
                        ) -> dict[str, Any]:
    """The report's ``time_offset.run_spread``: each run's own lag with its standard error, the spread."""
    if spread is None:
        return {"identifiable": False, "why": "fewer than two runs with LOS rows whose range rate changes"}
    w = 1.0 / (spread["std_error_s"] ** 2 + spread["spread_s"] ** 2)
    ok = np.isfinite(w)
    return {"identifiable": True,
            "per_run_s": {lab: (None if np.isnan(d) else grid_offset_s + float(d))
                          for lab, d in zip(labels, spread["correction_s"], strict=True)},
            "per_run_std_error_s": {lab: (None if np.isnan(e) else float(e))
                                    for lab, e in zip(labels, spread["std_error_s"], strict=True)},
            "spread_s": spread["spread_s"], "mean_s": grid_offset_s + spread["mean_correction_s"],
            "mean_std_error_s": float(1.0 / np.sqrt(np.sum(w[ok]))),
            "cochran_q": spread["q"], "dof": spread["dof"], "p_value": spread["p_value"],
            "significant": spread["significant"], "variance_inflation": spread.get("variance_inflation"),
            "variance_dof": spread.get("variance_dof"),
            "method": ("per-run lag corrections regressed on -range rate over the LOS rows ((run, anchor) means "
                       "and per-anchor range terms removed); each run's error from a delete-one-block jackknife "
                       "over blocks in time, its ratio to the independent-rows error pooled over the runs; "
                       "DerSimonian-Laird spread, Cochran's Q against an F distribution at 1 %")}


def fit_link_availability(inp: CalibrationInputs, ranging: RangingFit, timing: TimingFit,
                          report: ReportBuilder) -> AvailabilityFit:
    """Link range, attempt rate, dropout and outages per anchor, and tag outages, pooled over runs."""
    af = fit_availability(inp.traces, ranging.offset_s, timing.burst_rate_hz, inp.anchor_ids)
    av, tag, long_ = af.params["per_anchor"], af.params["tag"], af.params["long_outages"]
    report.sections["availability"] = {"per_anchor": av, "tag_outages": tag, "long_outages": long_,
                                       **af.diagnostics}
    return AvailabilityFit(per_anchor=av, tag=tag, long_outages=long_)


def _pooled_nlos_dwell(ids: Sequence[str], flags: dict[str, list[np.ndarray]], periods: dict[str, float]
                       ) -> tuple[dict[str, float | None], np.ndarray, float | None, float]:
    """NLOS dwell per anchor and one value for the generator, pooled over anchors:
    (per-anchor dwell, all NLOS run lengths, pooled dwell or None, dwell used)."""
    runs_all, per_anchor_dwell = [], {}
    for aid in ids:
        lengths = _nlos_runs(flags[aid])
        per_anchor_dwell[aid] = _dwell_from_runs(lengths, periods[aid])
        runs_all.append(lengths)
    all_runs = np.concatenate(runs_all) if runs_all else np.zeros(0)
    dwell = _dwell_from_runs(all_runs, float(np.mean(list(periods.values()))))
    nlos_dwell = dwell if dwell is not None else UwbParams().nlos_dwell_s
    return per_anchor_dwell, all_runs, dwell, nlos_dwell


def _episodes_and_short_pool(ids: Sequence[str], chan: _Channels, rep: ReportBuilder
                             ) -> tuple[dict[str, list[ModeEpisodes]], ModeEpisodes]:
    """Episodes of every mode per anchor, and the short ones pooled over modes and anchors (reported
    under ``short_nlos_episodes``)."""
    flags, mix = chan.flags, chan.mix
    # episodes of every mode; the short ones (gross outliers: a device behaviour, a few per anchor) are
    # pooled over modes and anchors to learn their length law and whether their offset is held
    empty = ModeEpisodes(lengths=np.zeros(0, np.int64), within_dev_m=np.zeros(0), within_dev_rel=np.zeros(0))
    episodes_of = {aid: (_mode_episodes(chan.per_anchor_rows[aid][0], flags[aid], mix[aid].modes)
                         if aid in chan.per_anchor_rows else [empty] * len(mix[aid].modes)) for aid in ids}
    short_pool = _pool_episodes([e for eps in episodes_of.values() for e in eps if _is_short(e)])
    rep.sections["short_nlos_episodes"] = {
        "rule": f"modes whose episodes last at most {SHORT_EPISODE_MAX_ROWS} rows on average, or with fewer "
                f"than {MIN_MODE_EPISODES} episodes, share one episode law fitted on all their episodes",
        "n_episodes": int(short_pool.lengths.size),
        "length_histogram_rows": np.bincount(short_pool.lengths.astype(np.int64)).tolist()
        if short_pool.lengths.size else [],
        "within_episode_std_m": short_pool.within_std_m, "within_episode_std_rel": short_pool.within_std_rel}
    return episodes_of, short_pool


def _anchor_link_range(aid: str, link: dict[str, Any], rep: ReportBuilder) -> tuple[float, float]:
    """(max range, edge width) of an anchor's link; above the largest range seen when not identifiable."""
    seen = link.get("max_range_seen_m") or 0.0
    if link.get("identifiable"):
        max_range, edge = link["max_range_m"], link["edge_width_m"]
    else:
        max_range, edge = 2.0 * seen + 10.0, 5.0
        rep.not_identifiable.append(f"channel_per_anchor.{aid}.max_range_m ({link.get('why', 'not identifiable')}; "
                                    f"set to {max_range:.0f} m, above the largest range {seen:.1f} m)")
    return max_range, edge


def _anchor_nlos_modes(chan: _Channels, aid: str, f: MixtureFit, episodes: list[ModeEpisodes],
                       short_pool: ModeEpisodes, period_s: float, burst_rate: float, nlos_dwell: float
                       ) -> tuple[list[NlosMode], list[dict[str, Any]], Any]:
    """An anchor's NLOS modes, each with its own episode length: (modes, episode shapes, HMM dwell)."""
    # each mode keeps its own episode length (an episode keeps one reflector): a long, small offset at
    # rest and short gross outliers are different processes
    shapes = [_episode_shape(m, short_pool if _is_short(e) else e, period_s, 1.0 / burst_rate,
                             short=_is_short(e))
              for m, e in zip(f.modes, episodes, strict=True)]
    hmm_dwell = _hmm_mode_dwell(chan, aid, f, shapes, [_is_short(e) for e in episodes], nlos_dwell)
    modes = [NlosMode(weight=rounded(m.weight, 4), mean_m=rounded(m.mean_m, 5), std_m=rounded(m.std_m, 4),
                      dwell_s=None if sh["dwell_s"] is None else rounded(sh["dwell_s"], 4),
                      fixed_dwell=sh["fixed_dwell"],
                      held_jitter_m=None if sh["held_jitter_m"] is None else rounded(sh["held_jitter_m"], 4))
             for m, sh in zip(f.modes, shapes, strict=True)]
    if not modes:
        modes = ChannelParams().nlos_modes
    return modes, shapes, hmm_dwell


def _anchor_std_errors(aid: str, f: MixtureFit, ranging: RangingFit, n_rows: int, period_s: float,
                       anchor_dwell: float | None, nlos_dwell: float) -> dict[str, Any]:
    """An anchor's standard errors, widened by the time-offset uncertainty and by NLOS episodes."""
    se = dict(f.se)
    sens = ((ranging.refinement or {}).get("sensitivity") or {}).get(aid)
    se_off = ranging.offset_se_s
    if sens:  # the LOS mean and slope move with the time offset: add its uncertainty
        se["los_mean_m"] = float(np.hypot(se["los_mean_m"], sens["d_los_mean_per_s"] * se_off))
        d_slope = sens["d_range_bias_per_decade_per_s" if ranging.range_bias_law == "log" else "d_range_bias_per_s"]
        se[ranging.slope_key] = float(np.hypot(se[ranging.slope_key], d_slope * se_off))
        se["includes_time_offset_uncertainty"] = True
    if f.nlos_prob > 0:
        # NLOS comes in episodes: Var(p) ~ 2 p (1 - p) tau_c / T_obs with tau_c = dwell (1 - p)
        t_obs = n_rows * period_s
        tau = (anchor_dwell or nlos_dwell) * (1.0 - f.nlos_prob)
        se["nlos_prob"] = float(max(se["nlos_prob"],
                                    np.sqrt(2.0 * f.nlos_prob * (1.0 - f.nlos_prob) * tau / max(t_obs, 1e-9))))
        se["nlos_prob_method"] = "episodes: sqrt(2 p (1-p) dwell (1-p) / T_obs), at least the binomial SE"
    return se


def _report_anchor_channel(aid: str, f: MixtureFit, se: dict[str, Any], n_a: int, a_av: dict[str, Any],
                           rate: float, max_range: float, chan: _Channels, ranging: RangingFit,
                           rep: ReportBuilder) -> None:
    """An anchor's channel in the report: what was not identifiable, modes below the LOS mean, parameters."""
    link = a_av["link"]
    if not f.modes:
        rep.not_identifiable.append(f"channel_per_anchor.{aid}.nlos_modes (no NLOS rows; nlos_prob = 0, "
                                    "default mode kept)")
    centre = float(f.los_centre(float(np.median(chan.per_anchor_rows.get(aid, ([1.0],) * 3)[1]))))
    negative = [m.mean_m for m in f.modes if m.mean_m < centre]
    if negative:
        rep.warnings.append(
            f"{aid}: {len(negative)} NLOS mode(s) below the LOS mean (means "
            f"{', '.join(f'{m:.2f}' for m in negative)} m): ranges shorter than the truth are not radio NLOS "
            "(that lengthens ranges) but truth errors or ranging outliers; the mixture reproduces them")
    pre = f"channel_per_anchor.{aid}"
    rep.param(f"{pre}.los_mean_m", f.los_mean_m, se=se["los_mean_m"], n=n_a, summary=True)
    rep.param(f"{pre}.los_std_m", f.los_std_m, se=se["los_std_m"], n=n_a, summary=True)
    key = ranging.slope_key
    rep.param(f"{pre}.{key}", getattr(f, key), se=se[key], n=n_a,
              note="fixed to the static-sweep slope" if ranging.fixed_slope is not None else None)
    rep.param(f"{pre}.nlos_prob", f.nlos_prob, se=se["nlos_prob"], n=n_a, summary=True)
    rep.param(f"{pre}.nlos_modes", [[m.weight, m.mean_m, m.std_m] for m in f.modes], se=f.se.get("mode_mean_m"),
              n=n_a, note="(weight, mean_m, std_m); std error of the means")
    rep.param(f"{pre}.rate_hz", rate, n=a_av["attempts"],
              note="recorded attempts" if a_av["attempts_recorded"] else "one attempt per burst (inferred)")
    rep.param(f"{pre}.max_range_m", max_range, n=link.get("n_attempts"),
              note=None if link.get("identifiable") else "not identifiable")


def _antenna_sway(chan: _Channels, rep: ReportBuilder) -> dict[str, Any]:
    """The antenna sway from the LOS rows of every (run, anchor) sequence (those with a trusted truth), their
    range law removed (:func:`physynth.calibrate.antenna_sway.fit_antenna_sway`), reported."""
    from .antenna_sway import fit_antenna_sway

    def sequences():
        for aid, (ra, ga, _) in chan.per_anchor_rows.items():
            f, start = chan.mix[aid], 0
            for nlos, t, c, h in zip(chan.flags[aid], chan.per_anchor_t.get(aid, []), chan.per_anchor_c.get(aid, []),
                                     chan.per_anchor_h.get(aid, []), strict=False):
                x = ra[start:start + nlos.size] - f.los_centre(ga[start:start + nlos.size])
                trusted = chan.per_anchor_trusted[aid][start:start + nlos.size] if aid in chan.per_anchor_trusted \
                    else True
                start += nlos.size
                keep = ~nlos & np.isfinite(x) & trusted
                yield x[keep], t[keep], c[keep], h[keep]

    fit = fit_antenna_sway(sequences())
    rep.sections["antenna_sway"] = fit
    if fit["identifiable"]:
        note = (f"slow share {fit['slow_share']:.2f} of the LOS variance; each anchor's los_std_m keeps the white "
                f"rest (x {np.sqrt(1.0 - fit['slow_share']):.3f})")
        rep.param("uwb.antenna_sway_std_m", fit["std_m"], n=fit["n_rows"], summary=True, note=note)
        mse = ", ".join(f"{k} {v['mse_m4']:.3g}" for k, v in fit["fits"].items())
        rep.param("uwb.antenna_sway_clock", fit["clock"], n=fit["n_rows"], summary=True,
                  note=f"the clock whose exponential fits the LOS residuals' semivariogram best (mean squared "
                       f"error [m^4]: {mse})")
        if fit["clock"] == "time":
            rep.param("uwb.antenna_sway_tau_s", fit["tau_s"], n=fit["n_rows"], summary=True,
                      note="exponential fit to the LOS residual autocovariance over 0.1-2 s")
        else:
            rep.param("uwb.antenna_sway_length_m", fit["length_m"], n=fit["n_rows"], summary=True,
                      note="distance travelled over which the slow error decorrelates (semivariogram fit)")
            if fit["clock"] == "motion":
                rep.param("uwb.antenna_sway_turn_rad", fit["turn_rad"], n=fit["n_rows"], summary=True,
                          note="angle turned over which the slow error decorrelates (semivariogram fit)")
    else:
        rep.not_identifiable.append(f"uwb.antenna_sway_* ({fit['why']})")
    return fit


def _mode_arrays(f: MixtureFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.array([m.weight for m in f.modes]), np.array([m.mean_m for m in f.modes]),
            np.array([m.std_m for m in f.modes]))


def _near_nlos(f: MixtureFit, x: np.ndarray, nlos: np.ndarray) -> np.ndarray:
    """Rows the mixture calls NLOS whose most likely NLOS mode is the near-LOS one a tag-side episode
    gives the anchor (:func:`physynth.models.uwb.tag_mode_index`)."""
    from ..models.uwb import tag_mode_index

    w, mu, sd = _mode_arrays(f) if f.modes else (np.zeros(0),) * 3
    k = tag_mode_index(w, mu, sd) if f.modes else -1
    if k < 0:
        return np.zeros(x.size, dtype=bool)
    logp = np.log(np.maximum(w, 1e-300)) - np.log(sd) - 0.5 * ((x[:, None] - mu) / sd) ** 2
    return nlos & (logp.argmax(axis=1) == k)


def _near_share(f: MixtureFit) -> float:
    """The fraction of rows a mixture gives its near-LOS NLOS mode (nlos_prob x its weight; 0: none)."""
    from ..models.uwb import tag_mode_index

    if not f.modes:
        return 0.0
    w, mu, sd = _mode_arrays(f)
    k = tag_mode_index(w, mu, sd)
    return float(f.nlos_prob * w[k]) if k >= 0 else 0.0


def _tag_nlos(chan: _Channels, ids: Sequence[str], burst_rate_hz: float, rep: ReportBuilder) -> dict[str, Any]:
    """The tag-side NLOS fraction from the anchors' NLOS rows burst by burst
    (:func:`physynth.calibrate.tag_nlos.fit_tag_nlos`), reported."""
    from .tag_nlos import fit_tag_nlos

    per_run: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for k, aid in enumerate(ids):
        if aid not in chan.per_anchor_rows:
            continue
        ra, f, start = chan.per_anchor_rows[aid][0], chan.mix[aid], 0
        runs = chan.per_anchor_run[aid]
        for nlos, t in zip(chan.flags[aid], chan.per_anchor_t.get(aid, []), strict=False):
            x = ra[start:start + nlos.size]
            run = int(runs[start]) if nlos.size else -1
            start += nlos.size
            per_run.setdefault(run, []).append((t, np.full(t.size, k), _near_nlos(f, x, nlos)))
    runs = [tuple(np.concatenate([p[i] for p in parts]) for i in range(3)) for parts in per_run.values()]
    fit = fit_tag_nlos(runs, len(ids), 1.0 / burst_rate_hz, np.array([_near_share(chan.mix[a]) for a in ids]))
    fit["applied"] = bool(fit["identifiable"])
    rep.sections["tag_nlos"] = fit
    if fit["identifiable"]:
        rep.param("uwb.tag_nlos_prob", fit["prob"], n=fit["n_bursts"], summary=True,
                  note="anchors NLOS in the same burst more often than apart (pairs of anchors pooled)")
    else:
        rep.not_identifiable.append(f"uwb.tag_nlos_prob ({fit['why']})")
    return fit


def _pooled_channel(pooled_fit: MixtureFit, per_channel: dict[str, ChannelParams], ids: Sequence[str],
                    burst_rate: float, white: float = 1.0) -> ChannelParams:
    """The channel pooled over anchors (the mean rate, the largest link range, the median edge);
    ``white``: the share of the LOS std left white by the antenna sway."""
    pooled_rate = float(np.mean([per_channel[a].rate_hz for a in ids]))
    pooled_modes = ([NlosMode(weight=rounded(m.weight, 4), mean_m=rounded(m.mean_m, 5), std_m=rounded(m.std_m, 4))
                     for m in pooled_fit.modes] or ChannelParams().nlos_modes)
    return ChannelParams(rate_hz=min(rounded(pooled_rate, 6), burst_rate),
                         los_mean_m=rounded(pooled_fit.los_mean_m, 5),
                         los_std_m=rounded(pooled_fit.los_std_m * white, 5),
                         range_bias_per_m=rounded(pooled_fit.range_bias_per_m, 5),
                         range_bias_per_decade_m=rounded(pooled_fit.range_bias_per_decade_m, 5),
                         nlos_prob=rounded(pooled_fit.nlos_prob, 5), nlos_modes=pooled_modes,
                         max_range_m=rounded(max(c.max_range_m for c in per_channel.values()), 5),
                         edge_width_m=rounded(float(np.median([c.edge_width_m for c in per_channel.values()])), 4))


def _report_static_bias(static: dict[str, Any], ranging: RangingFit, rep: ReportBuilder) -> None:
    """The static sweeps' range-bias slopes in the report (both laws; the fitted law's in the summary)."""
    for key in ("range_bias_per_m", "range_bias_per_decade_m"):
        rep.param(f"static.{key}", static[key], se=static["std_errors"][key], n=static["n_rows"],
                  note=f"static sweeps ({static['environment']}), {static['n_files']} files, rms "
                       f"{static['residual_std_per_law_m'][key]:.4f} m about the per-file medians",
                  summary=key == ranging.slope_key)


def _with_link_budget(inp: CalibrationInputs, channels: ChannelSet, static_sweeps: str | os.PathLike,
                      rep: ReportBuilder) -> ChannelSet:
    """``channels`` with the link budget of :func:`link_budget_for_runs` on every anchor (unchanged, and
    said so, when the recordings' losses do not follow the predicted power)."""
    from .link_budget import link_budget_for_runs

    params, mean_det, lb_rep = link_budget_for_runs(inp.traces, static_sweeps)
    rep.sections["link_budget"] = {**lb_rep, "applied": params is not None}
    if params is None:
        rep.not_identifiable.append("channel.link_budget (the recordings' losses do not follow the power "
                                    "the static sweeps predict)")
        return channels
    det = lb_rep["detection"]
    rep.param("channel.link_budget.sensitivity_dbm", params.sensitivity_dbm, n=det["n_attempts"],
              note=f"losses along the truth, likelihood ratio {det['likelihood_ratio']:.1f}")
    rep.param("channel.link_budget.shadowing_std_db", params.shadowing_std_db, n=det["n_attempts"])
    rep.param("channel.link_budget.tag_height_m", params.tag_height_m, n=lb_rep["static"]["n_positions"],
              note="from the static sweeps' ground nulls")
    per = {aid: c.model_copy(update={"link_budget": params}) for aid, c in channels.per_anchor.items()}
    return replace(channels, pooled=channels.pooled.model_copy(update={"link_budget": params}), per_anchor=per)


def _link_losses_out_of_dropouts(availability: AvailabilitySet, rep: ReportBuilder) -> AvailabilitySet:
    """The per-attempt dropout probabilities with the losses the link budget now makes taken out: the
    dropouts were fitted on all losses, the budget's among them, and the two must not count them twice.
    Per anchor, with m its mean detection under the budget over the recordings' bursts,
    (1 - d') = (1 - d) / m, at least 0; what a dropout probability of 0 cannot take out, (1 - d) - m,
    is reported (``link_loss_not_compensated``, a probability per attempt)."""
    lb = rep.sections.get("link_budget", {})
    mean_det = lb.get("mean_detection_per_anchor")
    if not lb.get("applied") or not mean_det:
        return availability
    pooled_d = availability.pooled.dropout_prob
    per = dict(availability.per_anchor)
    before, left = {}, {}
    for aid, m in mean_det.items():
        o = per.get(aid, AvailabilityOverride())
        d = pooled_d if o.dropout_prob is None else o.dropout_prob
        d_new = max(0.0, 1.0 - (1.0 - d) / max(m, 1e-6))
        before[aid], left[aid] = d, max(0.0, (1.0 - d) - (1.0 - d_new) * m)  # survival lost beyond d
        per[aid] = o.model_copy(update={"dropout_prob": rounded(d_new, 6)})  # the report: reconcile_parameters
    lb["dropout_prob_before"], lb["link_loss_not_compensated"] = before, left
    return replace(availability, per_anchor=per)


def assemble_channels(inp: CalibrationInputs, ranging: RangingFit, avail: AvailabilityFit, timing: TimingFit,
                      report: ReportBuilder) -> ChannelSet:
    """Per-anchor channel parameters (LOS, NLOS modes with their episode lengths, rate, link range)."""
    ids, chan, av, rep = inp.anchor_ids, ranging.channels, avail.per_anchor, report
    burst_rate = timing.burst_rate_hz
    mix, mix_diag, flags = chan.mix, chan.mix_diag, chan.flags
    # NLOS dwell: one value for the generator, pooled over anchors
    periods = {a: av[a]["dropout_outage"]["attempt_period_s"] for a in ids}
    per_anchor_dwell, all_runs, dwell, nlos_dwell = _pooled_nlos_dwell(ids, flags, periods)
    episodes_of, short_pool = _episodes_and_short_pool(ids, chan, rep)
    sway = _antenna_sway(chan, rep)
    tag = _tag_nlos(chan, ids, burst_rate, rep)
    # the share of the LOS variance left white: never 0 (each attempt has its own timing noise; a sway fit on
    # few rows can take the whole variance, which left a LOS std of 0)
    white = float(np.sqrt(max(1.0 - sway["slow_share"], MIN_WHITE_SHARE))) if sway["identifiable"] else 1.0
    channel_diag: dict[str, Any] = {}
    per_channel: dict[str, ChannelParams] = {}
    for aid in ids:
        f = mix[aid]
        a_av = av[aid]
        rate = min(a_av["attempt_prob"] * burst_rate, burst_rate)
        max_range, edge = _anchor_link_range(aid, a_av["link"], rep)
        episodes = episodes_of[aid]
        modes, shapes, hmm_dwell = _anchor_nlos_modes(chan, aid, f, episodes, short_pool, periods[aid], burst_rate,
                                                      nlos_dwell)
        per_channel[aid] = ChannelParams(
            rate_hz=min(rounded(rate, 6), burst_rate), los_mean_m=rounded(f.los_mean_m, 5),
            los_std_m=rounded(f.los_std_m * white, 5),
            range_bias_per_m=rounded(f.range_bias_per_m, 5),
            range_bias_per_decade_m=rounded(f.range_bias_per_decade_m, 5), nlos_prob=rounded(f.nlos_prob, 5),
            nlos_modes=modes,
            max_range_m=rounded(max_range, 5), edge_width_m=rounded(edge, 4))
        se = _anchor_std_errors(aid, f, ranging, mix_diag[aid]["n"], periods[aid], per_anchor_dwell[aid], nlos_dwell)
        channel_diag[aid] = {**mix_diag[aid], "std_errors": se,
                             "nlos_mode_dwell_hmm": hmm_dwell, "nlos_dwell_s": per_anchor_dwell[aid],
                             "nlos_mode_episodes": [int(e.lengths.size) for e in episodes],
                             "nlos_mode_dwell_s": [sh["dwell_s"] for sh in shapes],
                             "nlos_mode_episode_shape": shapes,
                             "n_nlos_episodes": int(_nlos_runs(flags[aid]).size)}
        _report_anchor_channel(aid, f, se, mix_diag[aid]["n"], a_av, rate, max_range, chan, ranging, rep)
    pooled_fit = chan.pooled_fit
    pooled = _pooled_channel(pooled_fit, per_channel, ids, burst_rate, white)
    rep.sections["channel"] = {"pooled": {"n": int(chan.pooled_r.size), **chan.pooled_sel,
                                          "std_errors": pooled_fit.se},
                               "per_anchor": channel_diag}
    if dwell is None:
        rep.not_identifiable.append("uwb.nlos_dwell_s (no NLOS episodes; default kept)")
    rep.param("uwb.nlos_dwell_s", nlos_dwell, n=int(all_runs.size), note="number of NLOS episodes")
    return ChannelSet(pooled=pooled, per_anchor=per_channel, nlos_dwell_s=nlos_dwell, sway=sway, tag_nlos=tag)


THIN_DATA_EVENTS = 10
"""A rate estimated from fewer events than this is drawn per synthetic trace from its Gamma posterior."""


def _rate_report(rep: ReportBuilder, key: str, post: RatePosterior, burst_rate_hz: float, note: str,
                 se: float | None = None) -> None:
    lo, hi = post.interval_per_s(0.05, 0.95)
    rep.param(key, post.mean_per_s / burst_rate_hz, n=int(round(post.events)), summary=True, se=se,
              interval=[lo / burst_rate_hz, hi / burst_rate_hz],
              note=f"{note}; Gamma posterior mean per burst, 90 % interval (prior Gamma({post.prior_shape:g}, "
                   f"{post.prior_rate_s:g} s)), {post.events:.3g} events in {post.exposure_s:.4g} s")


def _long_outage_params(fit: dict[str, Any], rep: ReportBuilder, *, use: bool) -> dict[str, Any]:
    """The ``long_outage_*`` fields of the pooled availability (:mod:`physynth.calibrate.outage_range`);
    with ``use`` False they are reported and left out of the scenario."""
    if not fit.get("identifiable"):
        if fit:
            rep.not_identifiable.append(f"availability.long_outage_* ({fit.get('why')}; none generated)")
        return {}
    slope = fit["range_slope_per_m"]
    out = {"long_outage_rate_per_s": rounded(fit["rate_per_s"], 8), "long_outage_mean_s": rounded(fit["mean_s"], 5),
           "long_outage_range_slope_per_m": rounded(slope, 5),
           "long_outage_ref_range_m": rounded(fit["ref_range_m"], 3),
           "long_outage_max_range_m": rounded(fit["max_range_m"], 3) if slope else None,
           "long_outage_frailty_shape": (rounded(fit["frailty_shape"], 5) if fit.get("frailty_shape") is not None
                                         else None)}
    note = (f"{fit['n_runs']} runs of >= {fit['min_missed_attempts']} missed attempts; likelihood ratio "
            f"{fit['lr_long']:.3g} against no long outages")
    rep.param("availability.long_outage_rate_per_s", out["long_outage_rate_per_s"], n=fit["n_runs"], summary=True,
              note=note + f"; rate at {out['long_outage_ref_range_m']} m")
    rep.param("availability.long_outage_mean_s", out["long_outage_mean_s"], n=fit["n_runs"], summary=True)
    rep.param("availability.long_outage_range_slope_per_m", out["long_outage_range_slope_per_m"], n=fit["n_runs"],
              summary=True, note=f"likelihood ratio {fit['lr_slope']:.3g} against slope 0"
              + ("" if slope else " (< 10: not kept)"))
    rep.param("availability.long_outage_frailty_shape", out["long_outage_frailty_shape"], n=fit["n_placements"],
              summary=True, note=f"placements (anchor x run); likelihood ratio {fit['lr_frailty']:.3g} against "
                                 "all placements alike" + ("" if out["long_outage_frailty_shape"] else
                                                          " (< 10: not kept)"))
    if not use:
        rep.not_identifiable.append("availability.long_outage_* (fitted and reported; not generated unless "
                                    "long_outages=True)")
        return {}
    return out


def _report_pooled_availability(pooled: AvailabilityParams, n_attempts: int, rep: ReportBuilder, *,
                                in_force: bool) -> None:
    """The pooled dropout and outages in the report: the scenario's values for every anchor without an
    override (``in_force``, in the summary: no anchor has one, as when the anchors were re-placed)."""
    note = "the anchors' values weighted by their attempts"
    rep.param("availability.dropout_prob", pooled.dropout_prob, n=n_attempts, note=note, summary=in_force)
    rep.param("availability.outage_onset_prob", pooled.outage_onset_prob, n=n_attempts, note=note, summary=in_force)
    rep.param("availability.outage_mean_s", pooled.outage_mean_s, n=n_attempts, summary=in_force,
              note="median of the outage means of the anchors with outages")


def assemble_availability(inp: CalibrationInputs, avail: AvailabilityFit, timing: TimingFit,
                          report: ReportBuilder, *, long_outages: bool = False) -> AvailabilitySet:
    """Availability parameters: dropout per anchor, outage and tag-outage rates with Gamma posteriors.

    An outage onset rate is estimated from a handful of events, so it is reported as the posterior of
    a Poisson rate under the prior :data:`physynth.models.availability.RATE_PRIOR_SHAPE` (Jeffreys,
    no prior exposure): Gamma(prior + events, exposure). The scenario gets the posterior mean and,
    when fewer than :data:`THIN_DATA_EVENTS` events back it, the posterior shape, so that each
    synthetic trace draws its own rate (``*_onset_shape``). A process never observed is not generated
    (its interval is still reported). When the anchors were re-placed between the recordings, the
    scenario gets no per-anchor overrides: availability is the placement's, and a new run places them
    anew (leave-one-out on the Hanyang runs: docs/calibration.md).
    """
    ids, av, tag, rep = inp.anchor_ids, avail.per_anchor, avail.tag, report
    burst_rate = timing.burst_rate_hz
    per_anchor: dict[str, AvailabilityOverride] = {}
    for aid in ids:
        do = av[aid]["dropout_outage"]
        pre = f"availability_per_anchor.{aid}"
        if do.get("identifiable"):
            rate_s = do["outage_onset_prob"] * burst_rate
            mean_s = do["outage_mean_s"]
            up_s = do["n_attempts"] * do["attempt_period_s"] * (1.0 / (1.0 + rate_s * mean_s))
            post = gamma_rate_posterior(events=rate_s * up_s, exposure_s=up_s)
            shape = rounded(post.shape, 5) if post.events < THIN_DATA_EVENTS else None
            p = AvailabilityOverride(dropout_prob=rounded(do["dropout_prob"], 5),
                                     outage_onset_prob=rounded(post.mean_per_s / burst_rate, 5),
                                     outage_mean_s=rounded(mean_s, 5), outage_onset_shape=shape)
            _rate_report(rep, f"{pre}.outage_onset_prob", post, burst_rate, "HMM events (rate x up time)",
                         se=do.get("outage_onset_prob_se"))
            rep.param(f"{pre}.outage_mean_s", p.outage_mean_s, se=do.get("outage_mean_s_se"),
                      n=do["n_attempts"], summary=True, note=do.get("why") if do.get("outage_mean_censored") else None)
            if do.get("outage_mean_censored"):
                rep.not_identifiable.append(f"{pre}.outage_mean_s ({do['why']})")
        else:
            p = AvailabilityOverride(dropout_prob=rounded(min(do.get("dropout_prob", 0.0), 1.0), 5),
                                     outage_onset_prob=0.0, outage_mean_s=AvailabilityParams().outage_mean_s)
            rep.not_identifiable.append(f"{pre}.outage_* ({do.get('why', 'not identifiable')}; no outages)")
            rep.param(f"{pre}.outage_onset_prob", 0.0, n=do["n_attempts"], note=do.get("why"))
        rep.param(f"{pre}.dropout_prob", p.dropout_prob, se=do.get("dropout_prob_se"), n=do["n_attempts"],
                  summary=True)
        per_anchor[aid] = p
    attempts = np.array([av[a]["dropout_outage"]["n_attempts"] for a in ids], dtype=float)
    weights = attempts / attempts.sum() if attempts.sum() > 0 else np.full(len(ids), 1.0 / len(ids))
    means = [p.outage_mean_s for p in per_anchor.values() if p.outage_onset_prob > 0]
    # tag outages: n events (the dark runs' tag probabilities summed) over the up bursts of every run
    n_tag = tag.get("events", tag["n_outages"] + tag["n_censored"])
    up_s = tag["effective_up_bursts"] / burst_rate  # outages too short to be told apart are not exposure
    tag_post = gamma_rate_posterior(events=float(n_tag), exposure_s=max(up_s, 1e-9))
    if n_tag:
        tag_onset = rounded(tag_post.mean_per_s / burst_rate, 5)
        tag_shape = rounded(tag_post.shape, 5) if n_tag < THIN_DATA_EVENTS else None
    else:
        tag_onset, tag_shape = 0.0, None
    pooled = AvailabilityParams(
        dropout_prob=rounded(float(np.dot(weights, [p.dropout_prob for p in per_anchor.values()])), 5),
        outage_onset_prob=rounded(float(np.dot(weights, [p.outage_onset_prob for p in per_anchor.values()])), 5),
        outage_mean_s=rounded(float(np.median(means)) if means else AvailabilityParams().outage_mean_s, 5),
        tag_outage_onset_prob=tag_onset,
        tag_outage_mean_s=rounded(tag["mean_s"], 5) if tag.get("mean_s") else AvailabilityParams().tag_outage_mean_s,
        tag_outage_onset_shape=tag_shape,
        **_long_outage_params(avail.long_outages, rep, use=long_outages),
    )
    _report_pooled_availability(pooled, int(attempts.sum()), rep, in_force=bool(inp.layout.get("conflicts")))
    if up_s > 0:
        _rate_report(rep, "availability.tag_outage_onset_prob", tag_post, burst_rate,
                     "tag outages" + ("" if n_tag else " (none seen: not generated)"))
    else:
        rep.param("availability.tag_outage_onset_prob", 0.0, n=0, note="no up time", summary=True)
    if tag.get("mean_s"):
        rep.param("availability.tag_outage_mean_s", pooled.tag_outage_mean_s, n=tag["n_outages"],
                  note="uncensored tag outages")
    if inp.layout.get("conflicts"):  # anchors re-placed between the runs
        rep.not_identifiable.append(
            "availability_per_anchor (the anchors were re-placed between the recordings: an anchor's outages "
            "and dropouts belong to its placement, not to the device, so the scenario takes the values pooled "
            "over anchors and placements; the per-anchor fits are in this report)")
        return AvailabilitySet(pooled=pooled, per_anchor={})
    return AvailabilitySet(pooled=pooled, per_anchor=per_anchor)


def fit_imu_step(inp: CalibrationInputs, report: ReportBuilder, progress: ProgressCallback) -> ImuParams:
    """IMU noise from every recording with IMU samples (the IMU-only ones included)."""
    imu_traces = [t for t in inp.traces if t.imu is not None and t.imu.t_s.size > 100] + inp.imu_only
    if not imu_traces:
        report.sections["imu"] = {"note": "no IMU samples in the recordings: IMU parameters are the defaults, "
                                          "not calibrated"}
        report.not_identifiable.append("imu (no IMU data; defaults kept)")
        return ImuParams()
    progress("fitting IMU noise")
    from .imu_fit import fit_imu

    imf = fit_imu(imu_traces)
    p = imf.params
    from .imu_only import has_body_imu

    if any(has_body_imu(t) for t in imu_traces):  # fitted by the IMU-only calibration alone
        report.not_identifiable.append("body_imu (the body-frame accelerometer and gyroscope are fitted only when "
                                       "every recording is IMU-only; defaults kept)")
    report.sections["imu"] = imf.diagnostics
    report.param("imu.white_noise_density_mps2_per_sqrt_hz", list(p.white_noise_density_mps2_per_sqrt_hz),
                 n=imf.n_samples, summary=True)
    report.param("imu.bias_rw_mps2_per_sqrt_s", p.bias_rw_mps2_per_sqrt_s, n=imf.n_samples)
    report.param("imu.vibration.fundamental_hz", p.vibration.fundamental_hz, n=imf.n_samples, summary=True)
    report.param("imu.vibration.amplitude_mps2", p.vibration.amplitude_mps2, n=imf.n_samples, summary=True)
    return p


def _sway_params(sway: dict[str, Any]) -> dict[str, float]:
    """``uwb.antenna_sway_*`` of an identified sway fit (none otherwise: the defaults, no sway)."""
    if not sway.get("identifiable"):
        return {}
    if sway.get("clock") in ("distance", "motion"):
        turn = {"antenna_sway_turn_rad": rounded(sway["turn_rad"], 3)} if sway["clock"] == "motion" else {}
        return {"antenna_sway_std_m": rounded(sway["std_m"], 4), "antenna_sway_clock": sway["clock"],
                "antenna_sway_length_m": rounded(sway["length_m"], 3), **turn}
    return {"antenna_sway_std_m": rounded(sway["std_m"], 4), "antenna_sway_tau_s": rounded(sway["tau_s"], 3)}


def _late_burst_params(bf: dict[str, Any]) -> dict[str, float]:
    """The scenario's late-stamp fields (none when calibration kept no late stamps: the defaults)."""
    if not bf["late_burst_prob"]:
        return {}
    return {"late_burst_prob": rounded(bf["late_burst_prob"], 5),
            "late_burst_delay_s": rounded(bf["late_burst_delay_s"], 4)}


def build_scenario(name: str, inp: CalibrationInputs, geometry: GeometryFit, timing: TimingFit,
                   ranging: RangingFit, channels: ChannelSet, availability: AvailabilitySet, imu: ImuParams,
                   *, sources: Sequence[str], created_utc: str, report: ReportBuilder) -> Scenario:
    """The calibrated scenario, composed from the fitted parameter objects."""
    bf = timing.burst.params
    phase = bf["burst_phase_s"]
    uwb = UwbParams(burst_rate_hz=timing.burst_rate_hz, burst_jitter_s=rounded(bf["burst_jitter_s"], 4),
                    burst_phase_s=None if phase is None else rounded(phase, 5),
                    slot_s=rounded(bf["slot_s"], 5), time_offset_s=rounded(ranging.offset_s, 5),
                    time_offset_std_s=rounded(ranging.offset_std_s, 5),
                    nlos_dwell_s=rounded(channels.nlos_dwell_s, 4), zones=[],
                    run_offset_std_m=rounded(ranging.run_offset_std_m, 4),
                    run_anchor_offset_std_m=rounded(ranging.run_anchor_offset_std_m, 4),
                    run_slope_std_m=rounded(ranging.run_slope_std_m, 4),
                    run_anchor_slope_std_m=rounded(ranging.run_anchor_slope_std_m, 4),
                    run_slope_ref_range_m=rounded(ranging.run_slope_ref_range_m, 3),
                    **_sway_params(channels.sway), tag_pattern_m=list(ranging.tag_pattern_m),
                    tag_nlos_prob=rounded(channels.tag_nlos["prob"], 4) if channels.tag_nlos["applied"] else 0.0,
                    **_late_burst_params(bf))
    report.not_identifiable.append("uwb.zones (NLOS zones along the path are not fitted)")
    provenance = {
        "calibrated_by": f"physynth {__version__}",
        "created_utc": created_utc,
        "datasets": list(sources),
        "recordings": inp.labels,
        "imu_only_recordings": inp.imu_only_labels,
        "command": "physynth calibrate",
    }
    if len(inp.layout["layouts"]) > 1:
        provenance["anchor_layout"] = {"policy": inp.layout["policy"],
                                       "generation_layout": inp.layout["generation_layout"],
                                       "layouts": inp.layout["layouts"]}
    return Scenario(
        name=name,
        description=(f"Calibrated by physynth {__version__} on {len(inp.traces)} recording(s): "
                     + ", ".join(inp.labels)),
        path=geometry.path,
        motion=geometry.motion,
        imu=imu,
        uwb=uwb,
        anchors=inp.anchors,
        channel=channels.pooled,
        channel_per_anchor={a: ChannelOverride(**dict(c)) for a, c in channels.per_anchor.items()},
        availability=availability.pooled,
        availability_per_anchor=availability.per_anchor,
        provenance=jsonable(provenance),
    )


# ---------------------------------------------------------------- the whole calibration
N_STEPS = 8


def _check_options(static_sweeps: str | os.PathLike | None, range_bias: str, range_bias_law: str,
                   link_budget: bool) -> None:
    """The option mistakes :func:`calibrate` refuses before any fitting."""
    if link_budget and static_sweeps is None:
        raise CalibrationError("link_budget=True needs static_sweeps (the Static_measurements folder)")
    if range_bias == "static" and static_sweeps is None:
        raise CalibrationError("range_bias='static' needs static_sweeps (the Static_measurements folder)")
    if range_bias_law not in RANGE_BIAS_LAWS:
        raise CalibrationError(f"unknown range-bias law {range_bias_law!r} (choose from {', '.join(RANGE_BIAS_LAWS)})")
    if static_sweeps is not None and not Path(static_sweeps).is_dir():
        raise CalibrationError(f"static sweeps folder {static_sweeps} does not exist")


def calibrate(traces: Trace | Sequence[Trace], *, name: str = "calibrated", path_kind: PathKind = "auto",
              anchor_policy: AnchorPolicy = "per-run", layout_from: int | str | None = None,
              static_sweeps: str | os.PathLike | None = None, range_bias: Literal["dynamic", "static"] = "dynamic",
              range_bias_law: Literal["log", "linear"] = "log",
              sources: Sequence[str] | None = None, long_outages: bool = False, tag_pattern: bool = False,
              run_slopes: bool = False, link_budget: bool = False, trusted_truth: bool = False,
              progress: ProgressCallback | None = None) -> CalibrationResult:
    """Calibrate a scenario on one or several recordings (real or synthetic Traces).

    Parameters
    ----------
    traces
        Recordings with ground truth and UWB rows (and optionally IMU samples), pooled.
    path_kind
        ``auto`` (polynomial for a cable-like path, else waypoints), ``polynomial`` or ``waypoints``.
    anchor_policy
        ``per-run`` (default): runs may place the anchors differently (each run's residuals against
        its own layout; channel parameters per anchor id pooled over the runs; the run-to-run ranging
        offsets become ``uwb.run_offset_std_m`` / ``uwb.run_anchor_offset_std_m``); the scenario
        generates with the layout of ``layout_from`` and records the others in its provenance.
        ``strict``: an anchor id placed differently by two recordings is an error. ``first``: the
        same as ``per-run`` without ``layout_from`` (the first recording's layout, each anchor it lacks
        at its first position elsewhere); every policy fits each run against its own layout.
    layout_from
        Index or label of the recording whose anchor layout the scenario generates with (``per-run``).
    static_sweeps
        Optional Hanyang ``Static_measurements`` folder: the range-proportional bias is also fitted on
        the static sweeps (reported), and used for every anchor when ``range_bias="static"``.
    range_bias_law
        How the LOS mean error grows with the true range r: ``log`` (default), gamma log10(r / 1 m),
        the received-power bias (``channel.range_bias_per_decade_m``); ``linear``, beta r, a clock-scale
        error (``channel.range_bias_per_m``, the former model).
    sources
        Names of the datasets the traces came from (provenance).
    long_outages
        Generate the long outages (``availability.long_outage_*``) the fit identifies (always fitted and
        reported); off by default: on the shared Hanyang runs they belong to one anchor placement and
        worsen the leave-one-out age of information (docs/calibration.md, "Long outages").
    tag_pattern
        Generate the tag antenna pattern (``uwb.tag_pattern_m``) when the fit keeps it, and fit the
        channels to the residuals with it removed. It is always fitted and reported; off by default
        because on the shared Hanyang walks (all along one route) applying it worsened the left-out
        runs' KS and the tracking study (docs/calibration.md, "Where the anchors lie from the walker").
    run_slopes
        Generate the run-to-run tilts of the range law (``uwb.run_slope_std_m``, ``uwb.run_anchor_slope_std_m``;
        several runs) the fit finds, and fit the channels with each run's tilt removed (always fitted and
        reported); off by default: on the shared Hanyang walks it made one left-out run's KS and the
        tracking study worse (docs/calibration.md, "Run-to-run tilts of the range law").
    link_budget
        Give every anchor a link budget (needs ``static_sweeps``; ``link_budget.link_budget_for_runs``), the
        dropouts lowered by its mean loss. Off by default (docs/calibration.md, "Fades from the anchor's height").
    trusted_truth
        Fit the ranging channel on the ranges whose truth the recording trusts (outside its
        ``truth_untrusted_s`` spans). Off by default (docs/calibration.md, "Where the truth itself errs").
    progress
        ``progress(message, done, total)`` before each step (:mod:`physynth.progress`).
    """
    _check_options(static_sweeps, range_bias, range_bias_law, link_budget)
    options = {"anchor_policy": anchor_policy, "layout_from": layout_from, "static_sweeps": static_sweeps,
               "range_bias": range_bias, "range_bias_law": range_bias_law, "long_outages": long_outages,
               "tag_pattern": tag_pattern, "run_slopes": run_slopes, "link_budget": link_budget,
               "trusted_truth": trusted_truth}
    trs = as_trace_list(traces)
    if trs and all(_imu_only(t) for t in trs):  # IMU recordings only: IMU models, path and motion, no anchors
        from .imu_only import calibrate_imu_only

        res = calibrate_imu_only(trs, name=name, path_kind=path_kind, sources=sources, progress=progress)
        return _held_to_scenario(res, unused_option_notes(options, uwb=False, n_runs=0, untrusted_truth=False))
    res = _calibrate_uwb(trs, name=name, path_kind=path_kind, sources=sources, progress=progress, **options)
    shares = res.report["truth_quality"]["untrusted_share_of_truth"].values()
    return _held_to_scenario(res, unused_option_notes(options, uwb=True, n_runs=len(res.report["recordings"]),
                                                      untrusted_truth=any(x > 0 for x in shares)))


def _held_to_scenario(res: CalibrationResult, notes: Sequence[str]) -> CalibrationResult:
    """``res`` with its report's parameters held to the scenario written
    (:func:`~physynth.calibrate.report_fields.reconcile_parameters`) and ``notes`` among its warnings."""
    reconcile_parameters(res.report, res.scenario.model_dump(mode="json"))
    if notes:
        res.report.setdefault("warnings", []).extend(notes)
    return res


def _calibrate_uwb(trs: list[Trace], *, name: str, path_kind: PathKind, anchor_policy: AnchorPolicy,
                   layout_from: int | str | None, static_sweeps: str | os.PathLike | None,
                   range_bias: Literal["dynamic", "static"], range_bias_law: Literal["log", "linear"],
                   sources: Sequence[str] | None, long_outages: bool, tag_pattern: bool, run_slopes: bool,
                   link_budget: bool, trusted_truth: bool, progress: ProgressCallback | None) -> CalibrationResult:
    """:func:`calibrate`'s steps on recordings of which some have UWB ranges (its report as fitted)."""
    say = progress or no_progress
    step = iter(range(N_STEPS))

    def tick(message: str) -> None:
        say(message, next(step, N_STEPS - 1), N_STEPS)

    rep = ReportBuilder()
    tick("checking the recordings")
    inp = prepare_inputs(trs, anchor_policy=anchor_policy, layout_from=layout_from, report=rep)
    rep.sections["sources"] = list(sources or [])
    geometry = fit_geometry(inp, path_kind, rep, lambda msg, *_: tick(msg))
    timing = fit_timing(inp, rep, lambda msg, *_: tick(msg))
    tick("fitting LOS/NLOS ranging errors per anchor")
    static = None
    if static_sweeps is not None:
        from .static_bias import fit_static_range_bias

        static = fit_static_range_bias(static_sweeps)
        rep.sections["static_range_bias"] = static
    ranging = fit_ranging(inp, timing, static=static, range_bias=range_bias, report=rep, law=range_bias_law,
                          tag_pattern=tag_pattern, run_slopes=run_slopes, trusted_truth=trusted_truth)
    tick("fitting availability (link range, dropouts, outages)")
    avail = fit_link_availability(inp, ranging, timing, rep)
    channels = assemble_channels(inp, ranging, avail, timing, rep)
    if static is not None:
        _report_static_bias(static, ranging, rep)
    availability = assemble_availability(inp, avail, timing, rep, long_outages=long_outages)
    if link_budget and static_sweeps is not None:  # static_sweeps checked on entry
        channels = _with_link_budget(inp, channels, static_sweeps, rep)
        availability = _link_losses_out_of_dropouts(availability, rep)
    imu = fit_imu_step(inp, rep, lambda msg, *_: tick(msg))
    scn = build_scenario(name, inp, geometry, timing, ranging, channels, availability, imu,
                         sources=list(sources or []), created_utc=rep.sections["created_utc"], report=rep)
    return CalibrationResult(scenario=scn, report=rep.to_dict())
