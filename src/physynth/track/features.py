"""Network features of a :class:`~physynth.track.inputs.TrackInput`, and the windows they are cut into.

Networks run on every ``decimation``-th grid step (:func:`network_arrays`): per-anchor features, the
far-field direction of the tag from the anchor centroid (:func:`far_field_direction`), and optionally
the fixed ``ekf`` filter's position (:func:`ekf_prior_rel_m`); their outputs are interpolated back onto
every grid step (:func:`upsample`). This module sits above the classical trackers (it runs the ``ekf``)
and below the networks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .inputs import TrackInput

N_ANCHOR_FEATURES = 9
"""Per-anchor network features: range, anchor position (3), fresh, AoI, has-range, mean range, range - mean."""
RANGE_DIFF_SCALE_M = 1.0
"""Scale of the feature ``range_i - mean range`` [m]: the direction to the tag lives in these differences,
centimetres to a metre for anchors a few metres apart, invisible at the scale of the range itself."""
N_GLOBAL_FEATURES = 12
"""Per-step network features: far-field direction estimate u (3), mean range x u / L (3), and the same
two for the level solve (tag at the anchors' level, ``u_z = 0``; :func:`far_field_direction`)."""
N_EKF_FEATURES = 3
"""Per-step features added by ``network_arrays(..., ekf_prior=True)``: the ``ekf`` position / L."""
EKF_PRIORS = ("none", "input", "residual")
"""How a network uses the ``ekf`` prior (``NetConfig.ekf_prior``): not at all, as an input, or as an input
its output is added to."""


def check_ekf_prior(value: str) -> None:
    """Raise ``PhySynthError`` unless ``value`` is one of :data:`EKF_PRIORS` (shared by the network and the
    study settings)."""
    if value not in EKF_PRIORS:
        from ..errors import PhySynthError

        raise PhySynthError(f"ekf_prior must be one of {', '.join(EKF_PRIORS)}, got '{value}'")


EKF_PRIOR_COAST_S = 1.0
"""Longest extrapolation [s] of the ``ekf`` prior past its last range update; then it holds its position
(:func:`ekf_prior_rel_m`): a filter that coasts on its last velocity through a 22 s outage of a tag that
stopped ends up 20 m away, a prior the networks could not undo."""
DIRECTION_RIDGE_M2 = 0.1
"""Ridge [m^2] of the far-field direction solve (keeps it defined with few anchors or a flat layout)."""
DIRECTION_RANGE_STD_M = 0.1
"""Ranging noise [m] in the weights of the far-field direction solve (:func:`far_field_direction`)."""
DIRECTION_RANGE_RATE_MPS = 1.0
"""Range-rate scale [m/s] in the weights of the far-field direction solve: a range measured ``dt`` before
the newest one may be off by up to the tag speed times ``dt`` (walking pace; see :func:`far_field_direction`)."""
AOI_SCALE_S = 0.1
"""AoI feature ``log1p(aoi_s / AOI_SCALE_S)``: about 0.7 at one nominal 10 Hz period, 5.4 at 22 s."""


def window_starts(n_steps: int, length: int, stride: int) -> np.ndarray:
    """Start indices of windows of ``length`` steps every ``stride`` steps; the last one ends at the end.

    A sequence shorter than ``length`` gives one window starting at 0 (the caller pads it).
    """
    if length < 1 or stride < 1:
        raise ValueError(f"window length and stride must be >= 1, got {length}, {stride}")
    if n_steps <= length:
        return np.zeros(1, dtype=np.int64)
    starts = np.arange(0, n_steps - length + 1, stride, dtype=np.int64)
    if starts[-1] != n_steps - length:
        starts = np.append(starts, n_steps - length)
    return starts


@dataclass(frozen=True, slots=True, kw_only=True)
class NetArrays:
    """Network inputs of one trace on every ``decimation``-th grid step (T = ceil(K / decimation)).

    ``x`` (T, A, 9) float32 per-anchor features: range / L, anchor position / ``anchor_scale_m``, fresh
    in the last ``decimation`` bins, ``log1p(aoi / AOI_SCALE_S)``, has-range, mean range of the anchors
    with a range / L, (range - mean range) / ``RANGE_DIFF_SCALE_M``; L = ``length_scale_m``; ``acc``
    (T, 3) float32 bin-mean acceleration [m s^-2] (zeros without IMU); ``has_imu`` bool; ``y`` (T, 3)
    float32 truth / L (0 where unknown); ``y_ok`` (T,) bool; ``step`` (T,) grid indices; ``g`` (T, 12)
    float32 per-step features (:func:`far_field_direction` ``u`` and mean range x ``u`` / L, full and level
    solves), (T, 15) with the ``ekf`` position / L appended (``ekf_prior``). Every three columns of ``g``
    are one 3-vector.
    """

    x: np.ndarray
    acc: np.ndarray
    has_imu: bool
    y: np.ndarray
    y_ok: np.ndarray
    step: np.ndarray
    g: np.ndarray


def far_field_direction(range_m: np.ndarray, has: np.ndarray, anchor_rel_m: np.ndarray,
                        aoi_s: np.ndarray | None = None, *, level: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Mean range (T,) [m] and direction estimate (T, 3) from the anchor centroid to the tag.

    Far from a compact anchor cluster, ``r_i - mean(r) ~ -(a_i - mean(a)) . u`` with ``u`` the unit
    vector towards the tag, so ``u`` solves a small linear least-squares problem per step (ridge
    ``DIRECTION_RIDGE_M2``), batched over steps. Near the anchors it is only a hint; the networks learn
    how far to trust it. Steps with fewer than two ranges give ``u = 0``.

    The direction lives in centimetre differences between ranges, so the ranges must refer to the same
    instant. With ``aoi_s`` (T, A) [s], the ages of the ranges, the solve is weighted by the inverse
    variance of each range as a stand-in for the newest one:
    ``w_i = s0^2 / (s0^2 + (v (aoi_i - min_j aoi_j))^2)`` with ``s0 = DIRECTION_RANGE_STD_M`` and
    ``v = DIRECTION_RANGE_RATE_MPS``: a range held for seconds while the tag moves (an anchor not heard)
    no longer bends the direction, while ranges of one burst (a tag-level outage: all equally old) keep
    full weight. Without ``aoi_s`` every range has weight 1.

    ``level=True`` solves for the horizontal part of ``u`` only (``u_z = 0``: a tag far away at about
    the anchors' height, as a walker or a ground vehicle). With three ranges the full solve cannot tell a
    direction from its mirror image in the anchors' plane, and the level one can: on the shared Hanyang
    runs, at steps with three fresh ranges, the median azimuth error drops from 11-20 deg to 1-16 deg
    (docs/tracking.md). The networks get both and learn which to trust.
    """
    w = has.astype(float)
    if aoi_s is not None:
        newest = np.min(np.where(has, aoi_s, np.inf), axis=1, keepdims=True)
        rel = np.where(has, aoi_s - np.where(np.isfinite(newest), newest, 0.0), 0.0)
        s0 = DIRECTION_RANGE_STD_M ** 2
        w = np.where(has, s0 / (s0 + (DIRECTION_RANGE_RATE_MPS * rel) ** 2), 0.0)
    n = has.sum(axis=1, keepdims=True)
    sw = w.sum(axis=1, keepdims=True)
    mean_r = (np.where(has, range_m, 0.0) * w).sum(axis=1, keepdims=True) / np.maximum(sw, 1e-12)
    mean_a = (w[..., None] * anchor_rel_m[None]).sum(axis=1) / np.maximum(sw, 1e-12)
    dims = 2 if level else 3
    b = (anchor_rel_m[None] - mean_a[:, None, :])[..., :dims]  # (T, A, dims)
    dr = np.where(has, range_m - mean_r, 0.0)
    m = np.einsum("ta,tai,taj->tij", w, b, b) + DIRECTION_RIDGE_M2 * np.eye(dims)
    v = -np.einsum("ta,tai,ta->ti", w, b, dr)
    u = np.linalg.solve(m, v[..., None])[..., 0]
    if level:
        u = np.concatenate([u, np.zeros((u.shape[0], 1))], axis=1)
    u = np.where(n >= 2, u, 0.0)
    return np.where(n[:, 0] > 0, mean_r[:, 0], 0.0), u


def network_arrays(inp: TrackInput, *, decimation: int = 10, length_scale_m: float = 10.0,
                   anchor_scale_m: float = 2.0, use_imu: bool = True,
                   age_weighted_direction: bool = True, ekf_prior: bool = False) -> NetArrays:
    """Decimated, normalised network inputs of one :class:`TrackInput` (vectorised over steps).

    ``age_weighted_direction``: the far-field direction solve weights each range by its age relative
    to the newest one (:func:`far_field_direction`); False gives every range weight 1 (the
    unweighted solve of earlier releases).
    ``ekf_prior``: append the position of the classical ``ekf`` tracker run on ``inp``
    (:func:`ekf_prior_rel_m`) / L to ``g``.
    """
    k = np.arange(0, inp.n_steps, decimation, dtype=np.int64)
    rng_m = inp.range_m[k]
    has = np.isfinite(rng_m)
    csum = np.concatenate([np.zeros((1, inp.n_anchors)), np.cumsum(inp.fresh, axis=0)])
    lo = np.maximum(k + 1 - decimation, 0)
    fresh = (csum[k + 1] - csum[lo]) > 0
    a = inp.anchor_pos_rel_m[None, :, :] / anchor_scale_m
    n_has = has.sum(axis=1, keepdims=True)
    mean_r = np.where(n_has > 0, np.where(has, rng_m, 0.0).sum(axis=1, keepdims=True) / np.maximum(n_has, 1), 0.0)
    x = np.concatenate([
        np.where(has, rng_m, 0.0)[..., None] / length_scale_m,
        np.broadcast_to(a, (k.size, inp.n_anchors, 3)),
        fresh[..., None].astype(float),
        np.log1p(inp.aoi_s[k] / AOI_SCALE_S)[..., None],
        has[..., None].astype(float),
        np.broadcast_to(mean_r / length_scale_m, has.shape)[..., None],
        np.where(has, rng_m - mean_r, 0.0)[..., None] / RANGE_DIFF_SCALE_M,
    ], axis=-1)
    has_imu = use_imu and inp.acc_mps2 is not None
    if has_imu:
        acc_full = np.nan_to_num(inp.acc_mps2, nan=0.0)
        cs = np.concatenate([np.zeros((1, 3)), np.cumsum(acc_full, axis=0)])
        acc = (cs[k + 1] - cs[lo]) / (k + 1 - lo)[:, None]
    else:
        acc = np.zeros((k.size, 3))
    y = inp.pos_rel_m[k] / length_scale_m
    y_ok = np.all(np.isfinite(y), axis=1) & (inp.t_s[k] >= inp.first_range_s)
    ages = inp.aoi_s[k] if age_weighted_direction else None
    r_bar, u = far_field_direction(rng_m, has, inp.anchor_pos_rel_m, aoi_s=ages)
    _, u_level = far_field_direction(rng_m, has, inp.anchor_pos_rel_m, aoi_s=ages, level=True)
    g = [u, (r_bar[:, None] * u) / length_scale_m, u_level, (r_bar[:, None] * u_level) / length_scale_m]
    if ekf_prior:
        g.append(ekf_prior_rel_m(inp, use_imu=has_imu, fallback_rel_m=r_bar[:, None] * u_level, steps=k)
                 / length_scale_m)
    g = np.concatenate(g, axis=1)
    return NetArrays(x=x.astype(np.float32), acc=acc.astype(np.float32), has_imu=bool(has_imu),
                     y=np.where(y_ok[:, None], y, 0.0).astype(np.float32), y_ok=y_ok, step=k,
                     g=g.astype(np.float32))


def ekf_prior_rel_m(inp: TrackInput, *, use_imu: bool, fallback_rel_m: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(len(steps), 3) [m]: the ``ekf`` tracker's position relative to the anchor centroid at grid ``steps``.

    A fixed filter (:class:`~physynth.track.trackers.ekf.EkfTracker` with its default noise, not fitted:
    the feature depends on the run alone), causal like the networks' recurrent model, that holds its
    position after ``EKF_PRIOR_COAST_S`` without a range. Before its first fix, ``fallback_rel_m`` (the
    far-field position of the level solve).
    """
    from .trackers.ekf import EkfTracker

    pos = EkfTracker(use_imu=use_imu, fit_range_std=False, max_coast_s=EKF_PRIOR_COAST_S).predict_rel(inp)[steps]
    return np.where(np.isfinite(pos).all(axis=1, keepdims=True), pos, fallback_rel_m)


def turn_arrays(arr: NetArrays, matrix: np.ndarray) -> NetArrays:
    """``arr`` in a world moved by the isometry ``matrix`` about the anchor centroid (numpy twin of
    :func:`physynth.track.torch_data.turn_window`): anchor positions, every 3-vector of ``g``, the
    acceleration and the target turn; ranges, ages and flags do not."""
    m = np.asarray(matrix, dtype=np.float32).T
    x = arr.x.copy()
    x[..., 1:4] = x[..., 1:4] @ m
    g = arr.g.copy()
    for j in range(0, g.shape[-1], 3):
        g[..., j:j + 3] = g[..., j:j + 3] @ m
    return NetArrays(x=x, acc=arr.acc @ m, has_imu=arr.has_imu, y=arr.y @ m, y_ok=arr.y_ok, step=arr.step, g=g)


def route_heading_rad(arr: NetArrays) -> float:
    """Heading [rad, counter-clockwise from east] of the run's route, from its ranges alone.

    The sum over the run of the level far-field vectors (mean range x level direction, the last three
    columns of ``g``): where the tag mostly was, seen from the anchor centroid, far points weighing
    most. 0 when the ranges give no direction (a run without ranges, or one that circles the anchors).
    """
    v = np.nansum(arr.g[:, 9:11].astype(np.float64), axis=0)
    return float(np.arctan2(v[1], v[0])) if np.hypot(v[0], v[1]) > 1e-9 else 0.0


def route_frame(arr: NetArrays) -> tuple[NetArrays, np.ndarray]:
    """``arr`` turned so that its route heading (:func:`route_heading_rad`) points east, and the turn.

    A network trained and run in this frame learns the shape of a route relative to its own heading,
    not its compass heading: predictions ``y'`` go back to the world as ``y' @ matrix``.
    """
    from ..transform import isometry_matrix

    matrix = isometry_matrix(-route_heading_rad(arr))
    return turn_arrays(arr, matrix), matrix


def upsample(inp: TrackInput, step: np.ndarray, pos_rel_m: np.ndarray) -> np.ndarray:
    """Positions (T, 3) at grid indices ``step`` -> (K, 3) ENU [m] at every grid step (linear, held at ends)."""
    out = np.empty((inp.n_steps, 3))
    ks = np.arange(inp.n_steps)
    for c in range(3):
        out[:, c] = np.interp(ks, step, pos_rel_m[:, c])
    return out + inp.ref_enu_m
