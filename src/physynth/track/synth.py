"""Synthetic training traces that vary the path and the anchor layout around a calibrated site.

A calibrated scenario reproduces one site; a network pre-trained only on it learns that one layout.
:class:`SynthVariation` draws, per trace and from the trace's own stream
(``SeedSequence(root_seed, spawn_key=(i, VARIATION_COMPONENT))``):

- an anchor layout: one of ``layouts`` (e.g. the layouts of the training runs; the scenario's own
  when empty), its positions optionally shuffled between the anchor ids (``shuffle_anchors``), each
  anchor moved by N(0, ``layout_jitter_m``) horizontally and N(0, ``layout_jitter_up_m``) vertically;
- the path: rotated about the anchor centroid by N(0, ``path_yaw_std_rad``) and shifted horizontally by
  N(0, ``path_shift_std_m``) per axis; the run-to-run deformation (``path.perturbation``) is replaced by
  ``path_lateral_std_m`` / ``path_sag_std_m`` when given;
- with probability ``random_route_prob``, a route of another shape instead of the scenario's path
  (:func:`random_route`): a smooth path through ``random_route_points`` waypoints of a random walk that
  starts near the anchors and stays within the scenario path's horizontal reach of them, at the path's
  mean height. A network then sees routes the training runs never took (loops, turns, other headings).

Everything else (motion, channel, availability, IMU) is the scenario's, drawn by the generator from the
usual per-component streams, so a trace is identical in every process and DataLoader worker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..generate import CompiledScenario, generate_trace
from ..records import Trace
from ..scenario import Scenario

VARIATION_COMPONENT = 100
"""spawn_key component of the variation draws (the generator uses 0-4)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SynthVariation:
    """Per-trace variation of anchor layout and path (see the module docstring). Metres, radians."""

    layouts: tuple[tuple[tuple[float, float, float], ...], ...] = ()
    shuffle_anchors: bool = False
    layout_jitter_m: float = 0.3
    layout_jitter_up_m: float = 0.1
    path_yaw_std_rad: float = 0.05
    path_shift_std_m: float = 0.5
    path_lateral_std_m: float | None = 1.0
    path_sag_std_m: float | None = 0.1
    random_route_prob: float = 0.0
    random_route_points: int = 8

    def __post_init__(self) -> None:
        stds = (self.layout_jitter_m, self.layout_jitter_up_m, self.path_yaw_std_rad, self.path_shift_std_m)
        if min(stds) < 0 or min(self.path_lateral_std_m or 0.0, self.path_sag_std_m or 0.0) < 0:
            raise ValueError(f"invalid SynthVariation (negative spread): {self!r}")
        if not 0.0 <= self.random_route_prob <= 1.0 or self.random_route_points < 2:
            raise ValueError(f"invalid SynthVariation (random_route_prob in [0, 1], random_route_points >= 2): "
                             f"{self!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"layouts": [list(map(list, lay)) for lay in self.layouts], "shuffle_anchors": self.shuffle_anchors,
                "layout_jitter_m": self.layout_jitter_m, "layout_jitter_up_m": self.layout_jitter_up_m,
                "path_yaw_std_rad": self.path_yaw_std_rad, "path_shift_std_m": self.path_shift_std_m,
                "path_lateral_std_m": self.path_lateral_std_m, "path_sag_std_m": self.path_sag_std_m,
                "random_route_prob": self.random_route_prob, "random_route_points": self.random_route_points}


def _rotated_path(path: dict[str, Any], yaw_rad: float, shift_m: np.ndarray, centre: np.ndarray) -> dict[str, Any]:
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


def _path_points(scn: Scenario, n: int = 200) -> np.ndarray:
    """(n, 3) points along the scenario's path [m]."""
    from ..models.path import compile_path

    geo = compile_path(scn.path)
    return np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, n))[0], dtype=float)


def random_route(centre_enu_m: np.ndarray, reach_m: float, height_m: float, n_points: int,
                 rng: np.random.Generator) -> list[list[float]]:
    """Waypoints [m] of a random route around ``centre_enu_m``: a random walk of ``n_points`` points.

    It starts within 3 m of the centre; every leg is 0.2-0.5 x ``reach_m`` long and turns by
    N(0, 70 deg) from the last one (its first heading uniform); a leg that would leave the disc of
    radius ``reach_m`` is turned back towards the centre. All points at ``height_m``.
    """
    pts = [centre_enu_m[:2] + rng.uniform(-3.0, 3.0, 2)]
    heading = rng.uniform(0.0, 2.0 * np.pi)
    for _ in range(n_points - 1):
        heading += rng.normal(0.0, np.radians(70.0))
        step = rng.uniform(0.2, 0.5) * reach_m
        nxt = pts[-1] + step * np.array([np.cos(heading), np.sin(heading)])
        if np.linalg.norm(nxt - centre_enu_m[:2]) > reach_m:  # turn back towards the centre
            back = centre_enu_m[:2] - pts[-1]
            heading = float(np.arctan2(back[1], back[0]) + rng.normal(0.0, np.radians(30.0)))
            nxt = pts[-1] + step * np.array([np.cos(heading), np.sin(heading)])
        pts.append(nxt)
    return [[float(p[0]), float(p[1]), float(height_m)] for p in pts]


def varied_scenario(scn: Scenario, variation: SynthVariation, rng: np.random.Generator) -> Scenario:
    """``scn`` with one draw of anchor layout and path (see :class:`SynthVariation`)."""
    ids = [a.id for a in scn.anchors]
    base = np.array([a.pos_enu_m for a in scn.anchors], dtype=float)
    pool = [np.asarray(lay, dtype=float) for lay in variation.layouts if len(lay) == len(ids)] or [base]
    pos = pool[int(rng.integers(len(pool)))].copy()
    if variation.shuffle_anchors:
        pos = pos[rng.permutation(len(ids))]
    pos[:, :2] += rng.normal(0.0, variation.layout_jitter_m, (len(ids), 2))
    pos[:, 2] += rng.normal(0.0, variation.layout_jitter_up_m, len(ids))
    data = scn.model_dump(mode="python")
    data["anchors"] = [{**a, "pos_enu_m": [float(v) for v in p]} for a, p in zip(data["anchors"], pos, strict=True)]
    yaw = float(rng.normal(0.0, variation.path_yaw_std_rad))
    shift = rng.normal(0.0, variation.path_shift_std_m, 2)
    path = _rotated_path(data["path"], yaw, shift, base.mean(axis=0))
    pert = dict(path["perturbation"])
    if variation.path_lateral_std_m is not None:
        pert["lateral_std_m"] = variation.path_lateral_std_m
    if variation.path_sag_std_m is not None:
        pert["sag_std_m"] = variation.path_sag_std_m
    data["path"] = {**path, "perturbation": pert}
    if variation.random_route_prob > 0 and rng.random() < variation.random_route_prob:  # drawn last
        pts = _path_points(scn)
        centre = base.mean(axis=0)
        reach = max(float(np.max(np.linalg.norm(pts[:, :2] - centre[:2], axis=1))), 5.0)
        route = random_route(centre, reach, float(pts[:, 2].mean()), variation.random_route_points, rng)
        data["path"] = {"kind": "waypoints", "waypoints_enu_m": route, "perturbation": pert}
    return Scenario.model_validate(data)


def synthetic_trace(scn: Scenario | CompiledScenario, index: int, root_seed: int,
                    variation: SynthVariation | None = None) -> Trace:
    """Trace ``index`` of root seed ``root_seed``, with its own variation of layout and path when given."""
    if variation is None:
        return generate_trace(scn, index, root_seed)
    base = scn.scenario if isinstance(scn, CompiledScenario) else scn
    rng = np.random.default_rng(np.random.SeedSequence(int(root_seed), spawn_key=(int(index), VARIATION_COMPONENT)))
    return generate_trace(varied_scenario(base, variation, rng), index, root_seed)
