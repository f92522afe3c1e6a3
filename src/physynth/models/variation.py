"""Per-trace variation of the site: the anchor layout and the path (the scenario's ``variation`` section).

A calibrated scenario reproduces one site: one anchor layout and one path. A tracker trained only on
its traces learns that layout and that route, and is lost on a run that goes elsewhere
(docs/tracking.md, "Runs in other directions"). With a ``variation`` section, every trace draws from
its own stream (component ``site`` of :mod:`physynth.rng`, so a trace is the same in every process
and in any order):

- an anchor layout: one of ``layouts`` (the scenario's own when empty), its positions optionally
  shuffled between the anchor ids (``shuffle_anchors``), each anchor moved by N(0, ``layout_jitter_m``)
  per horizontal axis and N(0, ``layout_jitter_up_m``) vertically;
  or, with a ``layout_distribution`` (:class:`LayoutDistribution`), a whole layout of its own instead
  (``layouts``, ``shuffle_anchors`` and the jitters then unused): :func:`draw_layout` draws the anchor
  count, the footprint, its aspect, whether the anchors share one height, their positions (redrawn until
  every two anchors are ``min_spacing_m`` apart), the layout's yaw and its offset from the scenario's
  anchor centroid; then every drawn anchor takes the channel and availability of an anchor of the
  scenario, drawn uniformly with replacement (the calibrated pool), and a new id ``L1`` .. ``Ln``
  (:func:`layout_anchors`), so that no id keeps the meaning it had in the training runs;
- the path: turned about the centre (the anchors' centroid; the path's without anchors) by
  N(0, ``path_yaw_std_rad``) and shifted by N(0, ``path_shift_std_m``) per horizontal axis; the
  run-to-run deformation ``path.perturbation`` is replaced by ``path_lateral_std_m`` /
  ``path_sag_std_m`` when they are set;
- with probability ``random_route_prob``, a route of another shape instead (:func:`random_route`): a
  smooth path through ``random_route_points`` waypoints of a random walk that starts near the centre and
  stays within the path's horizontal reach of it, at the path's mean height;
- with ``nlos_log_std`` > 0, how often the tag is out of line of sight: every anchor's ``nlos_prob`` and
  ``uwb.tag_nlos_prob`` times exp(N(0, ``nlos_log_std``)) (at most :data:`NLOS_PROB_MAX`), as one site
  has more obstacles than another; drawn last.

Everything else (motion, the rest of the channel, availability, IMU) is the scenario's. The draws happen
in this order (the tracking study's pre-training traces are such traces, :mod:`physynth.track.synth`):

1. the layout: either the choice among ``layouts``, the permutation (``shuffle_anchors``), the horizontal
   and the vertical jitter; or (``layout_distribution``) :func:`draw_layout`'s draws (rounds of
   :data:`LAYOUT_SHAPES` shapes with :data:`LAYOUT_PLACEMENTS` placements each, every round drawn whole:
   anchor counts, footprints, aspects, coplanar flags, shared heights; then the placements' height
   spreads, free heights and positions; after the accepted round the yaw, the offset's distance and its
   direction) and then the pool anchor of each drawn anchor;
2. the path's yaw and its shift;
3. the random route (only with ``random_route_prob`` > 0);
4. the NLOS factor (only with ``nlos_log_std`` > 0).

Without a ``layout_distribution`` the draws are exactly those before it existed, so every scenario and
dataset without one is unchanged.

A ``layout_distribution`` in YAML (the defaults)::

    variation:
      layout_distribution:
        anchor_count: [3, 6]      # anchors per layout (3..8), uniform
        footprint_m: [1.5, 10.0]  # long side of the anchors' horizontal bounding rectangle, uniform
        aspect: [0.1, 1.0]        # short side / long side, uniform
        height_m: [0.2, 3.0]      # anchor heights U in the scenario's frame
        coplanar_prob: 0.3        # share of layouts whose anchors all hang at one height ...
        coplanar_std_m: 0.05      # ... give or take this
        min_spacing_m: 0.5        # every two anchors at least this far apart (3-D)
        route_offset_m: [0.0, 2.0]  # layout centroid's horizontal distance from the scenario's anchor centroid
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Annotated, Any

import numpy as np
from pydantic import Field, model_validator

from ..errors import ScenarioError
from ._params import FiniteFloat, NonNegFloat, ParamsModel, Probability, Vec3

RANDOM_ROUTE_TURN_STD_DEG = 70.0
"""Std of the turn between two legs of a random route [deg]."""
RANDOM_ROUTE_BACK_STD_DEG = 30.0
"""Std of the heading of a leg turned back towards the centre [deg]."""
LAYOUT_SHAPES = 8
"""Layout shapes (anchor count, footprint, aspect, coplanar or not, shared height) :func:`draw_layout` draws
at once, one round of its rejection of crowded layouts."""
LAYOUT_PLACEMENTS = 16
"""Placements (positions and heights) drawn for each shape of a round: a shape is refused only when none of
them keeps ``min_spacing_m``, so that crowding redraws positions first and rarely changes the shape."""
LAYOUT_ROUNDS = 32
"""Rounds before :func:`draw_layout` gives up with a ScenarioError (256 shapes, 4096 placements)."""
LAYOUT_ID_PREFIX = "L"
"""Ids of the anchors of a drawn layout: ``L1`` .. ``Ln`` in the layout's anchor order."""

_Count = Annotated[int, Field(ge=3, le=8)]
_CountRange = Annotated[list[_Count], Field(min_length=2, max_length=2)]
_Range = Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]
_NonNegRange = Annotated[list[NonNegFloat], Field(min_length=2, max_length=2)]
_Aspect = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
_AspectRange = Annotated[list[_Aspect], Field(min_length=2, max_length=2)]


class LayoutDistribution(ParamsModel):
    """Whole anchor layouts, one drawn per trace (:func:`draw_layout`). Metres; every ``[min, max]`` is drawn
    uniformly; the physical ranges are in :data:`physynth.bounds.BOUNDS` (``variation.layout_distribution.*``).

    The defaults span the small outdoor and indoor deployments a tracker meets (a lab bay, a room, a yard),
    wider than any one site's runs (the Hanyang training layouts were 1.9-3 m x 1.7 m with two anchors at
    0.5 m; a held-out run had three at ~2 m and one at 0.5 m over 5 m x 1.7 m):

    - ``anchor_count`` [3, 6] (each 3..8): 3 is the fewest that fix a position, 6 more than most small
      deployments use; at most 8 (an 8-slot burst, the anchor study's largest cells).
    - ``footprint_m`` [1.5, 10]: the long side of the anchors' horizontal bounding rectangle, from anchors
      around a desk or a bay to a room or a yard.
    - ``aspect`` [0.1, 1] (each 0..1): short side / long side of that rectangle, from anchors along a corridor
      or one wall (0.1; 0 puts them on a line) to a square.
    - ``height_m`` [0.2, 3]: the anchors' heights U in the scenario's frame (absolute, like the scenario's
      anchors; not relative to the route), from a tripod's foot to a ceiling.
    - ``coplanar_prob`` 0.3, ``coplanar_std_m`` 0.05: the share of layouts whose anchors all hang at one height
      (drawn in ``height_m``) give or take N(0, ``coplanar_std_m``) (clipped to ``height_m``): a row of
      tripods or a ceiling, which leaves the vertical to the tag's motion, next to well-spread layouts,
      whose heights are drawn one by one in ``height_m``.
    - ``min_spacing_m`` 0.5: every two anchors at least this far apart in 3-D (nobody mounts two anchors
      closer; two so close add no geometry). A crowded layout's positions and heights are redrawn
      (:data:`LAYOUT_PLACEMENTS` at once); a shape (count, footprint, aspect, coplanar or not) none of whose
      placements keeps the spacing is redrawn whole, so shapes that can hardly meet it (many anchors at one
      height on a small narrow footprint) are rarer than their nominal share: with the defaults 0.8 % of
      shapes are redrawn and the coplanar share is 0.29 for 0.3. No layout in :data:`LAYOUT_ROUNDS` rounds
      is a ScenarioError (e.g. 8 anchors on 1.5 m with a 2 m spacing).
    - ``route_offset_m`` [0, 2]: the route stays where the scenario has it; the layout's centroid lies this far
      (horizontally, in a uniform direction) from the scenario's anchor centroid, so that the route crosses
      other parts of the layout or passes beside it. The layout is also turned by a uniform yaw.
    """

    anchor_count: _CountRange = [3, 6]
    footprint_m: _NonNegRange = [1.5, 10.0]
    aspect: _AspectRange = [0.1, 1.0]
    height_m: _Range = [0.2, 3.0]
    coplanar_prob: Probability = 0.3
    coplanar_std_m: NonNegFloat = 0.05
    min_spacing_m: NonNegFloat = 0.5
    route_offset_m: _NonNegRange = [0.0, 2.0]

    @model_validator(mode="after")
    def _check(self) -> LayoutDistribution:
        for name in ("anchor_count", "footprint_m", "aspect", "height_m", "route_offset_m"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name}: [min, max] with min <= max, got [{lo:g}, {hi:g}]")
        (_, l_hi), (_, a_hi), (h_lo, h_hi) = self.footprint_m, self.aspect, self.height_m
        room = float(np.sqrt(l_hi ** 2 + (a_hi * l_hi) ** 2 + (h_hi - h_lo) ** 2))
        if self.min_spacing_m > room:
            raise ValueError(f"min_spacing_m {self.min_spacing_m:g} m exceeds the largest distance two anchors can "
                             f"have ({room:.3g} m, the diagonal of the largest footprint and height range)")
        return self


def sample_layout(dist: LayoutDistribution, centre_enu_m: np.ndarray,
                  rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """One layout of ``dist`` and the record of its draw (:func:`draw_layout`, which returns the positions only).

    The record: ``anchor_count``, ``footprint_m`` (long side), ``aspect``, ``coplanar``, ``yaw_rad`` (the long
    side's direction, counter-clockwise from east), ``offset_m`` (E, N of the layout's centroid from
    ``centre_enu_m``) and ``shapes`` (how many shapes were drawn up to the accepted one: 1 unless crowded).
    """
    (n_lo, n_hi), (l_lo, l_hi), (a_lo, a_hi), (h_lo, h_hi) = (dist.anchor_count, dist.footprint_m, dist.aspect,
                                                              dist.height_m)
    k, p, m = LAYOUT_SHAPES, LAYOUT_PLACEMENTS, int(n_hi)
    others = ~np.eye(m, dtype=bool)
    for r in range(LAYOUT_ROUNDS):  # a round of k shapes x p placements is drawn whole, whichever is accepted
        n = rng.integers(n_lo, n_hi + 1, k)
        long_side = rng.uniform(l_lo, l_hi, k)
        aspect = rng.uniform(a_lo, a_hi, k)
        coplanar = rng.random(k) < dist.coplanar_prob
        level = rng.uniform(h_lo, h_hi, k)
        spread = rng.normal(0.0, dist.coplanar_std_m, (k, p, m))
        free = rng.uniform(h_lo, h_hi, (k, p, m))
        unit = rng.random((k, p, m, 2))
        valid = (np.arange(m) < n[:, None])[:, None, :, None]  # (k, 1, m, 1): the first n of a shape's m slots
        lo = np.where(valid, unit, np.inf).min(axis=2, keepdims=True)  # stretched onto the footprint rectangle
        span = np.where(valid, unit, -np.inf).max(axis=2, keepdims=True) - lo
        sides = np.stack([long_side, long_side * aspect], axis=1)[:, None, None, :]
        cand = np.empty((k, p, m, 3))
        cand[..., :2] = (unit - lo) / np.where(span > 0, span, 1.0) * sides
        cand[..., 2] = np.where(coplanar[:, None, None], np.clip(level[:, None, None] + spread, h_lo, h_hi), free)
        gap = np.linalg.norm(cand[:, :, :, None] - cand[:, :, None], axis=4)  # (k, p, m, m)
        pair = valid[..., 0][..., :, None] & valid[..., 0][..., None, :] & others
        ok = np.where(pair, gap, np.inf).min(axis=(2, 3)) >= dist.min_spacing_m  # (k, p)
        if ok.any():
            i = int(np.argmax(ok.any(axis=1)))  # the first shape that has a placement, and its first one
            q = int(np.argmax(ok[i]))
            tried = r * k + i + 1
            break
    else:
        raise ScenarioError(f"variation.layout_distribution: no layout of {n_lo}-{n_hi} anchors on a "
                            f"{l_lo:g}-{l_hi:g} m footprint (aspect {a_lo:g}-{a_hi:g}, heights {h_lo:g}-{h_hi:g} m) "
                            f"keeps every two anchors {dist.min_spacing_m:g} m apart ({LAYOUT_ROUNDS * k} shapes, "
                            f"{p} placements each): lower min_spacing_m or anchor_count, or widen footprint_m, "
                            "aspect or height_m")
    local = cand[i, q, :n[i]]
    yaw = float(rng.uniform(0.0, 2.0 * np.pi))
    reach = float(rng.uniform(*dist.route_offset_m))
    bearing = float(rng.uniform(0.0, 2.0 * np.pi))
    offset = reach * np.array([np.cos(bearing), np.sin(bearing)])
    c, s = np.cos(yaw), np.sin(yaw)
    pos = np.empty_like(local)
    pos[:, :2] = (local[:, :2] - local[:, :2].mean(axis=0)) @ np.array([[c, s], [-s, c]]) \
        + np.asarray(centre_enu_m, dtype=float)[:2] + offset
    pos[:, 2] = local[:, 2]
    record = {"anchor_count": int(n[i]), "footprint_m": float(long_side[i]), "aspect": float(aspect[i]),
              "coplanar": bool(coplanar[i]), "yaw_rad": yaw, "offset_m": [float(x) for x in offset],
              "shapes": tried}
    return pos, record


def draw_layout(dist: LayoutDistribution, centre_enu_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Anchor positions (A, 3) [m] of one layout of ``dist`` around ``centre_enu_m`` (its U unused: heights are
    ``dist.height_m``), drawn from ``rng`` only, vectorised over candidates, in this order: rounds of
    :data:`LAYOUT_SHAPES` shapes x :data:`LAYOUT_PLACEMENTS` placements until a placement keeps
    ``min_spacing_m`` (each round: anchor counts, long sides, aspects, coplanar flags, shared heights; the
    placements' height spreads, free heights, positions in the unit square stretched onto the footprint
    rectangle, so that the anchors' bounding rectangle is the footprint exactly); the first shape with such a
    placement, and its first one, is the layout; then the yaw, the offset's distance and its direction.

    Raises
    ------
    ScenarioError
        No placement in :data:`LAYOUT_ROUNDS` rounds keeps the spacing.
    """
    return sample_layout(dist, centre_enu_m, rng)[0]


def layout_anchor_ids(n: int) -> tuple[str, ...]:
    """The ids of the ``n`` anchors of a drawn layout (``L1`` .. ``Ln``)."""
    return tuple(f"{LAYOUT_ID_PREFIX}{j + 1}" for j in range(n))


def layout_anchors(scn: Any, pos_m: np.ndarray, drawn: dict[str, Any]) -> dict[str, Any]:
    """``model_copy`` updates of a :class:`~physynth.scenario.Scenario` whose anchors are a drawn layout.

    ``pos_m`` (A, 3) the layout, ``drawn`` its record (``draw_site``'s ``layout_drawn``: ``pool``, the index of
    the scenario's anchor each drawn anchor takes after, and ``yaw_rad``). Drawn anchor j gets the id
    ``L{j+1}``, no name, the pool anchor's ``channel_per_anchor`` and ``availability_per_anchor`` overrides
    (none where it has none: the scenario's defaults, as for the pool anchor) and its antenna
    (``front_back_db``; ``boresight_enu`` turned with the layout by ``yaw_rad``).
    """
    pool = [scn.anchors[int(i)] for i in drawn["pool"]]
    ids = layout_anchor_ids(len(pool))
    c, s = np.cos(drawn["yaw_rad"]), np.sin(drawn["yaw_rad"])

    def turned(b: list[float] | None) -> list[float] | None:
        return None if b is None else [float(c * b[0] - s * b[1]), float(s * b[0] + c * b[1]), float(b[2])]

    anchors = [a.model_copy(update={"id": aid, "name": None, "pos_enu_m": [float(x) for x in p],
                                    "boresight_enu": turned(a.boresight_enu)})
               for aid, a, p in zip(ids, pool, pos_m, strict=True)]  # a handful of anchors
    return {"anchors": anchors,
            "channel_per_anchor": {aid: scn.channel_per_anchor[a.id] for aid, a in zip(ids, pool, strict=True)
                                   if a.id in scn.channel_per_anchor},
            "availability_per_anchor": {aid: scn.availability_per_anchor[a.id]
                                        for aid, a in zip(ids, pool, strict=True)
                                        if a.id in scn.availability_per_anchor}}


class SiteVariationParams(ParamsModel):
    """Per-trace variation of anchor layout and path (module docstring). Metres, radians.

    ``layouts``: alternative anchor layouts, each one position [E, N, U] per anchor in the scenario's
    anchor order (e.g. the layouts of the runs a scenario was calibrated on); empty: the scenario's own.
    ``path_lateral_std_m`` / ``path_sag_std_m``: None (the default) keeps ``path.perturbation``, the
    run-to-run deformation a calibration fitted; the tracking study sets 1.0 / 0.1 m.
    ``nlos_log_std``: log-normal spread of each trace's NLOS probabilities (0: the scenario's in every trace).
    ``layout_distribution``: whole layouts drawn per trace (:class:`LayoutDistribution`) in place of
    ``layouts`` and the jitter; None (the default): the layouts above.
    """

    layouts: list[list[Vec3]] = []
    shuffle_anchors: bool = False
    layout_jitter_m: NonNegFloat = 0.3
    layout_jitter_up_m: NonNegFloat = 0.1
    path_yaw_std_rad: NonNegFloat = 0.05
    path_shift_std_m: NonNegFloat = 0.5
    path_lateral_std_m: NonNegFloat | None = None
    path_sag_std_m: NonNegFloat | None = None
    random_route_prob: Probability = 0.0
    random_route_points: Annotated[int, Field(ge=2)] = 8
    nlos_log_std: NonNegFloat = 0.0
    layout_distribution: LayoutDistribution | None = None


def random_route(centre_enu_m: np.ndarray, reach_m: float, height_m: float, n_points: int,
                 rng: np.random.Generator) -> list[list[float]]:
    """Waypoints [m] of a random route around ``centre_enu_m``: a random walk of ``n_points`` points.

    It starts within 3 m of the centre; every leg is 0.2-0.5 x ``reach_m`` long and turns by
    N(0, 70 deg) from the last one (its first heading uniform); a leg that would leave the disc of
    radius ``reach_m`` is turned back towards the centre. All points at ``height_m``.
    """
    pts = [centre_enu_m[:2] + rng.uniform(-3.0, 3.0, 2)]
    heading = rng.uniform(0.0, 2.0 * np.pi)
    for _ in range(n_points - 1):  # a handful of legs
        heading += rng.normal(0.0, np.radians(RANDOM_ROUTE_TURN_STD_DEG))
        step = rng.uniform(0.2, 0.5) * reach_m
        nxt = pts[-1] + step * np.array([np.cos(heading), np.sin(heading)])
        if np.linalg.norm(nxt - centre_enu_m[:2]) > reach_m:  # turn back towards the centre
            back = centre_enu_m[:2] - pts[-1]
            heading = float(np.arctan2(back[1], back[0]) + rng.normal(0.0, np.radians(RANDOM_ROUTE_BACK_STD_DEG)))
            nxt = pts[-1] + step * np.array([np.cos(heading), np.sin(heading)])
        pts.append(nxt)
    return [[float(p[0]), float(p[1]), float(height_m)] for p in pts]


def rotated_path(path: dict[str, Any], yaw_rad: float, shift_m: np.ndarray, centre: np.ndarray) -> dict[str, Any]:
    """A path mapping (``PathParams`` dumped) turned by ``yaw_rad`` about ``centre`` and shifted by
    ``shift_m`` (E, N) [m]: waypoints moved, or the polynomial's E/N coefficients transformed."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    rot = np.array([[c, -s], [s, c]])
    if path["kind"] == "waypoints":
        w = np.asarray(path["waypoints_enu_m"], dtype=float)
        w[:, :2] = (w[:, :2] - centre[:2]) @ rot.T + centre[:2] + shift_m
        return {**path, "waypoints_enu_m": w.tolist()}
    coeffs = [list(map(float, c_)) for c_ in path["coeffs_enu_m"]]
    n = max(len(coeffs[0]), len(coeffs[1]))
    en = np.zeros((2, n))
    for k in range(2):
        en[k, :len(coeffs[k])] = coeffs[k]
    en[:, 0] -= centre[:2]
    en = rot @ en
    en[:, 0] += centre[:2] + shift_m
    return {**path, "coeffs_enu_m": [en[0].tolist(), en[1].tolist(), coeffs[2]]}


def draw_site(v: Any, base_pos_m: np.ndarray, path: dict[str, Any], path_points: Callable[[], np.ndarray],
              rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any], dict[str, Any]]:
    """One draw of the site: (anchor positions (A, 3) [m], path mapping, record of what was drawn).

    ``v`` holds the fields of :class:`SiteVariationParams`; ``base_pos_m``
    the scenario's anchor positions; ``path`` its ``PathParams`` as a mapping; ``path_points()`` (N, 3)
    points along its path [m], called only for a random route or without anchors.

    With ``v.layout_distribution``, the positions are a drawn layout (:func:`sample_layout`, possibly of
    another anchor count), the record's ``layout`` is None and its ``layout_drawn`` holds that draw's record
    plus ``pool``: for each drawn anchor the index of the scenario's anchor whose channel it takes
    (uniform, with replacement; :func:`layout_anchors` builds the anchors).

    Raises
    ------
    ScenarioError
        A layout distribution on a scenario without anchors (no channel to give the drawn anchors), or one
        whose spacing no placement keeps (:func:`draw_layout`).
    """
    base = np.asarray(base_pos_m, dtype=float).reshape(-1, 3)
    n_a = base.shape[0]
    dist = getattr(v, "layout_distribution", None)
    drawn = None
    if dist is not None:  # a whole layout, then the pool anchor of each of its anchors
        if n_a == 0:
            raise ScenarioError("variation.layout_distribution needs a scenario with anchors: each drawn anchor "
                                "takes the channel of one of them")
        pos, drawn = sample_layout(dist, base.mean(axis=0), rng)
        drawn["pool"] = [int(i) for i in rng.integers(n_a, size=pos.shape[0])]
        k = None
    else:
        pool = [np.asarray(lay, dtype=float) for lay in v.layouts if len(lay) == n_a] or [base]
        k = int(rng.integers(len(pool)))
        pos = pool[k].copy()
        if v.shuffle_anchors:
            pos = pos[rng.permutation(n_a)]
        pos[:, :2] += rng.normal(0.0, v.layout_jitter_m, (n_a, 2))
        pos[:, 2] += rng.normal(0.0, v.layout_jitter_up_m, n_a)
    centre = base.mean(axis=0) if n_a else np.asarray(path_points(), dtype=float).mean(axis=0)
    yaw = float(rng.normal(0.0, v.path_yaw_std_rad))
    shift = rng.normal(0.0, v.path_shift_std_m, 2)
    out = rotated_path(path, yaw, shift, centre)
    pert = dict(out["perturbation"])
    if v.path_lateral_std_m is not None:
        pert["lateral_std_m"] = v.path_lateral_std_m
    if v.path_sag_std_m is not None:
        pert["sag_std_m"] = v.path_sag_std_m
    out = {**out, "perturbation": pert}
    route = False
    if v.random_route_prob > 0 and rng.random() < v.random_route_prob:  # drawn last
        pts = np.asarray(path_points(), dtype=float)
        reach = max(float(np.max(np.linalg.norm(pts[:, :2] - centre[:2], axis=1))), 5.0)
        waypoints = random_route(centre, reach, float(pts[:, 2].mean()), v.random_route_points, rng)
        out = {"kind": "waypoints", "waypoints_enu_m": waypoints, "perturbation": pert}
        route = True
    record = {"layout": k, "yaw_rad": yaw, "shift_m": [float(x) for x in shift], "random_route": route}
    if drawn is not None:
        record["layout_drawn"] = drawn
    if v.nlos_log_std > 0:  # drawn after everything else: without it the draws are as before
        record["nlos_scale"] = float(np.exp(rng.normal(0.0, v.nlos_log_std)))
    return pos, out, record


NLOS_PROB_MAX = 0.9
"""Upper limit of a scaled NLOS probability (a site where the tag is never in line of sight is another site)."""


def nlos_scaled(scn: Any, factor: float) -> dict[str, Any]:
    """``model_copy`` updates of a :class:`~physynth.scenario.Scenario` whose NLOS is ``factor`` times as
    frequent: every channel's ``nlos_prob`` and the tag-side ``uwb.tag_nlos_prob`` scaled (at most
    :data:`NLOS_PROB_MAX`); the modes, their dwell and every LOS parameter unchanged."""
    def scaled(p: float | None) -> float | None:  # None: an anchor that inherits the scenario's channel
        return p if p is None or p >= NLOS_PROB_MAX else float(min(p * factor, NLOS_PROB_MAX))

    return {"channel": scn.channel.model_copy(update={"nlos_prob": scaled(scn.channel.nlos_prob)}),
            "channel_per_anchor": {a: c.model_copy(update={"nlos_prob": scaled(c.nlos_prob)})
                                   for a, c in scn.channel_per_anchor.items()},
            "uwb": scn.uwb.model_copy(update={"tag_nlos_prob": scaled(scn.uwb.tag_nlos_prob)})}


def max_route_length_m(v: SiteVariationParams, path_points: np.ndarray, centre: np.ndarray) -> float:
    """Upper bound of a random route's length [m] (``random_route_points - 1`` legs of at most half the
    reach each): for the size estimate of a generation."""
    reach = max(float(np.max(np.linalg.norm(path_points[:, :2] - centre[:2], axis=1))), 5.0)
    return (v.random_route_points - 1) * 0.5 * reach


def recorded_layouts(provenance: dict[str, Any], anchor_ids: Sequence[str]) -> list[list[list[float]]]:
    """The anchor layouts a calibration on several runs recorded (``provenance.anchor_layout.layouts``:
    run label -> anchor id -> [E, N, U]) that place exactly ``anchor_ids``, each in that order; [] when
    none is recorded. They are the natural ``layouts`` of a site whose anchors were re-placed between runs."""
    what = "provenance.anchor_layout.layouts must map run labels to {anchor id: [E, N, U]}"
    section = (provenance or {}).get("anchor_layout") or {}
    if not isinstance(section, dict):
        raise ScenarioError(f"provenance.anchor_layout must be a mapping, not {type(section).__name__}")
    layouts = section.get("layouts") or {}
    if not isinstance(layouts, dict) or not all(isinstance(lay, dict) for lay in layouts.values()):
        raise ScenarioError(what)
    out = []
    for label, lay in layouts.items():  # a handful of recorded runs
        for aid, pos in lay.items():
            v = np.asarray(pos, dtype=object)
            if v.shape != (3,) or not all(isinstance(x, (int, float)) and np.isfinite(x) for x in v):
                raise ScenarioError(f"{what}: run {label!r}, anchor {aid!r} has {pos!r}")
        if set(lay) == set(anchor_ids) and len(lay) == len(anchor_ids):
            out.append([[float(x) for x in lay[a]] for a in anchor_ids])
    return out
