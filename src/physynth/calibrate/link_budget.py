"""Link-budget calibration (:class:`physynth.models.uwb.LinkBudgetParams`) from received power and from
detection rates.

Two sources, used where a recording has them:

- received power per range (the Hanyang static sweeps carry RSSI and first-path power per range,
  :func:`physynth.io.importers.import_hanyang_static`): :func:`fit_path_loss` fits the log-distance
  law P(r) = P0 - 10 n log10(r / 1 m) plus the two-ray ground term of the antenna heights, with the
  receiver's power-estimate saturation as a nuisance parameter (the DW1000 reports about -80 dBm
  for every stronger signal), and the height of the other antenna above the reflecting ground: the
  interference nulls sit where the ground path is a whole number of wavelengths longer, at a
  distance proportional to the product of the two heights, so their positions fix it. The shadowing
  spread is the scatter of the per-position medians about the fit;
- detection against distance (any recording): :func:`fit_detection_vs_distance` fits the sensitivity
  S of Phi((P(r) - S) / sigma) by maximum likelihood on detected / attempted counts, with P(r) and sigma
  from the power fit (or assumed). When no attempt is lost the likelihood has no maximum: only an
  upper bound on S is returned (the 95 % one-sided profile-likelihood bound).

:func:`fit_link_budget_hanyang_static` runs both on the Hanyang static sweeps (docs/anchors.md).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import optimize
from scipy.special import log_ndtr

from ..errors import PhySynthError
from ..models.uwb import LinkBudgetParams, ground_gain_db

OUTAGE_RATE_FRAC = 0.5
"""Static positions that delivered less than this fraction of the sweep's row rate are reported apart."""

CHI2_1_95_HALF = 1.3528
"""Half the 90 % quantile of chi-square(1): the profile-likelihood drop of a one-sided 95 % bound."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PathLossFit:
    """Fitted path-loss law; powers in dBm, distances in m."""

    ref_power_dbm: float
    path_loss_exponent: float
    ground_reflection: float
    saturation_dbm: float
    shadowing_std_db: float
    wavelength_m: float
    tag_height_m: float
    tag_height_fitted: bool
    rms_db: float
    n_positions: int


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectionFit:
    """Sensitivity fit: ``sensitivity_dbm`` (None when no attempt is lost) and its one-sided 95 % upper bound."""

    sensitivity_dbm: float | None
    sensitivity_upper_95_dbm: float
    n_attempts: int
    n_detected: int
    min_detection_rate: float


def _smooth_min(a: np.ndarray, b: float, scale_db: float = 1.0) -> np.ndarray:
    return b - scale_db * np.logaddexp(0.0, (b - a) / scale_db)


def path_loss_model(params: np.ndarray, horiz_m: np.ndarray, anchor_h_m: np.ndarray, tag_h_m: float,
                    wavelength_m: float, *, with_saturation: bool = True) -> np.ndarray:
    """Reported power [dBm] for (P0, n, rho, P_sat) at horizontal distance and anchor height [m]."""
    p0, n, rho, psat = params
    r = np.hypot(horiz_m, anchor_h_m - tag_h_m)
    p = p0 - 10.0 * n * np.log10(np.maximum(r, 1.0))
    p = p + ground_gain_db(horiz_m, anchor_h_m, np.full_like(horiz_m, tag_h_m), np.full_like(horiz_m, rho),
                           np.full_like(horiz_m, wavelength_m))
    return _smooth_min(p, psat) if with_saturation else p


TAG_HEIGHT_BOUNDS_M = (0.2, 3.0)
"""Range [m] of the fitted height of the other antenna (:func:`fit_path_loss` with ``tag_height_m=None``)."""


def fit_path_loss(horiz_m: np.ndarray, anchor_height_m: np.ndarray, power_dbm: np.ndarray, *,
                  tag_height_m: float | None = None, wavelength_m: float = 0.0462) -> PathLossFit:
    """Fit P0, n, the ground reflection rho, the saturation level and the tag height to per-position
    power medians.

    Parameters
    ----------
    horiz_m, anchor_height_m, power_dbm : arrays (K,)
        Horizontal tag-anchor distance [m], anchor antenna height above ground [m] and the median
        reported power [dBm] at each position.
    tag_height_m : float or None
        Height of the other (tag) antenna above the reflecting ground [m]. None (the default) fits it
        within :data:`TAG_HEIGHT_BOUNDS_M`: the nulls of the two-ray term lie at horizontal distances
        near 2 h_anchor h_tag / (k lambda), k = 1, 2, ..., so sweeps over several anchor heights fix
        it. A number holds it fixed.
    wavelength_m : float
        Carrier wavelength [m] (channel 5: 0.0462 m).
    """
    h = np.asarray(horiz_m, float)
    a = np.asarray(anchor_height_m, float)
    p = np.asarray(power_dbm, float)
    ok = np.isfinite(h) & np.isfinite(a) & np.isfinite(p)
    if ok.sum() < 6:
        raise PhySynthError(f"a path-loss fit needs at least 6 positions with a finite power, got {int(ok.sum())}")
    if tag_height_m is not None and not tag_height_m > 0:
        raise PhySynthError(f"tag_height_m must be positive (or None to fit it), got {tag_height_m}")
    h, a, p = h[ok], a[ok], p[ok]
    fit_h = tag_height_m is None

    def resid(x: np.ndarray) -> np.ndarray:
        return path_loss_model(x[:4], h, a, x[4] if fit_h else tag_height_m, wavelength_m) - p

    lo, hi = [-120.0, 0.5, 0.0, -120.0], [0.0, 6.0, 0.99, 0.0]
    if fit_h:
        lo, hi = lo + [TAG_HEIGHT_BOUNDS_M[0]], hi + [TAG_HEIGHT_BOUNDS_M[1]]
    heights = (0.8, 1.2, 1.8) if fit_h else (None,)
    best = None
    starts = [(p0, n, rho, ht) for p0 in (-40.0, -55.0, -70.0) for n in (1.5, 2.0, 3.0) for rho in (0.2, 0.5, 0.8)
              for ht in heights]
    for p0, n0, rho0, ht0 in starts:  # a grid of starts: saturation and the two-ray term make the cost multi-modal
        x0 = [p0, n0, rho0, float(np.max(p))] + ([ht0] if fit_h else [])
        sol = optimize.least_squares(resid, x0=x0, loss="soft_l1", f_scale=2.0, bounds=(lo, hi))
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    r = resid(best.x)
    mad = float(np.median(np.abs(r - np.median(r))) * 1.4826)
    return PathLossFit(ref_power_dbm=float(best.x[0]), path_loss_exponent=float(best.x[1]),
                       ground_reflection=float(best.x[2]), saturation_dbm=float(best.x[3]), shadowing_std_db=mad,
                       wavelength_m=wavelength_m, tag_height_m=float(best.x[4]) if fit_h else float(tag_height_m),
                       tag_height_fitted=fit_h, rms_db=float(np.sqrt(np.mean(r**2))), n_positions=int(h.size))


def fit_detection_vs_distance(mean_power_dbm: np.ndarray, n_detected: np.ndarray, n_attempts: np.ndarray, *,
                              shadowing_std_db: float) -> DetectionFit:
    """Maximum-likelihood sensitivity of p = Phi((P - S) / sigma) from detected / attempted counts.

    ``mean_power_dbm`` is the modelled mean power at each position (or distance bin). With no lost
    attempt the maximum is at S = -inf and only the upper bound is finite.
    """
    pw = np.asarray(mean_power_dbm, float)
    k = np.asarray(n_detected, float)
    m = np.asarray(n_attempts, float)
    if pw.size == 0 or np.any(k > m) or np.any(m <= 0):
        raise PhySynthError("detection counts: need positions with 0 <= detected <= attempted and attempted > 0")
    sig = max(float(shadowing_std_db), 1e-3)

    def nll(s: float) -> float:
        z = (pw - s) / sig
        return -float(np.sum(k * log_ndtr(z) + (m - k) * log_ndtr(-z)))

    lo, hi = float(pw.min()) - 60.0, float(pw.max()) + 30.0
    res = optimize.minimize_scalar(nll, bounds=(lo, hi), method="bounded")
    s_hat, nll_min = float(res.x), float(res.fun)
    if np.all(k == m) or s_hat <= lo + 1.0:
        s_hat_out: float | None = None
        nll_min = nll(lo)
        s_hat = lo
    else:
        s_hat_out = s_hat
    target = nll_min + CHI2_1_95_HALF
    upper = optimize.brentq(lambda s: nll(s) - target, s_hat, hi) if nll(hi) > target else hi
    return DetectionFit(sensitivity_dbm=s_hat_out, sensitivity_upper_95_dbm=float(upper), n_attempts=int(m.sum()),
                        n_detected=int(k.sum()), min_detection_rate=float(np.min(k / m)))


def detection_counts_vs_distance(traces: Any, anchor_id: str, *, nominal_rate_hz: float, bin_m: float = 5.0,
                                 rate_hz: float = 10.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detected and expected ranges of one anchor per distance bin, from recordings with truth.

    The tag's distance to the anchor is evaluated on a ``rate_hz`` grid of each trace's truth; a bin
    of width ``bin_m`` [m] expects ``nominal_rate_hz`` x (time spent in it) attempts and detects the
    valid ranges whose true distance falls in it. For recordings that log only delivered ranges (most
    real ones): the attempts are implied by the nominal rate. Returns (bin centre [m], detected,
    expected), bins with at least one expected attempt.
    """
    from ..evaluate.grid import grid_times

    dist_t, dist_r = [], []
    dwell = []
    for tr in traces:
        if anchor_id not in tr.anchors.ids:
            continue
        a = tr.anchors.pos_enu_m[tr.anchors.index(anchor_id)]
        t = grid_times(tr.t0_s, tr.duration_s, rate_hz)
        dist_t.append(np.linalg.norm(tr.truth.position_at(t) - a, axis=1))
        dwell.append(np.full(t.shape[0], 1.0 / rate_hz))
        ok = tr.uwb.valid & (tr.uwb.anchor == tr.anchors.index(anchor_id))
        dist_r.append(np.linalg.norm(tr.truth.position_at(tr.uwb.t_s[ok]) - a, axis=1))
    if not dist_t:
        raise PhySynthError(f"no trace has anchor {anchor_id}")
    d_t, d_r, w = np.concatenate(dist_t), np.concatenate(dist_r), np.concatenate(dwell)
    edges = np.arange(0.0, np.nanmax(d_t) + bin_m, bin_m)
    expected = np.histogram(d_t, edges, weights=w * nominal_rate_hz)[0]
    detected = np.histogram(d_r, edges)[0].astype(float)
    keep = expected >= 1.0
    centre = 0.5 * (edges[:-1] + edges[1:])
    return centre[keep], np.minimum(detected[keep], np.round(expected[keep])), np.round(expected[keep])


def static_positions(root: str | os.PathLike, *, power: str = "rssi_fp_dbm") -> Any:
    """Per-position table of the Hanyang static sweeps: environment, anchor height, horizontal distance,
    median power (``rssi_fp_dbm`` or ``rssi_dbm``), rows and duration (pandas DataFrame)."""
    from ..io.importers import import_hanyang_static

    df, _ = import_hanyang_static(root)
    if power not in ("rssi_fp_dbm", "rssi_dbm"):
        raise PhySynthError(f"power must be rssi_fp_dbm or rssi_dbm, got {power}")
    g = df.groupby(["environment", "height_m", "nominal_distance_m"])
    out = g.agg(power_dbm=(power, "median"), n_rows=("range_m", "size"),
                duration_s=("t_s", lambda t: float(t.max() - t.min()))).reset_index()
    return out


def fit_link_budget_hanyang_static(root: str | os.PathLike, *, environment: str = "LOS",
                                   power: str = "rssi_fp_dbm", tag_height_m: float | None = None
                                   ) -> tuple[LinkBudgetParams, dict[str, Any]]:
    """Link budget from the Hanyang static sweeps of one environment (LOS or NLOS).

    Power law from the per-position medians (:func:`fit_path_loss`); detection from the rows each
    ~13 s position delivered against the median row rate of the sweep (the logger's own rate), as
    binomial counts (:func:`fit_detection_vs_distance`). ``tag_height_m``: the other antenna's height
    above the ground (None: fitted from the nulls, and then set on the parameters, so that a scenario
    with them puts the nulls where the sweeps do whatever its path's height). Returns the parameters
    (sensitivity at its upper bound when no loss is seen) and a JSON-able report.
    """
    tab = static_positions(root, power=power)
    tab = tab[tab["environment"] == environment]
    if tab.empty:
        raise PhySynthError(f"no static sweep of environment {environment!r} below {root}")
    fit = fit_path_loss(tab["nominal_distance_m"].to_numpy(), tab["height_m"].to_numpy(),
                        tab["power_dbm"].to_numpy(), tag_height_m=tag_height_m)
    rate = tab["n_rows"] / tab["duration_s"].clip(lower=1e-9)
    nominal_rate = float(np.median(rate))
    attempts = np.maximum(np.round(tab["duration_s"].to_numpy() * nominal_rate), 1.0)
    detected = np.minimum(tab["n_rows"].to_numpy(), attempts)
    # every position counts, those that lost more than half their rows too: on the Hanyang sweeps they
    # are the deepest ground nulls of the fitted law (predicted -92.6 to -95.2 dBm), weak links, not
    # logger resets; they are reported with their predicted power
    heavy = detected < OUTAGE_RATE_FRAC * attempts
    full = np.array([fit.ref_power_dbm, fit.path_loss_exponent, fit.ground_reflection, fit.saturation_dbm])
    mean_p = path_loss_model(full, tab["nominal_distance_m"].to_numpy(), tab["height_m"].to_numpy(),
                             fit.tag_height_m, fit.wavelength_m, with_saturation=False)
    det = fit_detection_vs_distance(mean_p, detected, attempts, shadowing_std_db=max(fit.shadowing_std_db, 0.5))
    params = LinkBudgetParams(ref_power_dbm=round(fit.ref_power_dbm, 2),
                              path_loss_exponent=round(fit.path_loss_exponent, 3),
                              sensitivity_dbm=round(det.sensitivity_dbm if det.sensitivity_dbm is not None
                                                    else det.sensitivity_upper_95_dbm, 1),
                              shadowing_std_db=round(max(fit.shadowing_std_db, 0.5), 2),
                              ground_reflection=round(fit.ground_reflection, 3), wavelength_m=fit.wavelength_m,
                              tag_height_m=round(fit.tag_height_m, 3) if fit.tag_height_fitted else None)
    report = {"environment": environment, "power_column": power, "path_loss": asdict(fit),
              "detection": asdict(det),
              "nominal_row_rate_hz": nominal_rate, "n_positions": int(len(tab)),
              "n_positions_losing_half": int(heavy.sum()),
              "mean_power_of_positions_losing_half_dbm": [round(float(v), 2) for v in mean_p[heavy]],
              "weakest_mean_power_dbm": float(np.min(mean_p)),
              "distance_range_m": [float(tab["nominal_distance_m"].min()), float(tab["nominal_distance_m"].max())],
              "note": ("no detection loss in the sweeps: the sensitivity is the 95 % upper bound"
                       if det.sensitivity_dbm is None else "sensitivity from the detection losses")}
    return params, report


LINK_LR_MIN = 10.0
"""Likelihood ratio a link-budget detection fit on recordings must reach against losses independent of
the predicted power (:func:`fit_link_detection`) for its sensitivity to count as found."""


def burst_link_rows(trace: Any, law: PathLossFit, *, ground_u_m: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (burst in which some anchor answered, anchor): the power ``law`` predicts [dBm] (no saturation;
    anchor heights from the layout above ``ground_u_m``, the tag at ``law.tag_height_m``), whether that
    anchor answered, and its index in ``trace.anchors`` (each (M,)). A burst no anchor answered says
    nothing about any one link (the tag was silent)."""
    from .uwb_fit import burst_ids

    u = trace.uwb
    ok = u.valid
    b, t, a = burst_ids(trace)[ok], u.t_s[ok], u.anchor[ok].astype(np.intp)
    ub, first = np.unique(b, return_index=True)
    n_a = len(trace.anchors)
    answered = np.zeros((ub.size, n_a), dtype=bool)
    answered[np.searchsorted(ub, b), a] = True
    pos = trace.truth.position_at(t[first])
    anc = trace.anchors.pos_enu_m
    horiz = np.hypot(pos[:, None, 0] - anc[None, :, 0], pos[:, None, 1] - anc[None, :, 1])
    heights = np.broadcast_to(anc[None, :, 2] - ground_u_m, horiz.shape)
    x = np.array([law.ref_power_dbm, law.path_loss_exponent, law.ground_reflection, law.saturation_dbm])
    power = path_loss_model(x, horiz.ravel(), heights.ravel(), law.tag_height_m, law.wavelength_m,
                            with_saturation=False)
    idx = np.broadcast_to(np.arange(n_a)[None, :], horiz.shape).ravel()
    keep = np.isfinite(power)
    return power[keep], answered.ravel()[keep], idx[keep]


def fit_link_detection(traces: Any, law: PathLossFit, *, ground_u_m: float = 0.0) -> dict[str, Any]:
    """Sensitivity and per-attempt fading of a link budget from recordings, given its power law.

    Each (burst, anchor) of every trace (:func:`burst_link_rows`) answered with probability
    (1 - q_anchor) Phi((P - S) / sigma): a loss independent of the power per anchor id (dropouts,
    outages) times the link's detection at the power P the law predicts along the truth. S and sigma
    are fitted by maximum likelihood with the q's; the fit is kept (``identifiable``) when its
    likelihood ratio against the q's alone reaches :data:`LINK_LR_MIN` (the losses follow the
    predicted power). Returns a JSON-able dict, with ``mean_detection_per_anchor``: the mean of
    Phi((P - S) / sigma) over each anchor id's rows, the share of its attempts the budget alone lets through.
    """
    from scipy.optimize import minimize
    from scipy.special import expit, log_ndtr, ndtr

    rows = [burst_link_rows(tr, law, ground_u_m=ground_u_m) for tr in traces]
    ids = sorted({aid for tr in traces for aid in tr.anchors.ids})
    gid = [np.searchsorted(ids, np.asarray(tr.anchors.ids))[r[2]] for tr, r in zip(traces, rows, strict=True)]
    p = np.concatenate([r[0] for r in rows])
    y = np.concatenate([r[1] for r in rows])
    g = np.concatenate(gid)
    if p.size == 0:
        raise PhySynthError("a link-detection fit needs bursts with ranges and truth")
    n_g = np.maximum(np.bincount(g, minlength=len(ids)), 1)
    miss = np.bincount(g, weights=~y, minlength=len(ids)) / n_g
    null = -float(np.sum(np.where(y, np.log1p(-miss[g] + 1e-12), np.log(miss[g] + 1e-12))))
    strong = p >= np.quantile(p, 0.5)  # where the link itself hardly loses: a start for the q's
    miss_strong = np.bincount(g[strong], weights=~y[strong], minlength=len(ids)) / np.maximum(
        np.bincount(g[strong], minlength=len(ids)), 1)

    def logit(q: np.ndarray) -> np.ndarray:
        q = np.clip(q, 1e-4, 0.5)
        return np.log(q / (1.0 - q))

    def nll(x: np.ndarray) -> float:
        s, log_sig, q = x[0], x[1], expit(x[2:])[g]
        ld = np.log1p(-q) + log_ndtr((p - s) / np.exp(log_sig))
        return -float(np.sum(np.where(y, ld, np.log(-np.expm1(np.minimum(ld, -1e-12))))))

    best = None
    starts = [(s0, sig0, q0) for s0 in (float(p.min()) - 10.0, float(p.min()), float(np.quantile(p, 0.05)))
              for sig0 in (1.0, 3.0) for q0 in (miss_strong, miss)]
    for s0, sig0, q0 in starts:  # the q's trade off against a soft curve: start from both sides
        sol = minimize(nll, np.concatenate([[s0, np.log(sig0)], logit(q0)]), method="L-BFGS-B",
                       bounds=[(float(p.min()) - 40.0, float(p.max())), (np.log(0.1), np.log(20.0))]
                       + [(-12.0, 0.0)] * len(ids))
        if best is None or sol.fun < best.fun:
            best = sol
    assert best is not None
    lr = 2.0 * (null - float(best.fun))
    mean_det = np.bincount(g, weights=ndtr((p - best.x[0]) / np.exp(best.x[1])), minlength=len(ids)) / n_g
    return {"sensitivity_dbm": float(best.x[0]), "shadowing_std_db": float(np.exp(best.x[1])),
            "baseline_miss": {a: float(v) for a, v in zip(ids, expit(best.x[2:]), strict=True)},
            "mean_detection_per_anchor": {a: float(v) for a, v in zip(ids, mean_det, strict=True)},
            "likelihood_ratio": lr, "identifiable": bool(lr >= LINK_LR_MIN), "n_attempts": int(p.size),
            "n_missed": int((~y).sum()), "weakest_predicted_power_dbm": float(p.min())}


def link_budget_for_runs(traces: Any, static_root: str | os.PathLike, *, environment: str = "LOS"
                         ) -> tuple[LinkBudgetParams | None, dict[str, float], dict[str, Any]]:
    """A link budget for recordings of a site with Hanyang-style static sweeps: the power law (and the
    tag antenna's height) from the sweeps (:func:`fit_link_budget_hanyang_static`), the sensitivity and
    per-attempt fading from the recordings' own losses along their truth (:func:`fit_link_detection`).

    Returns the parameters (None when the recordings' losses do not follow the predicted power), the
    mean detection probability the budget gives each anchor id over the recordings' bursts (to take out
    of a loss model fitted on the same recordings, so that the two do not count the same losses twice),
    and a JSON-able report.
    """
    _, static_rep = fit_link_budget_hanyang_static(static_root, environment=environment)
    law = PathLossFit(**static_rep["path_loss"])
    det = fit_link_detection(traces, law)
    report = {"static": static_rep, "detection": det}
    if not det["identifiable"]:
        return None, {}, report
    mean_det = det["mean_detection_per_anchor"]
    params = LinkBudgetParams(ref_power_dbm=round(law.ref_power_dbm, 2),
                              path_loss_exponent=round(law.path_loss_exponent, 3),
                              sensitivity_dbm=round(det["sensitivity_dbm"], 2),
                              shadowing_std_db=round(det["shadowing_std_db"], 2),
                              ground_reflection=round(law.ground_reflection, 3), wavelength_m=law.wavelength_m,
                              tag_height_m=round(law.tag_height_m, 3))
    report["mean_detection_per_anchor"] = mean_det
    return params, mean_det, report
