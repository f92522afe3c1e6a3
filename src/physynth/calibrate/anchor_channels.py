"""Per-anchor LOS/NLOS mixtures of the ranging residuals, pooled over the runs (:func:`fit_channels`).

Each run's residuals are taken against its own anchor positions, at its lag, with what the ranging
component removes (the run's offsets and tilts, the tag antenna pattern) taken out; the result,
:class:`Channels`, keeps every anchor's rows with the motion clocks and bearings the later components
(episodes, antenna sway, tag pattern, tag NLOS, run offsets) read.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..field_bounds import BOUNDS
from ..models.uwb import heading_at, pattern_features, range_decades, relative_bearing, travelled_m, turned_rad
from ..records import Trace
from ._base import CalibrationError
from .uwb_fit import MIN_ANCHOR_ROWS, MixtureFit, Residuals, corrected_residuals, select_mixture

AnchorRows = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(residual [m], geometric range [m], range rate [m/s]) of an anchor's rows, pooled over runs."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Channels:
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

RunSlopes = dict[tuple[str, str], tuple[float, float]]
"""(run label, anchor id) -> (the run's tilt of the anchor's range law relative to the anchor's mean
over runs [m per decade of range], the mean log10 range of the cell's rows it pivots about)."""

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
    """What :func:`fit_channels` removes from each row of run ``lab``: the run's offset of the row's
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


def fit_channels(trs: Sequence[Trace], offset: float | Sequence[float], ids: Sequence[str], fixed_slope: float | None,
                  labels: Sequence[str], run_offsets: RunOffsets | None = None, law: str = "log",
                  tag_pattern: Sequence[float] | None = None, run_slopes: RunSlopes | None = None,
                  trusted_truth: bool = False) -> Channels:
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
    return Channels(pooled_r=pooled_r, pooled_fit=pooled_fit, pooled_sel=pooled_sel, mix=mix, mix_diag=mix_diag,
                     flags=flags, per_anchor_rows=rows, notes=notes, per_anchor_t=times, per_anchor_run=run_of,
                     per_anchor_c=dist, per_anchor_h=turned, per_anchor_p=pattern_terms, per_anchor_v=speeds,
                     per_anchor_trusted=trusted)
