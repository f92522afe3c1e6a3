"""Validation figures: paths, ranges, residual CDFs, availability, AoI, outages, autocorrelation and
IMU spectra/Allan deviation, drawn from the :class:`~physynth.validate.evidence.Evidence` of a report.

matplotlib (the ``report`` extra) is imported only when figures are drawn, through the Agg canvas (no
pyplot, no global backend switch).
"""

from __future__ import annotations

import io
import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import PhySynthError
from .evidence import Evidence, SideEvidence
from .report_model import ValidationReport
from .tables import _fmt

REAL_COLOR = "#222222"
SYNTH_COLOR = "#1f77b4"
NLOS_COLOR = "#d62728"

FIGURES: dict[str, str] = {
    "paths": "Path projections East-North and East-Up: synthetic ensemble (blue) over the real path(s) "
             "(black); anchors as red triangles (paper Fig. 3).",
    "speed": "Speed profiles: synthetic ensemble (blue) and real run(s) (black) (paper Fig. 4, left).",
    "ranges": "Measured ranges over time per anchor: the first real trace (left) and the first synthetic "
              "trace (right); grey line = geometric range from the truth, red crosses = NLOS rows where "
              "known (paper Fig. 4, right).",
    "residual_cdf": "Empirical CDF of |residual|, real vs synthetic, log x (paper section IV.A).",
    "residual_per_anchor": "Signed residual distributions per anchor, real vs synthetic, with the "
                           "per-anchor KS statistic; the window spans each side's 1-99 % range (plus 10 %), "
                           "and densities are relative to all values (paper Fig. 5).",
    "availability": "Availability: grid steps by number of fresh anchors, per-anchor fraction of fresh "
                    "grid steps, and fresh anchors over time (1 s moving mean; synthetic median and "
                    "10-90 % band).",
    "aoi": "Age of information: mean AoI over anchors along the run (1 s moving mean; synthetic median and "
           "10-90 % band) and the CDF of all AoI values.",
    "outages": "Gap lengths between consecutive valid ranges of one anchor: complementary CDF, log-log "
               "(dropouts at the left, outages in the tail).",
    "residual_acf": ("Residual autocorrelation at lags 1..10 measurements within each anchor's sequence; pale: "
                     "the residuals within 0.5 m of their anchor's median (the outliers left out)."),
    "imu_spectrum": "Acceleration power spectral density per axis (Welch, 100 Hz grid), real vs synthetic.",
    "allan": "Overlapping Allan deviation of the acceleration per axis, real vs synthetic.",
}
"""Figure file stem -> caption, in report order. The IMU figures appear only when both sides have IMU."""

REPORT_FILES = ("report.json", "report.md", "report.html")


# ---------------------------------------------------------------- matplotlib, lazily
def require_matplotlib() -> tuple[Any, Any]:
    """(Figure, FigureCanvasAgg) classes; a clear PhySynthError when matplotlib is missing."""
    from ..extras import require

    agg = require("matplotlib.backends.backend_agg", "report", "a figure",
                  otherwise="ask for no figures (figures=False)")
    return require("matplotlib.figure", "report", "a figure").Figure, agg.FigureCanvasAgg


def figure_png(fig: Any, canvas_cls: Any) -> bytes:
    canvas_cls(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    return buf.getvalue()


# ---------------------------------------------------------------- figure helpers
def _nan_band(series: Sequence[np.ndarray], q: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Percentiles across traces of per-step series of unequal length -> (steps, (len(q), K))."""
    k = max(s.size for s in series)
    mat = np.full((len(series), k), np.nan)
    for i, s in enumerate(series):  # one row per trace
        mat[i, :s.size] = s
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN tail columns
        return np.arange(k), np.nanpercentile(mat, q, axis=0)


def _moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    if x.size < n or n <= 1:
        return x.astype(float)
    c = np.concatenate([[0.0], np.cumsum(x, dtype=float)])
    out = np.empty(x.size)
    half = n // 2
    lo = np.clip(np.arange(x.size) - half, 0, x.size)
    hi = np.clip(np.arange(x.size) + n - half, 0, x.size)
    out[:] = (c[hi] - c[lo]) / (hi - lo)
    return out


def _ecdf(x: np.ndarray, max_points: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    xs = np.sort(x)
    p = np.arange(1, xs.size + 1) / xs.size
    if xs.size > max_points:
        idx = np.unique(np.linspace(0, xs.size - 1, max_points).astype(np.int64))
        xs, p = xs[idx], p[idx]
    return xs, p



def _anchor_positions(ev: SideEvidence) -> tuple[tuple[str, ...], np.ndarray]:
    return ev.anchors.ids, ev.anchors.pos_enu_m



# ---------------------------------------------------------------- figures
def _fig_paths(Figure, ev: Evidence) -> Any:
    fig = Figure(figsize=(11, 4.4), layout="constrained")
    ax_en, ax_eu = fig.subplots(1, 2)
    for p in ev.synthetic.paths_enu_m:
        ax_en.plot(p[:, 0], p[:, 1], color=SYNTH_COLOR, lw=0.6, alpha=0.35)
        ax_eu.plot(p[:, 0], p[:, 2], color=SYNTH_COLOR, lw=0.6, alpha=0.35)
    for p in ev.real.paths_enu_m:
        ax_en.plot(p[:, 0], p[:, 1], color=REAL_COLOR, lw=1.6)
        ax_eu.plot(p[:, 0], p[:, 2], color=REAL_COLOR, lw=1.6)
    ids, pos = _anchor_positions(ev.real)
    for ax, c in ((ax_en, 1), (ax_eu, 2)):
        ax.scatter(pos[:, 0], pos[:, c], marker="^", color=NLOS_COLOR, zorder=5, s=40)
        for a, q in zip(ids, pos, strict=True):
            ax.annotate(a, (q[0], q[c]), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.grid(alpha=0.3)
        ax.set_xlabel("East [m]")
    ax_en.set_ylabel("North [m]")
    ax_en.set_aspect("equal", adjustable="datalim")
    ax_eu.set_ylabel("Up [m]")
    ax_en.set_title("East-North")
    ax_eu.set_title("East-Up")
    ax_en.plot([], [], color=SYNTH_COLOR, label=f"synthetic ({ev.synthetic.n_traces})")
    ax_en.plot([], [], color=REAL_COLOR, label=f"real ({ev.real.n_traces})")
    ax_en.legend(fontsize=8, loc="best")
    return fig


def _fig_speed(Figure, ev: Evidence) -> Any:
    fig = Figure(figsize=(9, 3.8), layout="constrained")
    ax = fig.subplots()
    for t, v in ev.synthetic.speeds:
        ax.plot(t, v, color=SYNTH_COLOR, lw=0.6, alpha=0.35)
    for t, v in ev.real.speeds:
        ax.plot(t, v, color=REAL_COLOR, lw=1.4)
    ax.plot([], [], color=SYNTH_COLOR, label="synthetic")
    ax.plot([], [], color=REAL_COLOR, label="real")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("speed [m/s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def _fig_ranges(Figure, ev: Evidence) -> Any:
    ids = list(ev.real.anchors.ids)
    n = len(ids)
    fig = Figure(figsize=(11, 1.6 + 1.5 * n), layout="constrained")
    axes = np.atleast_2d(fig.subplots(n, 2, sharex="col", sharey="row", squeeze=False))
    for col, (side, name) in enumerate(((ev.real, "real"), (ev.synthetic, "synthetic"))):
        tr = side.sample
        u = tr.uwb
        t0 = tr.t0_s
        t_truth = tr.truth.t_s
        for row, a in enumerate(ids):
            ax = axes[row, col]
            if a in tr.anchors.ids:
                j = tr.anchors.index(a)
                geom = np.linalg.norm(tr.truth.pos_enu_m - tr.anchors.pos_enu_m[j], axis=1)
                ax.plot(t_truth - t0, geom, color="0.6", lw=1.0)
                rows = (u.anchor == j) & u.valid
                ax.plot(u.t_s[rows] - t0, u.range_m[rows], ".", ms=1.5,
                        color=REAL_COLOR if col == 0 else SYNTH_COLOR)
                if u.nlos_known:
                    nl = rows & u.nlos
                    ax.plot(u.t_s[nl] - t0, u.range_m[nl], "x", ms=3, color=NLOS_COLOR)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(f"{a}\nrange [m]")
            if row == 0:
                ax.set_title(f"{name} trace 0" + ("" if u.nlos_known else " (NLOS unknown)"))
        axes[-1, col].set_xlabel("time since start [s]")
    return fig


def _fig_residual_cdf(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(7, 4.2), layout="constrained")
    ax = fig.subplots()
    for side, color, name in ((ev.real, REAL_COLOR, "real"), (ev.synthetic, SYNTH_COLOR, "synthetic")):
        a = np.abs(side.residual_m)
        a = a[a > 0]
        if a.size:
            x, p = _ecdf(a)
            ax.step(x, p, where="post", color=color, label=f"{name} (n={side.residual_m.size})")
    ax.set_xscale("log")
    pooled = np.abs(np.concatenate([ev.real.residual_m, ev.synthetic.residual_m]))
    pooled = pooled[pooled > 0]
    if pooled.size:
        ax.set_xlim(left=float(np.percentile(pooled, 0.2)))  # no decade of empty left tail
    ax.set_xlabel("|residual| [m]")
    ax.set_ylabel("CDF")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"KS = {_fmt(report.ks_statistic)}, W1 = "
                 f"{_fmt(report.extended.get('residual_wasserstein_m'), 4)} m", fontsize=10)
    return fig


def _fig_residual_per_anchor(Figure, ev: Evidence, report: ValidationReport) -> Any:
    ids = list(report.per_anchor)
    ncol = min(3, len(ids))
    nrow = int(math.ceil(len(ids) / ncol))
    fig = Figure(figsize=(3.7 * ncol, 2.8 * nrow), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    for ax, a in zip(axes, ids, strict=False):
        r = ev.real.residual_m[ev.real.residual_anchor == a]
        s = ev.synthetic.residual_m[ev.synthetic.residual_anchor == a]
        sides = [(x, c, n) for x, c, n in ((r, REAL_COLOR, "real"), (s, SYNTH_COLOR, "synthetic")) if x.size]
        if sides:
            # each side's central 98 %, widened by 10 %: one side's rare far mode does not squash the other
            qs = np.array([np.percentile(x, [1.0, 99.0]) for x, _, _ in sides])
            lo, hi = qs[:, 0].min(), qs[:, 1].max()
            pad = 0.1 * (hi - lo) if hi > lo else 0.5
            bins = np.linspace(lo - pad, hi + pad, 60)
            for x, color, name in sides:
                # density relative to all of the side's values, so the mass outside the window is visible
                w = np.full(x.size, 1.0 / (x.size * (bins[1] - bins[0])))
                ax.hist(x, bins=bins, weights=w, histtype="step", color=color, lw=1.3, label=name)
        ax.set_title(f"{a}: KS {_fmt(report.per_anchor[a]['ks_statistic'])}", fontsize=10)
        ax.set_xlabel("residual [m]")
        ax.grid(alpha=0.3)
    for ax in axes[len(ids):]:
        ax.set_visible(False)
    axes[0].legend(fontsize=8)
    return fig


def _fig_availability(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(13, 3.9), layout="constrained")
    ax_k, ax_a, ax_t = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1, 1.6]})
    kmax = max(ev.real.n_fresh_counts.size, ev.synthetic.n_fresh_counts.size)
    k = np.arange(kmax)
    for off, side, color, name in ((-0.2, ev.real, REAL_COLOR, "real"), (0.2, ev.synthetic, SYNTH_COLOR, "synthetic")):
        c = np.pad(side.n_fresh_counts, (0, kmax - side.n_fresh_counts.size)).astype(float)
        ax_k.bar(k + off, c / max(c.sum(), 1), width=0.4, color=color, label=name)
    ax_k.set_yscale("log")
    ax_k.set_xlabel("fresh anchors in a grid step")
    ax_k.set_ylabel("fraction of grid steps")
    ax_k.set_xticks(k)
    ax_k.legend(fontsize=8)
    ids = list(report.per_anchor)
    x = np.arange(len(ids))
    for off, key, color in ((-0.2, "real", REAL_COLOR), (0.2, "synthetic", SYNTH_COLOR)):
        vals = [(report.per_anchor[a][key] or {}).get("fresh_frac") for a in ids]
        ax_a.bar(x + off, [np.nan if v is None else v for v in vals], width=0.4, color=color, label=key)
    ax_a.set_xticks(x, ids, fontsize=8)
    ax_a.set_ylabel("fraction of grid steps fresh")
    ax_a.set_title("per anchor", fontsize=10)
    _plot_time_band(ax_t, ev.real.n_fresh_series, ev.synthetic.n_fresh_series, ev.real.rate_hz)
    ax_t.set_xlabel("time since start [s]")
    ax_t.set_ylabel("fresh anchors per step (1 s mean)")
    ax_t.legend(fontsize=8)
    for ax in (ax_k, ax_a, ax_t):
        ax.grid(alpha=0.3)
    return fig


def _plot_time_band(ax, real_series, synth_series, rate: float) -> None:
    """1 s moving means over time: the synthetic median with its 10-90 % band, each real trace as a line."""
    win = max(int(round(rate)), 1)
    if synth_series:
        steps, band = _nan_band([_moving_mean(s, win) for s in synth_series], [10, 50, 90])
        ax.fill_between(steps / rate, band[0], band[2], color=SYNTH_COLOR, alpha=0.25, lw=0)
        ax.plot(steps / rate, band[1], color=SYNTH_COLOR, label="synthetic median, 10-90 %")
    for s in real_series:
        ax.plot(np.arange(s.size) / rate, _moving_mean(s, win), color=REAL_COLOR, lw=1.0)
    ax.plot([], [], color=REAL_COLOR, label="real")


def _fig_aoi(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(12, 3.9), layout="constrained")
    ax_t, ax_c = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1]})
    _plot_time_band(ax_t, ev.real.mean_aoi_series, ev.synthetic.mean_aoi_series, ev.real.rate_hz)
    ax_t.set_yscale("log")
    ax_t.set_xlabel("time since start [s]")
    ax_t.set_ylabel("mean AoI over anchors, 1 s mean [s]")
    ax_t.legend(fontsize=8)
    for side, color, name in ((ev.real, REAL_COLOR, "real"), (ev.synthetic, SYNTH_COLOR, "synthetic")):
        a = side.aoi_s[side.aoi_s > 0]
        if a.size:
            x, p = _ecdf(a)
            ax_c.step(x, p, where="post", color=color, label=name)
    ax_c.set_xscale("log")
    ax_c.set_xlim(left=1e-3)
    ax_c.set_xlabel("AoI [s]")
    ax_c.set_ylabel("CDF")
    ax_c.set_title(f"KS = {_fmt(report.extended.get('aoi_ks_statistic'))}", fontsize=10)
    ax_c.legend(fontsize=8, loc="lower right")
    for ax in (ax_t, ax_c):
        ax.grid(alpha=0.3, which="both")
    return fig


def _fig_outages(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(7, 4.2), layout="constrained")
    ax = fig.subplots()
    for side, color, name in ((ev.real, REAL_COLOR, "real"), (ev.synthetic, SYNTH_COLOR, "synthetic")):
        g = side.gap_s[side.gap_s > 0]
        if g.size:
            x, p = _ecdf(g)
            ax.step(x, np.clip(1.0 - p + 1.0 / g.size, 1.0 / g.size, 1.0), where="post", color=color,
                    label=f"{name} ({g.size} gaps, max {g.max():.1f} s)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("gap between consecutive valid ranges of an anchor [s]")
    ax.set_ylabel("P(gap >= x)")
    ax.set_title(f"gap KS = {_fmt(report.extended.get('gap_ks_statistic'))}", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return fig


def _fig_acf(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(7, 3.8), layout="constrained")
    ax = fig.subplots()
    lags = np.arange(1, ev.real.acf.size + 1)
    ax.plot(lags, ev.real.acf, "o-", color=REAL_COLOR, label="real")
    ax.plot(lags, ev.synthetic.acf, "s--", color=SYNTH_COLOR, label="synthetic")
    ax.plot(lags, ev.real.acf_inliers, "o-", color=REAL_COLOR, alpha=0.45, label="real, within 0.5 m")
    ax.plot(lags, ev.synthetic.acf_inliers, "s--", color=SYNTH_COLOR, alpha=0.45, label="synthetic, within 0.5 m")
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xticks(lags)
    ax.set_xlabel("lag [measurements of the same anchor]")
    ax.set_ylabel("residual autocorrelation")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def _fig_imu_spectrum(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(13, 3.8), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    for c, (ax, axis) in enumerate(zip(axes, ("East", "North", "Up"), strict=True)):
        for side, color, name in ((ev.real, REAL_COLOR, "real"), (ev.synthetic, SYNTH_COLOR, "synthetic")):
            f, p = side.psd_f_hz, side.psd_mps2_sq_per_hz
            ax.loglog(f[1:], p[c, 1:], color=color, lw=1.0, label=name)
        ax.set_title(axis)
        ax.set_xlabel("frequency [Hz]")
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("PSD [(m/s²)²/Hz]")
    axes[0].legend(fontsize=8)
    return fig


def _fig_allan(Figure, ev: Evidence, report: ValidationReport) -> Any:
    fig = Figure(figsize=(13, 3.8), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    for c, (ax, axis) in enumerate(zip(axes, ("East", "North", "Up"), strict=True)):
        for side, color, ls, name in ((ev.real, REAL_COLOR, "-", "real"),
                                      (ev.synthetic, SYNTH_COLOR, "--", "synthetic")):
            ax.loglog(side.allan_tau_s, side.allan_dev_mps2[c], ls, color=color, label=name)
        for tau in (0.1, 1.0, 10.0):
            ax.axvline(tau, color="0.7", lw=0.7)
        ax.set_title(axis)
        ax.set_xlabel("tau [s]")
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("Allan deviation [m/s²]")
    axes[0].legend(fontsize=8)
    return fig


_DRAW: dict[str, Callable[..., Any]] = {
    "paths": lambda F, ev, rep: _fig_paths(F, ev),
    "speed": lambda F, ev, rep: _fig_speed(F, ev),
    "ranges": lambda F, ev, rep: _fig_ranges(F, ev),
    "residual_cdf": _fig_residual_cdf,
    "residual_per_anchor": _fig_residual_per_anchor,
    "availability": _fig_availability,
    "aoi": _fig_aoi,
    "outages": _fig_outages,
    "residual_acf": _fig_acf,
    "imu_spectrum": _fig_imu_spectrum,
    "allan": _fig_allan,
}


def available_figures(evidence: Evidence) -> list[str]:
    """Stems of the figures this evidence supports (IMU figures only when both sides have IMU)."""
    names = [n for n in FIGURES if n not in ("imu_spectrum", "allan")]
    r, s = evidence.real, evidence.synthetic
    if r.psd_mps2_sq_per_hz is not None and s.psd_mps2_sq_per_hz is not None \
            and np.array_equal(r.psd_f_hz, s.psd_f_hz):
        names.append("imu_spectrum")
    if r.allan_dev_mps2 is not None and s.allan_dev_mps2 is not None:
        names.append("allan")
    return names


def render_figures(report: ValidationReport, names: Sequence[str] | None = None) -> dict[str, bytes]:
    """The report's figures as PNG bytes, keyed by file stem (order of :data:`FIGURES`).

    Raises
    ------
    PhySynthError
        When the report carries no evidence (read back from JSON) or matplotlib is missing.
    """
    if report.evidence is None:
        raise PhySynthError("this report has no evidence to draw figures from (it was read back from JSON)")
    Figure, Canvas = require_matplotlib()
    ev = report.evidence
    wanted = available_figures(ev) if names is None else [n for n in available_figures(ev) if n in names]
    return {name: figure_png(_DRAW[name](Figure, ev, report), Canvas) for name in wanted}




# ---------------------------------------------------------------- IMU-only reports
IMU_FIGURES: dict[str, str] = {
    "imu_error_psd": "IMU error power spectral density per axis (Welch, pooled over traces), real (black) against "
                     "synthetic (blue); one row per error compared (ENU accelerometer, body-frame accelerometer, "
                     "gyroscope).",
    "imu_error_allan": "Overlapping Allan deviation of the IMU error per axis at the report's averaging times, real "
                       "(black) against synthetic (blue, dashed), mean over traces.",
}
"""Figure file stem -> caption of an IMU-only report (:func:`physynth.validate.imu_report.write_imu_report`)."""

_ENU, _XYZ = ("East", "North", "Up"), ("x", "y", "z")
_IMU_ROWS = {"imu": ("ENU accelerometer error", "(m/s²)²/Hz", "m/s²", _ENU),
             "acc_body": ("body accelerometer error", "(m/s²)²/Hz", "m/s²", _XYZ),
             "gyro": ("gyroscope error", "(rad/s)²/Hz", "rad/s", _XYZ)}


def _imu_figure(Figure, series: dict[str, dict[str, Any]], kinds: Sequence[str], ylabel: str, per_hz: bool,
                xlabel: str, draw: Callable[[Any, dict[str, Any], int, str, str], None]) -> Any:
    """A row per error kind, a column per axis; ``draw(ax, side's series, axis, side name, colour)`` plots one
    side in one cell. ``ylabel`` gets the row's unit (:data:`_IMU_ROWS`; its PSD unit with ``per_hz``)."""
    fig = Figure(figsize=(13, 3.2 * len(kinds) + 0.4), layout="constrained")
    axes = np.asarray(fig.subplots(len(kinds), 3, squeeze=False))
    for row, kind in zip(axes, kinds, strict=True):
        title, psd_unit, unit, names = _IMU_ROWS[kind]
        for c, ax in enumerate(row):
            for side, color in (("real", REAL_COLOR), ("synthetic", SYNTH_COLOR)):
                draw(ax, series[kind][side], c, side, color)
            ax.set_title(f"{title}, {names[c]}")
            ax.grid(alpha=0.3, which="both")
        row[0].set_ylabel(f"{ylabel} [{psd_unit if per_hz else unit}]")
    for ax in axes[-1]:
        ax.set_xlabel(xlabel)
    axes[0, 0].legend(fontsize=8)
    return fig


def _imu_psd_figure(Figure, series: dict[str, dict[str, Any]]) -> Any:
    def draw(ax: Any, sd: dict[str, Any], c: int, side: str, color: str) -> None:
        ax.loglog(sd["f"][1:], sd["psd"][1:, c], color=color, lw=0.9, label=side)

    return _imu_figure(Figure, series, list(series), "PSD", True, "frequency [Hz]", draw)


def _imu_allan_figure(Figure, series: dict[str, dict[str, Any]], taus: Sequence[float]) -> Any:
    def draw(ax: Any, sd: dict[str, Any], c: int, side: str, color: str) -> None:
        ax.loglog(taus, sd["adev"][:, c], "o-" if side == "real" else "s--", color=color, ms=4, label=side)

    kinds = [k for k, v in series.items() if v["real"]["adev"] is not None and v["synthetic"]["adev"] is not None]
    return _imu_figure(Figure, series, kinds, "Allan deviation", False, "tau [s]", draw)


def render_imu_figures(series: dict[str, dict[str, Any]]) -> dict[str, bytes]:
    """The figures of an IMU-only report (:data:`IMU_FIGURES`) as PNG bytes, from its ``series`` (per error
    kind, the real and synthetic pooled PSD and Allan deviation); the Allan figure only where both sides
    have an Allan deviation. Raises PhySynthError without matplotlib."""
    from .imu_errors import ALLAN_TAUS_S

    Figure, Canvas = require_matplotlib()
    out = {"imu_error_psd": figure_png(_imu_psd_figure(Figure, series), Canvas)}
    if any(v["real"]["adev"] is not None and v["synthetic"]["adev"] is not None for v in series.values()):
        out["imu_error_allan"] = figure_png(_imu_allan_figure(Figure, series, ALLAN_TAUS_S), Canvas)
    return out
