"""Geometric dilution of precision of range-only positioning along a path.

With unit vectors u_i from anchor i to the tag as the rows of H (only the anchors that count at that
instant), a least-squares position fix from ranges of standard deviation sigma has covariance
sigma^2 (H^T H)^-1, so GDOP = sqrt(trace((H^T H)^-1)) is the position error per metre of range error.
Fewer than three anchors, or anchors that see the tag along nearly one line or plane, leave H^T H
singular: GDOP is then infinite (no 3-D fix).

HDOP is the same with the tag height known (a walker, a vehicle, a cable car on its cable): H keeps the
horizontal (E, N) components of the unit vectors, and two anchors that are not in line with the tag
suffice.
"""

from __future__ import annotations

import numpy as np

from ..evaluate.grid import age_of_information, grid_times
from ..records import Trace

GDOP_CAP = 1e3
"""GDOP above this is reported as infinite (a near-singular geometry: no usable fix)."""

FRESH_AOI_S = 1.0
"""An anchor counts for the *fresh* GDOP while its newest valid range is at most this old [s]."""

DOP_RATE_HZ = 10.0
"""Rate of the points along the path at which GDOP is evaluated [Hz]."""


def gdop(tag_enu_m: np.ndarray, anchor_enu_m: np.ndarray, mask: np.ndarray | None = None, *,
         known_height: bool = False) -> np.ndarray:
    """(K,) GDOP at tag positions (K, 3) [m] with anchors (A, 3) [m]; ``mask`` (K, A) selects anchors.

    ``known_height``: the HDOP of a fix with the tag height known (E, N only). Infinite where fewer
    than three (two for HDOP) anchors count or the geometry is (near) singular.
    """
    d = tag_enu_m[:, None, :] - anchor_enu_m[None, :, :]
    u = d / np.maximum(np.linalg.norm(d, axis=2, keepdims=True), 1e-9)
    if known_height:
        u = u[..., :2]
    if mask is not None:
        u = u * mask[..., None]
    m = np.einsum("kai,kaj->kij", u, u)
    out = np.full(tag_enu_m.shape[0], np.inf)
    n = (mask.sum(axis=1) if mask is not None else np.full(tag_enu_m.shape[0], anchor_enu_m.shape[0]))
    ok = n >= (2 if known_height else 3)
    if np.any(ok):
        eig = np.linalg.eigvalsh(m[ok])
        with np.errstate(divide="ignore"):
            g = np.sqrt(np.sum(1.0 / np.maximum(eig, 0.0), axis=1))
        out[ok] = np.where(g <= GDOP_CAP, g, np.inf)
    return out


def trace_gdop(trace: Trace, rate_hz: float = DOP_RATE_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(geometric GDOP, fresh GDOP, fresh HDOP) along one trace at ``rate_hz``: with every anchor of the
    trace, and with the anchors whose newest valid range is at most :data:`FRESH_AOI_S` old."""
    t = grid_times(trace.t0_s, trace.duration_s, rate_hz)
    pos = trace.truth.position_at(t)
    anchors = trace.anchors.pos_enu_m
    fresh = age_of_information(trace, t) <= FRESH_AOI_S
    return gdop(pos, anchors), gdop(pos, anchors, fresh), gdop(pos, anchors, fresh, known_height=True)


def summarize_gdop(values: np.ndarray, prefix: str) -> dict[str, float]:
    """Median, P95 (infinite values count; inf when more than half / 5 % are infinite) and the fraction
    of points with GDOP <= 5 (a usable fix)."""
    if values.size == 0:
        return {f"{prefix}_median": float("nan"), f"{prefix}_p95": float("nan"), f"{prefix}_le5_frac": float("nan")}
    v = np.sort(values)
    return {
        f"{prefix}_median": float(v[int(np.floor(0.5 * (v.size - 1)))]),
        f"{prefix}_p95": float(v[int(np.floor(0.95 * (v.size - 1)))]),
        f"{prefix}_le5_frac": float(np.mean(v <= 5.0)),
    }
