"""Whether datasets pooled by calibration describe the same kind of site.

Pooling a Hanyang walk with a cable-car recording gives one scenario that matches neither. Two
datasets with UWB anchors are taken as the same kind of site when they share at least one anchor id
and, when both are real recordings, come from the same importer (``source`` in ``dataset.json``). An
IMU-only dataset (e.g. a BROAD trial) pools with anything: it only lends the IMU noise.
:func:`check_same_site` refuses anything else with one line
(:class:`~physynth.errors.MixedSitesError`) unless told to pool them anyway.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import MixedSitesError
from ..records import Trace


@dataclass(frozen=True, slots=True)
class Site:
    """What identifies the site of one dataset: its name, kind (real/synthetic), source and anchor ids."""

    name: str
    kind: str | None
    source: str | None
    anchors: frozenset[str]

    def describe(self) -> str:
        ids = sorted(self.anchors)
        shown = ", ".join(ids[:4]) + (", ..." if len(ids) > 4 else "")
        return f"{self.name} ({self.kind or 'unknown kind'}, source {self.source or '?'}, anchors [{shown}])"


def site_of(name: str, meta: Mapping[str, Any], traces: Sequence[Trace]) -> Site:
    """The site of a dataset from its ``dataset.json`` and traces."""
    anchors = frozenset(a for t in traces for a in t.anchors.ids)
    return Site(name=name, kind=meta.get("kind"), source=meta.get("source"), anchors=anchors)


def mixed_reason(a: Site, b: Site) -> str | None:
    """Why two sites are not the same kind (None when they are)."""
    if not a.anchors or not b.anchors:  # an IMU-only recording lends only IMU noise (docs/calibration.md)
        return None
    if not (a.anchors & b.anchors):
        return "they have no anchor in common"
    if a.kind == b.kind == "real" and a.source and b.source and a.source != b.source:
        return f"they come from different recording sources ({a.source} and {b.source})"
    return None


def check_same_site(sites: Sequence[Site], *, allow_mixed: bool = False) -> None:
    """Refuse to pool datasets of different kinds of site (unless ``allow_mixed``)."""
    if allow_mixed:
        return
    for i, a in enumerate(sites):
        for b in sites[i + 1:]:
            reason = mixed_reason(a, b)
            if reason:
                raise MixedSitesError(f"will not pool {a.describe()} with {b.describe()}: not the same kind of "
                                      f"site ({reason})")
