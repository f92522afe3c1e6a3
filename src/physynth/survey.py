"""A scenario for a site known only from its survey: its anchors, a route sketch, another site's channel.

The user who has no labelled run at a site yet still knows where the anchors stand (the survey), roughly
where the tag will go (a route sketch) and how UWB ranges behave at a similar site (a scenario calibrated
there). :func:`survey_scenario` puts the three together: the other site's channel, availability, motion
and IMU, with the surveyed anchors and the sketched route. What belonged to the other site's anchors goes:
their own channels and availabilities (each surveyed anchor takes the scenario-wide ones, the pooled fit of
a calibration), the layouts of its runs, its `variation` section. Trackers pre-trained on this scenario's
traces (``physynth study tracking --protocol survey-only``) have seen no real range of the site.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import ScenarioError
from .scenario import Scenario, scenario_from_dict, scenario_to_dict


def survey_scenario(base: Scenario, anchor_ids: Sequence[str], anchor_pos_enu_m: Any,
                    route_enu_m: Any | None = None, *, name: str | None = None) -> Scenario:
    """``base`` at a surveyed site: anchors ``anchor_ids`` at ``anchor_pos_enu_m`` (A, 3) [m], and the
    route through the waypoints ``route_enu_m`` (W, 3) [m] (W >= 2), or without a route ``base``'s path
    moved with the anchors (by the horizontal shift between the two anchor centroids)."""
    ids = [str(a) for a in anchor_ids]
    pos = np.asarray(anchor_pos_enu_m, dtype=float)
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] != len(ids):
        raise ScenarioError(f"the survey needs one [E, N, U] position per anchor: {len(ids)} id(s), positions of "
                            f"shape {pos.shape}")
    if len(ids) < 3:
        raise ScenarioError(f"a survey of {len(ids)} anchor(s): a tag is placed by three or more")
    if not np.all(np.isfinite(pos)):
        raise ScenarioError("the surveyed anchor positions must be finite numbers of metres")
    if len(set(ids)) != len(ids):
        twice = sorted({a for a in ids if ids.count(a) > 1})
        raise ScenarioError(f"the surveyed anchor ids repeat: {', '.join(twice)}")
    data = scenario_to_dict(base)
    data["name"] = name or f"{base.name}-survey"
    data["anchors"] = [{"id": a, "pos_enu_m": [float(v) for v in p]} for a, p in zip(ids, pos, strict=True)]
    for key in ("channel_per_anchor", "availability_per_anchor"):
        data.pop(key, None)
    data["variation"] = None
    prov = dict(data.get("provenance") or {})
    prov.pop("anchor_layout", None)
    prov["survey"] = {"base": base.name, "anchors": len(ids), "route": route_enu_m is not None}
    data["provenance"] = prov
    if route_enu_m is not None:
        route = np.asarray(route_enu_m, dtype=float)
        if route.ndim != 2 or route.shape[1] != 3 or route.shape[0] < 2 or not np.all(np.isfinite(route)):
            raise ScenarioError(f"the route sketch needs two or more finite [E, N, U] waypoints, got shape "
                                f"{route.shape}")
        data["path"] = {"kind": "waypoints", "waypoints_enu_m": route.tolist(),
                        "perturbation": data["path"].get("perturbation", {})}
    else:
        from .models.variation import rotated_path

        old = np.array([a.pos_enu_m for a in base.anchors], dtype=float)
        shift = pos.mean(axis=0)[:2] - (old.mean(axis=0)[:2] if len(old) else pos.mean(axis=0)[:2])
        data["path"] = rotated_path(base.path.model_dump(mode="python"), 0.0, shift, np.zeros(3))
    return scenario_from_dict(data)
