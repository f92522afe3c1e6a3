"""Obstacles that block the line of sight between the tag and an anchor: boxes, walls, prisms, terrain.

An attempt is *geometrically NLOS* when the straight segment from the tag position p(t) to the anchor
antenna a_i meets an obstacle. The tests are exact for the polyhedral obstacles and vectorised over
rows (one attempt each); the only Python loops run over obstacles and over the faces of one obstacle.

- ``box``: an axis-aligned box [min_enu_m, max_enu_m] (slab test).
- ``wall``: a vertical polyline wall on the ground plan (``vertices_en_m``, at least two points) from
  ``base_m`` to ``top_m`` up [m]; every edge is a vertical rectangle.
- ``prism``: a closed polygon footprint (``vertices_en_m``, at least three points) extruded from
  ``base_m`` to ``top_m`` (a building); blocked when the segment crosses a side, the roof or the floor,
  or when an end lies inside.
- terrain (:class:`TerrainGrid`): a height grid; blocked when the terrain rises above the segment at
  any of the sample points placed every half grid step along it (bilinear heights).

Every obstacle carries ``loss_db``, the extra attenuation it adds to the link budget
(:class:`physynth.models.uwb.LinkBudgetParams`) of a blocked attempt, summed over the obstacles met.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from ._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat, Vec3

Vec2 = Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]

_EPS = 1e-12


class BoxObstacle(ParamsModel):
    """An axis-aligned box in ENU [m] (a container, a cabin, a rock)."""

    kind: Literal["box"] = "box"
    min_enu_m: Vec3
    max_enu_m: Vec3
    loss_db: NonNegFloat = 10.0
    label: str = "box"

    @model_validator(mode="after")
    def _ordered(self) -> BoxObstacle:
        if any(lo >= hi for lo, hi in zip(self.min_enu_m, self.max_enu_m, strict=True)):
            raise ValueError("box min_enu_m must be below max_enu_m on every axis")
        return self


class _Extruded(ParamsModel):
    """A footprint on the ground plan (E, N) [m] standing from ``base_m`` to ``top_m`` up [m]: what a wall
    and a prism share (each sets its kind, its least number of vertices, its loss and its label)."""

    kind: str
    vertices_en_m: list[Vec2]
    base_m: FiniteFloat = 0.0
    top_m: FiniteFloat
    loss_db: NonNegFloat
    label: str

    @model_validator(mode="after")
    def _heights(self) -> _Extruded:
        if self.top_m <= self.base_m:
            raise ValueError(f"{self.kind} top_m must be above base_m")
        return self


class WallObstacle(_Extruded):
    """A vertical wall along a polyline of the ground plan (E, N) [m], from ``base_m`` to ``top_m`` up [m]."""

    kind: Literal["wall"] = "wall"
    vertices_en_m: list[Vec2] = Field(min_length=2)
    loss_db: NonNegFloat = 10.0
    label: str = "wall"


class PrismObstacle(_Extruded):
    """A closed polygon footprint (E, N) [m] extruded from ``base_m`` to ``top_m`` (a building)."""

    kind: Literal["prism"] = "prism"
    vertices_en_m: list[Vec2] = Field(min_length=3)
    loss_db: NonNegFloat = 20.0
    label: str = "building"


Obstacle = Annotated[BoxObstacle | WallObstacle | PrismObstacle, Field(discriminator="kind")]


class TerrainGrid(ParamsModel):
    """Terrain heights U [m] on a regular grid: ``heights_m[j][k]`` at E = e0 + k*spacing, N = n0 + j*spacing.

    Outside the grid the terrain is taken as absent (no blocking).
    """

    origin_en_m: Vec2
    spacing_m: PositiveFloat
    heights_m: list[list[FiniteFloat]] = Field(min_length=2)
    loss_db: NonNegFloat = 30.0

    @model_validator(mode="after")
    def _rectangular(self) -> TerrainGrid:
        widths = {len(row) for row in self.heights_m}
        if len(widths) != 1 or widths.pop() < 2:
            raise ValueError("terrain heights_m must be a rectangular grid of at least 2 x 2 values")
        return self


# ---------------------------------------------------------------- vectorised segment tests
def segment_hits_box(p: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) bool: segment p->q (rows of (N, 3)) meets the closed box [lo, hi] (slab test)."""
    d = q - p
    t0 = np.zeros(p.shape[0])
    t1 = np.ones(p.shape[0])
    for k in range(3):
        dk = d[:, k]
        par = np.abs(dk) < _EPS
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (lo[k] - p[:, k]) / dk
            b = (hi[k] - p[:, k]) / dk
        near = np.where(par, -np.inf, np.minimum(a, b))
        far = np.where(par, np.inf, np.maximum(a, b))
        outside = par & ((p[:, k] < lo[k]) | (p[:, k] > hi[k]))
        t0 = np.maximum(t0, near)
        t1 = np.where(outside, -1.0, np.minimum(t1, far))
    return t0 <= t1


def segment_hits_vertical_rect(p: np.ndarray, q: np.ndarray, e0: np.ndarray, e1: np.ndarray,
                               base_m: float, top_m: float) -> np.ndarray:
    """(N,) bool: segment p->q meets the vertical rectangle above the ground segment e0->e1 (E, N) [m]
    between heights ``base_m`` and ``top_m``."""
    d = q[:, :2] - p[:, :2]
    w = e1 - e0
    den = d[:, 0] * w[1] - d[:, 1] * w[0]  # 2-D cross product
    rel = e0 - p[:, :2]
    ok = np.abs(den) > _EPS
    den_safe = np.where(ok, den, 1.0)
    t = (rel[:, 0] * w[1] - rel[:, 1] * w[0]) / den_safe  # along the LOS segment
    u = (rel[:, 0] * d[:, 1] - rel[:, 1] * d[:, 0]) / den_safe  # along the wall
    z = p[:, 2] + t * (q[:, 2] - p[:, 2])
    return ok & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1) & (z >= base_m) & (z <= top_m)


def points_in_polygon(x: np.ndarray, y: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: points (x, y) inside the polygon (V, 2) (even-odd ray casting, vectorised over points)."""
    inside = np.zeros(x.shape[0], dtype=bool)
    v = poly.shape[0]
    for j in range(v):
        (xa, ya), (xb, yb) = poly[j], poly[(j + 1) % v]
        crosses = (ya > y) != (yb > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = xa + (y - ya) * (xb - xa) / (yb - ya)
        inside ^= crosses & (x < xc)
    return inside


def segment_hits_prism(p: np.ndarray, q: np.ndarray, poly: np.ndarray, base_m: float, top_m: float) -> np.ndarray:
    """(N,) bool: segment p->q meets the prism of footprint ``poly`` (V, 2) between ``base_m`` and ``top_m``."""
    v = poly.shape[0]
    hit = np.zeros(p.shape[0], dtype=bool)
    for j in range(v):
        hit |= segment_hits_vertical_rect(p, q, poly[j], poly[(j + 1) % v], base_m, top_m)
    for end in (p, q):
        hit |= (end[:, 2] >= base_m) & (end[:, 2] <= top_m) & points_in_polygon(end[:, 0], end[:, 1], poly)
    dz = q[:, 2] - p[:, 2]
    for h in (base_m, top_m):  # roof and floor
        ok = np.abs(dz) > _EPS
        t = np.where(ok, (h - p[:, 2]) / np.where(ok, dz, 1.0), -1.0)
        x = p[:, 0] + t * (q[:, 0] - p[:, 0])
        y = p[:, 1] + t * (q[:, 1] - p[:, 1])
        hit |= ok & (t >= 0) & (t <= 1) & points_in_polygon(x, y, poly)
    return hit


def terrain_height(terrain: TerrainGrid, e_m: np.ndarray, n_m: np.ndarray) -> np.ndarray:
    """Bilinear terrain height U [m] at (E, N) points; NaN outside the grid."""
    h = np.asarray(terrain.heights_m, dtype=float)
    fx = (e_m - terrain.origin_en_m[0]) / terrain.spacing_m
    fy = (n_m - terrain.origin_en_m[1]) / terrain.spacing_m
    inside = (fx >= 0) & (fy >= 0) & (fx <= h.shape[1] - 1) & (fy <= h.shape[0] - 1)
    k = np.clip(np.floor(fx).astype(np.int64), 0, h.shape[1] - 2)
    j = np.clip(np.floor(fy).astype(np.int64), 0, h.shape[0] - 2)
    ax = np.clip(fx - k, 0.0, 1.0)
    ay = np.clip(fy - j, 0.0, 1.0)
    z = ((1 - ax) * (1 - ay) * h[j, k] + ax * (1 - ay) * h[j, k + 1]
         + (1 - ax) * ay * h[j + 1, k] + ax * ay * h[j + 1, k + 1])
    return np.where(inside, z, np.nan)


def segment_below_terrain(p: np.ndarray, q: np.ndarray, terrain: TerrainGrid, *,
                          max_samples: int = 256, chunk_rows: int = 4096) -> np.ndarray:
    """(N,) bool: the terrain rises above segment p->q at some interior sample point.

    Samples sit every half grid step along the horizontal projection (at most ``max_samples``),
    end points excluded (an antenna standing on the ground is not blocked by it).
    """
    out = np.zeros(p.shape[0], dtype=bool)
    if p.shape[0] == 0:
        return out
    horiz = np.hypot(q[:, 0] - p[:, 0], q[:, 1] - p[:, 1])
    k = int(np.clip(np.ceil(horiz.max() / (0.5 * terrain.spacing_m)), 2, max_samples))
    s = (np.arange(1, k) / k)[None, :]  # interior samples
    for a in range(0, p.shape[0], chunk_rows):  # bounded memory: chunk_rows x k values at a time
        pp, qq = p[a:a + chunk_rows], q[a:a + chunk_rows]
        pts = pp[:, None, :] + s[..., None] * (qq - pp)[:, None, :]
        ground = terrain_height(terrain, pts[..., 0], pts[..., 1])
        out[a:a + chunk_rows] = np.any(ground > pts[..., 2], axis=1)
    return out


def obstacle_bounds(ob: BoxObstacle | WallObstacle | PrismObstacle) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (lo (3,), hi (3,)) of an obstacle [m]."""
    if isinstance(ob, BoxObstacle):
        return np.asarray(ob.min_enu_m, dtype=float), np.asarray(ob.max_enu_m, dtype=float)
    v = np.asarray(ob.vertices_en_m, dtype=float)
    return (np.array([v[:, 0].min(), v[:, 1].min(), ob.base_m]),
            np.array([v[:, 0].max(), v[:, 1].max(), ob.top_m]))


def obstacle_losses(tag_enu_m: np.ndarray, anchor_enu_m: np.ndarray, obstacles: Sequence[BoxObstacle | WallObstacle
                                                                                        | PrismObstacle],
                    terrain: TerrainGrid | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Line-of-sight test of every row: segment tag (N, 3) -> anchor (N, 3) [m] against the obstacles.

    Returns (blocked (N,) bool, loss_db (N,) summed ``loss_db`` of the obstacles met).
    """
    n = tag_enu_m.shape[0]
    blocked = np.zeros(n, dtype=bool)
    loss = np.zeros(n)
    seg_lo = np.minimum(tag_enu_m, anchor_enu_m)
    seg_hi = np.maximum(tag_enu_m, anchor_enu_m)
    for ob in obstacles:
        box_lo, box_hi = obstacle_bounds(ob)
        # only rows whose segment's bounding box meets the obstacle's can hit it (an exact pre-filter)
        rows = np.flatnonzero(np.all(seg_hi >= box_lo, axis=1) & np.all(seg_lo <= box_hi, axis=1))
        if rows.size == 0:
            continue
        p, q = tag_enu_m[rows], anchor_enu_m[rows]
        if isinstance(ob, BoxObstacle):
            hit = segment_hits_box(p, q, box_lo, box_hi)
        elif isinstance(ob, WallObstacle):
            v = np.asarray(ob.vertices_en_m, dtype=float)
            hit = np.zeros(rows.size, dtype=bool)
            for j in range(v.shape[0] - 1):
                hit |= segment_hits_vertical_rect(p, q, v[j], v[j + 1], ob.base_m, ob.top_m)
        else:
            hit = segment_hits_prism(p, q, np.asarray(ob.vertices_en_m, dtype=float), ob.base_m, ob.top_m)
        blocked[rows[hit]] = True
        loss[rows[hit]] += ob.loss_db
    if terrain is not None:
        hit = segment_below_terrain(tag_enu_m, anchor_enu_m, terrain)
        blocked |= hit
        loss += np.where(hit, terrain.loss_db, 0.0)
    return blocked, loss
