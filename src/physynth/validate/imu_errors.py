"""IMU error statistics, reduced trace by trace and compared real against synthetic.

The IMU error of a trace is what the IMU reads minus what its truth says it should read:

- ``imu`` (ENU, gravity-free accelerometer): IMU minus the truth position low-passed at
  ``cutoff_hz`` and differentiated twice (:func:`physynth.calibrate.imu_fit.imu_error`);
- ``acc_body`` (body-frame accelerometer): measured specific force minus R_wb^T (a_w - g_w), with the
  truth attitude; ``gyro`` (gyroscope): measured rate minus the truth body rate low-passed at
  ``cutoff_hz`` (:func:`physynth.calibrate.imu_only.body_truth`). Compared when both sides have them.

Per error and side: the standard deviation per axis (pooled over traces), the Welch PSD (pooled) and
the overlapping Allan deviation (averaged over traces). :func:`imu_error_comparison` gives, for each
error ``<e>`` in (``imu``, ``acc_body``, ``gyro``): ``real.<e>_error_std_<unit>`` and
``synthetic.<e>_error_std_<unit>`` (3 axes), ``relative_deviation_pct.<e>_error_std_<unit>``
((synthetic / real - 1) x 100 per axis), ``extended.<e>_log_spectral_distance_db`` (per axis, RMS of
10 log10(PSD_synth / PSD_real) over 0.2 Hz to 0.95 x Nyquist) and ``extended.<e>_allan_ratio``
(synthetic / real Allan deviation per tau and axis). Units: m s^-2 (``mps2``), rad s^-1 (``radps``).

The floor below :mod:`physynth.validate.compare` (the ``imu_errors`` block of a validation report),
:mod:`physynth.validate.imu_report` (IMU-only validation, whose ``report.json`` holds these keys) and
:mod:`physynth.validate.figures`; it imports none of them.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from scipy.signal import welch

from ..calibrate._base import median_step_s, segments
from ..calibrate.imu_fit import imu_error
from ..calibrate.imu_only import body_truth, has_body_imu
from ..evaluate.stats import allan_deviation
from ..records import Trace

CUTOFF_HZ = 10.0
"""Low-pass cut-off of the truth before differentiation, both sides [Hz]."""
ALLAN_TAUS_S = (0.01, 0.1, 1.0, 10.0)
"""Averaging times of the Allan-deviation ratio [s]."""
ERRORS = {"imu": "mps2", "acc_body": "mps2", "gyro": "radps"}


def _errors(trace: Trace, kinds: Iterable[str] = tuple(ERRORS)) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """Per error kind (of ``kinds``): (error (N, 3), valid mask (N,), sample rate) of one trace."""
    out: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    im = trace.imu
    if im is None:
        return out
    kinds = set(kinds)
    fs = 1.0 / median_step_s(im.t_s)
    if im.acc_mps2 is not None and "imu" in kinds:
        e, ok, _ = imu_error(trace, CUTOFF_HZ)
        out["imu"] = (e, ok, fs)
    if has_body_imu(trace) and kinds & {"acc_body", "gyro"}:
        f_b, w, ok, _ = body_truth(trace, CUTOFF_HZ)
        out["acc_body"] = (im.acc_body_mps2 - f_b, ok & np.all(np.isfinite(im.acc_body_mps2), axis=1), fs)
        out["gyro"] = (im.gyro_body_radps - w, ok & np.all(np.isfinite(im.gyro_body_radps), axis=1), fs)
    return out


class ImuErrorAccumulator:
    """Per error kind (:data:`ERRORS`), reduced trace by trace: std per axis (pooled), Welch PSD
    (pooled, weighted by valid samples) and the overlapping Allan deviation (mean over traces).
    Memory does not grow with the number of traces. ``kinds``: the error kinds to compute."""

    def __init__(self, kinds: Iterable[str] = tuple(ERRORS)) -> None:
        self._acc: dict[str, dict[str, Any]] = {}
        self.kinds = tuple(kinds)

    def add(self, trace: Trace) -> None:
        for kind, (e, ok, fs) in _errors(trace, self.kinds).items():
            if ok.sum() < 100:
                continue
            a = self._acc.setdefault(kind, {"sq": np.zeros(3), "sum": np.zeros(3), "n": 0, "psd": None, "w": 0.0,
                                            "adev_sum": np.zeros((len(ALLAN_TAUS_S), 3)),
                                            "adev_n": np.zeros((len(ALLAN_TAUS_S), 3)), "fs": fs})
            a["sq"] += np.sum(e[ok] ** 2, axis=0)
            a["sum"] += np.sum(e[ok], axis=0)
            a["n"] += int(ok.sum())
            nper = int(min(2 ** int(np.log2(max(ok.sum() // 8, 64))), 8192))
            f, p = welch(np.where(ok[:, None], np.nan_to_num(e), 0.0), fs=fs, nperseg=nper, axis=0)
            if a["psd"] is None:
                a["psd"] = (f, p * ok.sum())
            elif a["psd"][1].shape == p.shape:
                a["psd"] = (f, a["psd"][1] + p * ok.sum())
            a["w"] += float(ok.sum())
            seg = max(segments(trace.imu.t_s, ok, max_gap_s=1.5 / fs), key=lambda s: s[1] - s[0])
            x = e[seg[0]:seg[1]]
            taus = [t for t in ALLAN_TAUS_S if 2 * t * fs < x.shape[0]]
            if taus:
                ad = allan_deviation(x, fs, taus).T  # (len(taus), 3)
                fin = np.isfinite(ad)
                a["adev_sum"][: len(taus)] += np.where(fin, ad, 0.0)
                a["adev_n"][: len(taus)] += fin

    def finish(self) -> dict[str, dict[str, Any]]:
        out = {}
        for kind, a in self._acc.items():
            mean = a["sum"] / a["n"]
            with np.errstate(invalid="ignore", divide="ignore"):
                adev = np.where(a["adev_n"] > 0, a["adev_sum"] / a["adev_n"], np.nan)
            out[kind] = {"std": np.sqrt(np.maximum(a["sq"] / a["n"] - mean**2, 0.0)),
                         "f": a["psd"][0], "psd": a["psd"][1] / a["w"],
                         "adev": adev if np.any(a["adev_n"] > 0) else None, "fs": a["fs"]}
        return out


def imu_error_comparison(rs: dict[str, dict[str, Any]], ss: dict[str, dict[str, Any]]
                         ) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], dict[str, Any]]:
    """(real, synthetic, relative_deviation_pct, extended) of the module docstring, from two
    :class:`ImuErrorAccumulator` summaries; None for a kind that a side lacks."""
    out_r: dict[str, Any] = {}
    out_s: dict[str, Any] = {}
    dev: dict[str, Any] = {}
    ext: dict[str, Any] = {}
    for kind, unit in ERRORS.items():
        key = f"{kind}_error_std_{unit}"
        r, s = rs.get(kind), ss.get(kind)
        out_r[key] = None if r is None else r["std"].tolist()
        out_s[key] = None if s is None else s["std"].tolist()
        if r is None or s is None:
            dev[key] = None
            ext[f"{kind}_log_spectral_distance_db"] = None
            ext[f"{kind}_allan_ratio"] = None
            continue
        dev[key] = (100.0 * (s["std"] / r["std"] - 1.0)).tolist()
        f = r["f"]
        ps = np.stack([np.interp(f, s["f"], s["psd"][:, k]) for k in range(3)], axis=1)
        band = (f > 0.2) & (f < 0.95 * r["fs"] / 2)
        tiny = 1e-30
        ratio_db = 10.0 * np.log10(np.maximum(ps[band], tiny) / np.maximum(r["psd"][band], tiny))
        ext[f"{kind}_log_spectral_distance_db"] = {"axes": "xyz" if kind != "imu" else "enu",
                                                   "per_axis": np.sqrt(np.mean(ratio_db**2, axis=0)).tolist(),
                                                   "band_hz": [0.2, 0.95 * r["fs"] / 2]}
        ext[f"{kind}_allan_ratio"] = (None if r["adev"] is None or s["adev"] is None else
                                      {"tau_s": list(ALLAN_TAUS_S), "ratio": (s["adev"] / r["adev"]).tolist()})
    return out_r, out_s, dev, ext
