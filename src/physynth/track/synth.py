"""Synthetic training traces that vary the path and the anchor layout around a calibrated site.

The tracking study's form of a scenario's ``variation`` section (:mod:`physynth.models.variation`,
whose draws it shares, in the same order and from the same stream: a study trace and a trace of the
scenario with the same section are the same).

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
- with ``nlos_log_std`` > 0, its own NLOS frequency: every anchor's ``nlos_prob`` and the tag-side
  ``uwb.tag_nlos_prob`` times exp(N(0, ``nlos_log_std``)), drawn last (a site with more or fewer
  obstacles than the calibration runs had).

With ``layout_distribution`` (:class:`~physynth.models.variation.LayoutDistribution`), the layout is a whole
one drawn per trace instead of one of ``layouts`` jittered: its own anchor count, footprint, aspect, heights,
yaw and offset from the scenario's anchors, each anchor with the channel and availability of one of the
scenario's anchors (drawn with replacement) and a new id ``L1`` .. ``Ln``, so that a network learns no
anchor's id, count or place (:func:`physynth.models.variation.draw_layout`, ``layout_anchors``).

Everything else (motion, the rest of the channel, availability, IMU) is the scenario's, drawn by the
generator from the usual per-component streams, so a trace is identical in every process and DataLoader worker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..generate import CompiledScenario, generate_trace
from ..models.variation import LayoutDistribution, draw_site, layout_anchors, nlos_scaled, random_route
from ..records import Trace
from ..rng import COMPONENT_ID
from ..scenario import Scenario

__all__ = ["VARIATION_COMPONENT", "SynthVariation", "random_route", "synthetic_trace", "varied_scenario"]

VARIATION_COMPONENT = COMPONENT_ID["site"]
"""spawn_key component of the variation draws (100: that of a scenario's ``variation`` section)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SynthVariation:
    """Per-trace variation of anchor layout and path (see the module docstring). Metres, radians.

    ``layout_distribution``: a :class:`~physynth.models.variation.LayoutDistribution` (or its fields as a
    mapping, validated here); None: the layouts and their jitter.
    """

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
    nlos_log_std: float = 0.0
    layout_distribution: LayoutDistribution | None = None

    def __post_init__(self) -> None:
        if isinstance(self.layout_distribution, dict):  # the fields of a scenario's section
            object.__setattr__(self, "layout_distribution", LayoutDistribution.model_validate(self.layout_distribution))
        elif self.layout_distribution is not None and not isinstance(self.layout_distribution, LayoutDistribution):
            raise ValueError(f"invalid SynthVariation (layout_distribution is a LayoutDistribution, a mapping of its "
                             f"fields or None): {self!r}")
        stds = (self.layout_jitter_m, self.layout_jitter_up_m, self.path_yaw_std_rad, self.path_shift_std_m,
                self.nlos_log_std)
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
                "random_route_prob": self.random_route_prob, "random_route_points": self.random_route_points,
                "nlos_log_std": self.nlos_log_std,
                "layout_distribution": (None if self.layout_distribution is None
                                        else self.layout_distribution.model_dump(mode="python"))}


def _path_points(scn: Scenario, n: int = 200) -> np.ndarray:
    """(n, 3) points along the scenario's path [m]."""
    from ..models.path import compile_path

    geo = compile_path(scn.path)
    return np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, n))[0], dtype=float)


def varied_scenario(scn: Scenario, variation: SynthVariation, rng: np.random.Generator) -> Scenario:
    """``scn`` with one draw of anchor layout and path (:func:`physynth.models.variation.draw_site`), and
    without a ``variation`` section of its own: ``variation`` takes its place."""
    base = np.array([a.pos_enu_m for a in scn.anchors], dtype=float)
    data = scn.model_dump(mode="python")
    pos, path, record = draw_site(variation, base, data["path"], lambda: _path_points(scn), rng)
    if "layout_drawn" in record:  # a whole layout: new anchors, each with a pool anchor's channel
        drawn = layout_anchors(scn, pos, record["layout_drawn"])
        data["anchors"] = [a.model_dump(mode="python") for a in drawn["anchors"]]
        for key in ("channel_per_anchor", "availability_per_anchor"):
            data[key] = {k: o.model_dump(mode="python") for k, o in drawn[key].items()}
    else:
        data["anchors"] = [{**a, "pos_enu_m": [float(v) for v in p]}
                           for a, p in zip(data["anchors"], pos, strict=True)]
    data["path"] = path
    data["variation"] = None  # this draw replaces a section of the scenario's own (drawn from the same stream)
    varied = Scenario.model_validate(data)
    if "nlos_scale" in record:
        varied = varied.model_copy(update=nlos_scaled(varied, record["nlos_scale"]))
    return varied


def synthetic_trace(scn: Scenario | CompiledScenario, index: int, root_seed: int,
                    variation: SynthVariation | None = None) -> Trace:
    """Trace ``index`` of root seed ``root_seed``, with its own variation of layout and path when given."""
    if variation is None:
        return generate_trace(scn, index, root_seed)
    base = scn.scenario if isinstance(scn, CompiledScenario) else scn
    rng = np.random.default_rng(np.random.SeedSequence(int(root_seed), spawn_key=(int(index), VARIATION_COMPONENT)))
    return generate_trace(varied_scenario(base, variation, rng), index, root_seed)
