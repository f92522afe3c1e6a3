"""Where the geometry cannot tell the vertical, a learned tracker falls back to what is known.

A network trained with a likelihood (:mod:`physynth.track.trackers.nets`) gives each position with a
variance per axis. On an anchor layout unlike its training ones it may still be sure of a vertical the
ranges do not determine (a tag tens of metres from anchors at nearly one height): no network can know
the vertical better than the ranges allow. So its vertical variance is floored by the geometry's, the
Cramér-Rao bound of one set of ranges at its estimate (:func:`geometry_vertical_var`), and the vertical
is then the inverse-variance combination with what is known without the ranges
(:func:`fuse_vertical`): the carrier's height (:class:`~physynth.track.height.HeightPrior`) when the
scenario or the user gives it, otherwise the classical ``ekf``'s vertical and its variance. Where the
geometry is good and the network sure, its own vertical stands; where not, the known height does.

All functions are vectorised over steps; positions are relative to the anchor centroid [m].
"""

from __future__ import annotations

import numpy as np

GEOMETRY_RANGE_STD_M = 0.1
"""Ranging noise [m] of the geometry floor: about the LOS spread of the calibrated sites (0.1 m)."""
GEOMETRY_RIDGE = 1e-6
"""Ridge [1/m^2] added to the range information, so that a step with fewer than three ranges gets a very
large (not infinite) variance."""


def geometry_vertical_var(pos_rel_m: np.ndarray, anchor_rel_m: np.ndarray, has: np.ndarray,
                          range_std_m: float = GEOMETRY_RANGE_STD_M) -> np.ndarray:
    """(T,) [m^2] the vertical variance one set of ranges leaves at each position.

    ``pos_rel_m`` (T, 3) positions, ``anchor_rel_m`` (A, 3) anchors, ``has`` (T, A) which anchors have a
    range at each step. With unit vectors u_i from each anchor to the position, the information is
    ``sum_i u_i u_i^T / range_std_m^2``; the result is the (z, z) entry of its inverse. Far from a
    compact cluster of anchors at one height, u_i are nearly horizontal and alike, and the vertical
    variance grows as (distance / vertical spread of the anchors)^2.
    """
    diff = pos_rel_m[:, None, :] - anchor_rel_m[None]  # (T, A, 3)
    d = np.maximum(np.linalg.norm(diff, axis=2, keepdims=True), 1e-6)
    u = np.where(has[..., None], diff / d, 0.0)
    info = np.einsum("tai,taj->tij", u, u) / range_std_m**2 + GEOMETRY_RIDGE * np.eye(3)
    return np.linalg.inv(info)[:, 2, 2]


def fuse_vertical(z_m: np.ndarray, var_m2: np.ndarray, known_z_m: np.ndarray | float,
                  known_var_m2: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """The inverse-variance combination of two vertical estimates, and its variance (elementwise).

    A NaN known value (no estimate there) leaves the first estimate as it is.
    """
    kz = np.broadcast_to(np.asarray(known_z_m, dtype=float), np.shape(z_m))
    kv = np.broadcast_to(np.asarray(known_var_m2, dtype=float), np.shape(z_m))
    ok = np.isfinite(kz) & np.isfinite(kv) & (kv > 0)
    w = np.where(ok, var_m2 / (var_m2 + np.where(ok, kv, 1.0)), 0.0)  # weight of the known value
    z = np.where(ok, (1.0 - w) * z_m + w * np.where(ok, kz, 0.0), z_m)
    v = np.where(ok, var_m2 * np.where(ok, kv, 1.0) / (var_m2 + np.where(ok, kv, 1.0)), var_m2)
    return z, v
