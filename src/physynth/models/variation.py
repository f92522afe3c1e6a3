"""Per-trace variation of the site: the anchor layout and the path (the scenario's ``variation`` section).

A calibrated scenario reproduces one site: one anchor layout and one path. A tracker trained only on
its traces learns that layout and that route, and is lost on a run that goes elsewhere
(docs/tracking.md, "Runs in other directions"). With a ``variation`` section, every trace draws from
its own stream (component ``site`` of :mod:`physynth.rng`, so a trace is the same in every process
and in any order):

- an anchor layout: one of ``layouts`` (the scenario's own when empty), its positions optionally
  shuffled between the anchor ids (``shuffle_anchors``), each anchor moved by N(0, ``layout_jitter_m``)
  per horizontal axis and N(0, ``layout_jitter_up_m``) vertically;
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
in this order, which :class:`physynth.track.synth.SynthVariation` (the tracking study's) shares.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Annotated, Any

import numpy as np
from pydantic import Field

from ..errors import ScenarioError
from ._params import NonNegFloat, ParamsModel, Probability, Vec3

RANDOM_ROUTE_TURN_STD_DEG = 70.0
"""Std of the turn between two legs of a random route [deg]."""
RANDOM_ROUTE_BACK_STD_DEG = 30.0
"""Std of the heading of a leg turned back towards the centre [deg]."""


class SiteVariationParams(ParamsModel):
    """Per-trace variation of anchor layout and path (module docstring). Metres, radians.

    ``layouts``: alternative anchor layouts, each one position [E, N, U] per anchor in the scenario's
    anchor order (e.g. the layouts of the runs a scenario was calibrated on); empty: the scenario's own.
    ``path_lateral_std_m`` / ``path_sag_std_m``: None (the default) keeps ``path.perturbation``, the
    run-to-run deformation a calibration fitted; the tracking study sets 1.0 / 0.1 m.
    ``nlos_log_std``: log-normal spread of each trace's NLOS probabilities (0: the scenario's in every trace).
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

    ``v`` holds the fields of :class:`SiteVariationParams` (or of the tracking study's
    ``SynthVariation``, whose layouts of another anchor count the caller has left out); ``base_pos_m``
    the scenario's anchor positions; ``path`` its ``PathParams`` as a mapping; ``path_points()`` (N, 3)
    points along its path [m], called only for a random route or without anchors.
    """
    base = np.asarray(base_pos_m, dtype=float).reshape(-1, 3)
    n_a = base.shape[0]
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
