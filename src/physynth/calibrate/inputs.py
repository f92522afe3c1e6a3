"""Checked calibration inputs: the recordings labelled, the IMU-only ones set aside, the anchor layouts
read and every run's track summarised once (:func:`prepare_inputs` -> :class:`CalibrationInputs`).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import __version__
from ..records import Trace
from ..scenario import AnchorSpec
from ._base import CalibrationError, as_trace_list, require_truth, trace_label
from .geometry import AnchorPolicy, anchor_layout
from .report import ReportBuilder
from .tracks import TrackSummary, summarize_track


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


def is_imu_only(t: Trace) -> bool:
    """A recording with IMU samples and no UWB range (e.g. a lab trial)."""
    return not (len(t.uwb) > 0 and bool(t.uwb.valid.any())) and t.imu is not None and t.imu.t_s.size > 100


def fingerprint(trace: Trace) -> str:
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
        key = fingerprint(t)
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
