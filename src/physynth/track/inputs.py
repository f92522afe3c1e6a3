"""Model inputs on the evaluation grid, one function for real and synthetic traces.

For every grid step ``t_k`` (100 Hz, :mod:`physynth.evaluate.grid`) and anchor ``i``:

- ``range_m[k, i]``: the newest valid range of anchor ``i`` measured at or before ``t_k`` (NaN before
  the first one, i.e. masked);
- ``fresh[k, i]``: anchor ``i`` delivered a range in bin ``k`` (:func:`physynth.evaluate.grid.fresh_mask`);
- ``aoi_s[k, i]``: age of information [s] (:func:`physynth.evaluate.grid.age_of_information`);
- ``anchor_pos_rel_m[i]``: the anchor position relative to the trace's reference point;

plus the IMU acceleration as the mean of the samples in each bin (:func:`physynth.evaluate.grid.imu_on_grid`,
NaN without IMU) and the truth position relative to the reference (NaN where unknown). The reference
point is the anchor centroid, so a model sees the geometry of the site, not its coordinates.

UWB stamps may lag the true time (Hanyang: ~0.18 s, ``uwb.time_offset_s`` of a calibrated scenario);
``time_offset_s`` moves every UWB row back by that lag before the grid is built, so that ranges and
truth refer to the same instant. Use the offset estimated on the *training* runs for every run.

The networks' features of these inputs are in :mod:`physynth.track.features`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import DEFAULT_GRID_RATE_HZ
from ..evaluate.grid import age_of_information, fresh_mask, grid_times, imu_on_grid
from ..records import Trace, Uwb, untrusted_truth
from .height import HeightPrior


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackInput:
    """One trace on the grid, as every tracker sees it.

    Shapes: ``t_s`` (K,) [s]; ``range_m``, ``fresh``, ``aoi_s`` (K, A); ``anchor_pos_rel_m`` (A, 3) [m];
    ``acc_mps2`` (K, 3) [m s^-2] ENU gravity-free, or None without IMU; ``pos_rel_m`` (K, 3) [m]
    truth (NaN where unknown); ``ref_enu_m`` (3,) [m] the reference point (anchor centroid) that
    relative positions are measured from. ``first_range_s`` is the time of the first valid range.
    """

    t_s: np.ndarray
    range_m: np.ndarray
    fresh: np.ndarray
    aoi_s: np.ndarray
    anchor_pos_rel_m: np.ndarray
    acc_mps2: np.ndarray | None
    pos_rel_m: np.ndarray
    ref_enu_m: np.ndarray
    first_range_s: float
    rate_hz: float
    label: str = ""
    height: HeightPrior | None = None
    """What is known of the tag's height without the ranges (the carrier's height above the ground), or
    None: the trackers then take the vertical from the ranges alone."""

    @property
    def height_rel_m(self) -> float | None:
        """The height prior's mean relative to ``ref_enu_m`` [m] (None without a prior)."""
        return None if self.height is None else self.height.mean_m - float(self.ref_enu_m[2])

    @property
    def n_steps(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def n_anchors(self) -> int:
        return int(self.anchor_pos_rel_m.shape[0])

    @property
    def pos_enu_m(self) -> np.ndarray:
        """Truth (K, 3) in the trace's own ENU frame [m]."""
        return self.pos_rel_m + self.ref_enu_m

    @property
    def anchor_pos_enu_m(self) -> np.ndarray:
        return self.anchor_pos_rel_m + self.ref_enu_m

    def eval_mask(self) -> np.ndarray:
        """(K,) steps that are scored: truth known and at or after the first valid range."""
        return np.all(np.isfinite(self.pos_rel_m), axis=1) & (self.t_s >= self.first_range_s)


def shift_uwb(trace: Trace, time_offset_s: float) -> Trace:
    """The trace with every UWB stamp moved back by ``time_offset_s`` [s] (stamp - offset = true time)."""
    if time_offset_s == 0.0:
        return trace
    u = trace.uwb
    uwb = Uwb(t_s=u.t_s - time_offset_s, anchor=u.anchor, range_m=u.range_m, true_range_m=u.true_range_m,
              nlos=u.nlos, burst=u.burst, reason=u.reason, nlos_known=u.nlos_known)
    return Trace(truth=trace.truth, uwb=uwb, anchors=trace.anchors, imu=trace.imu, meta=trace.meta)


def latest_range(trace: Trace, t_s: np.ndarray) -> np.ndarray:
    """(K, A) newest valid range [m] of each anchor at or before each time of ``t_s``; NaN before the first."""
    uwb = trace.uwb
    ok = uwb.valid
    out = np.full((t_s.shape[0], len(trace.anchors)), np.nan)
    for i in range(len(trace.anchors)):  # one pass per anchor, vectorised over time
        sel = ok & (uwb.anchor == i)
        ti, ri = uwb.t_s[sel], uwb.range_m[sel]
        if ti.size == 0:
            continue
        j = np.searchsorted(ti, t_s + 1e-9, side="right") - 1
        out[:, i] = np.where(j >= 0, ri[np.maximum(j, 0)], np.nan)
    return out


def track_input(trace: Trace, *, time_offset_s: float = 0.0, rate_hz: float = DEFAULT_GRID_RATE_HZ,
                label: str = "", trusted_truth_only: bool = False, height: HeightPrior | None = None) -> TrackInput:
    """The grid inputs of one trace (real or synthetic) after removing the UWB lag ``time_offset_s`` [s].

    ``trusted_truth_only``: the truth is NaN (unknown) at the grid steps inside the recording's untrusted
    truth spans (``meta["truth_untrusted_s"]``, :func:`physynth.records.untrusted_truth`; the grid steps
    are truth times), so that a network is not trained on positions the truth system itself flags, and
    a score leaves them out. A trace without spans is unchanged. ``height``: the tag's height prior,
    handed to every tracker with the input (:class:`~physynth.track.height.HeightPrior`).
    """
    tr = shift_uwb(trace, time_offset_s)
    t_s = grid_times(tr.t0_s, tr.duration_s, rate_hz)
    ref = tr.anchors.pos_enu_m.mean(axis=0) if len(tr.anchors) else np.zeros(3)
    valid_t = tr.uwb.t_s[tr.uwb.valid]
    pos_rel = tr.truth.position_at(t_s) - ref
    if trusted_truth_only:
        pos_rel[untrusted_truth(tr.meta, t_s)] = np.nan
    return TrackInput(
        t_s=t_s,
        range_m=latest_range(tr, t_s),
        fresh=fresh_mask(tr, t_s, rate_hz),
        aoi_s=age_of_information(tr, t_s),
        anchor_pos_rel_m=tr.anchors.pos_enu_m - ref,
        acc_mps2=imu_on_grid(tr, t_s, rate_hz) if tr.imu is not None else None,
        pos_rel_m=pos_rel,
        ref_enu_m=ref,
        first_range_s=float(valid_t[0]) if valid_t.size else float("inf"),
        rate_hz=float(rate_hz),
        label=label or str(trace.meta.get("run") or trace.meta.get("label") or ""),
        height=height,
    )


