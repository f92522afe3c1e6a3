"""The tag antenna pattern: a range bias against the anchor's bearing from the walker's heading."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .sway import TURN_MIN_SPEED_MPS


def heading_unit(vel_enu_mps: np.ndarray) -> np.ndarray:
    """Unit vectors (T, 2) (east, north) of the direction of horizontal travel of velocities
    ``vel_enu_mps`` (T, 3): where the horizontal speed is below :data:`TURN_MIN_SPEED_MPS` (or NaN) the
    last heading is held, before the first such sample the first heading is taken; a carrier that never
    moves faces east."""
    v = np.nan_to_num(vel_enu_mps[:, :2])
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed >= TURN_MIN_SPEED_MPS
    if not moving.any():
        return np.tile([1.0, 0.0], (v.shape[0], 1))
    idx = np.where(moving, np.arange(v.shape[0]), 0)
    np.maximum.accumulate(idx, out=idx)  # the last moving sample at or before each one
    idx[: int(np.argmax(moving))] = int(np.argmax(moving))
    return v[idx] / speed[idx, None]


def relative_bearing(d_east: np.ndarray, d_north: np.ndarray, head_east: np.ndarray, head_north: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(cos phi, sin phi) of the bearing phi of the horizontal vectors (``d_east``, ``d_north``) (tag to
    anchor) relative to the headings (``head_east``, ``head_north``) (unit vectors): 0 ahead, pi/2 to the
    left. A zero vector (the anchor straight above the tag) counts as ahead."""
    norm = np.hypot(d_east, d_north)
    safe = np.where(norm > 0, norm, 1.0)
    cos_phi = np.where(norm > 0, (d_east * head_east + d_north * head_north) / safe, 1.0)
    sin_phi = np.where(norm > 0, (head_east * d_north - head_north * d_east) / safe, 0.0)
    return cos_phi, sin_phi


def pattern_features(cos_phi: np.ndarray, sin_phi: np.ndarray) -> np.ndarray:
    """(N, 4) [cos phi, sin phi, cos 2 phi, sin 2 phi], the terms of ``UwbParams.tag_pattern_m``."""
    return np.stack([cos_phi, sin_phi, 2.0 * cos_phi * cos_phi - 1.0, 2.0 * sin_phi * cos_phi], axis=1)


def tag_pattern_bias(tag_e: np.ndarray, tag_n: np.ndarray, anchor_e: np.ndarray, anchor_n: np.ndarray,
                     head: np.ndarray, coef: Sequence[float]) -> np.ndarray:
    """Range bias [m] of the tag antenna pattern ``coef`` (``UwbParams.tag_pattern_m``) for tags at
    (``tag_e``, ``tag_n``) ranging anchors at (``anchor_e``, ``anchor_n``) with headings ``head`` (N, 2)."""
    cos_phi, sin_phi = relative_bearing(anchor_e - tag_e, anchor_n - tag_n, head[:, 0], head[:, 1])
    return pattern_features(cos_phi, sin_phi) @ np.asarray(coef, dtype=float)


def heading_at(t_s: np.ndarray, grid_t_s: np.ndarray, vel_enu_mps: np.ndarray) -> np.ndarray:
    """Headings (N, 2) at the times ``t_s``: :func:`heading_unit` of the velocities on ``grid_t_s``,
    interpolated component-wise and renormalised."""
    h = heading_unit(vel_enu_mps)
    he, hn = np.interp(t_s, grid_t_s, h[:, 0]), np.interp(t_s, grid_t_s, h[:, 1])
    norm = np.hypot(he, hn)
    bad = norm < 1e-9  # a reversal between two grid samples: take the earlier heading
    if bad.any():
        k = np.clip(np.searchsorted(grid_t_s, t_s[bad], side="right") - 1, 0, grid_t_s.size - 1)
        he[bad], hn[bad], norm[bad] = h[k, 0], h[k, 1], 1.0
    return np.stack([he / norm, hn / norm], axis=1)
