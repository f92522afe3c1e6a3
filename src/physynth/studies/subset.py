"""Anchor subsets of scenarios and traces: what a deployment with fewer anchors would have seen."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import PhySynthError
from ..records import Anchors, Trace
from ..scenario import Scenario, scenario_from_dict, scenario_to_dict


def check_subset(ids: Sequence[str], available: Sequence[str], where: str) -> list[str]:
    """``ids`` as a list, refusing duplicates, an empty list and ids not in ``available``."""
    ids = [str(i).strip() for i in ids]
    if not ids or any(not i for i in ids):
        raise PhySynthError(f"{where}: the anchor subset is empty")
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise PhySynthError(f"{where}: anchor(s) {', '.join(dup)} given twice")
    unknown = [i for i in ids if i not in available]
    if unknown:
        raise PhySynthError(f"{where}: unknown anchor(s) {', '.join(unknown)}; the anchors are "
                            f"{', '.join(available)}")
    return ids


def subset_scenario(scn: Scenario, ids: Sequence[str]) -> Scenario:
    """The scenario with only the anchors ``ids`` (in the scenario's order) and their overrides."""
    keep = set(check_subset(ids, scn.anchor_ids, f"scenario '{scn.name}'"))
    d = scenario_to_dict(scn)
    idx = [i for i, a in enumerate(d["anchors"]) if a["id"] in keep]
    d["anchors"] = [d["anchors"][i] for i in idx]
    if d.get("variation"):  # the alternative layouts of the same anchors
        d["variation"]["layouts"] = [[lay[i] for i in idx] for lay in d["variation"]["layouts"]]
    for key in ("channel_per_anchor", "availability_per_anchor"):
        d[key] = {k: v for k, v in d[key].items() if k in keep}
    return scenario_from_dict(d, f"{scn.name} restricted to {len(keep)} anchor(s)")


def restrict_to_anchors(trace: Trace, ids: Sequence[str]) -> Trace:
    """The trace as a deployment of only the anchors ``ids`` would have recorded it (same random numbers).

    Rows of other anchors are dropped and the anchor index is renumbered in the order of ``ids``.
    """
    pos = [trace.anchors.index(i) for i in ids]
    remap = np.full(len(trace.anchors), -1, dtype=np.int64)
    remap[pos] = np.arange(len(pos))
    u = trace.uwb
    new_idx = remap[u.anchor.astype(np.int64)]
    keep = new_idx >= 0
    uwb = u.rows(keep, anchor=new_idx[keep])
    anchors = Anchors(ids=tuple(ids), pos_enu_m=trace.anchors.pos_enu_m[pos],
                      names=tuple(trace.anchors.names[p] for p in pos))
    return Trace(truth=trace.truth, uwb=uwb, anchors=anchors, imu=trace.imu, meta=dict(trace.meta))
