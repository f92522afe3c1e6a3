"""What is known of the tag's height without the ranges: the carrier's height above the ground.

A walker's tag rides at about 1 m, a robot's at its mast height, a cable-car cabin's on its rope. Seen
from anchors that stand at nearly one height, or from far away, the ranges hardly tell the vertical: a
tracker that takes it from them alone extrapolates (metres off, on a layout unlike its training ones).
:class:`HeightPrior` is that knowledge, ``U ~ N(mean_m, std_m^2)`` in the site's frame; every tracker
reads it from its :class:`~physynth.track.inputs.TrackInput` (``height``): ``ls`` and ``ekf`` as a
pseudo-measurement of the height, the networks as the value their vertical falls back to where their
own uncertainty (and the geometry's) is larger than the prior's.

Where it comes from: the user (``physynth study tracking --tag-height``), the training runs' truth
(:func:`height_from_truth`) or a scenario's path (:func:`height_from_scenario`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import PhySynthError

MIN_HEIGHT_STD_M = 0.05
"""Smallest spread [m] a prior estimated from data is given (a tag is never held to a centimetre)."""


@dataclass(frozen=True, slots=True)
class HeightPrior:
    """The tag's height U [m] in the site's frame: N(``mean_m``, ``std_m``^2)."""

    mean_m: float
    std_m: float

    def __post_init__(self) -> None:
        if not math.isfinite(self.mean_m):
            raise PhySynthError(f"tag height must be a finite number of metres, got {self.mean_m}")
        if not (math.isfinite(self.std_m) and self.std_m > 0.0):
            raise PhySynthError(f"tag height spread must be a positive number of metres, got {self.std_m}")

    def to_dict(self) -> dict[str, float]:
        return {"mean_m": float(self.mean_m), "std_m": float(self.std_m)}


def height_from_heights(u_m: np.ndarray) -> HeightPrior:
    """The prior of a set of known heights U [m] (NaN ignored): their mean and spread (at least
    :data:`MIN_HEIGHT_STD_M`)."""
    u = np.asarray(u_m, dtype=float).ravel()
    u = u[np.isfinite(u)]
    if u.size < 2:
        raise PhySynthError("no known tag height to build a height prior from")
    return HeightPrior(float(u.mean()), max(float(u.std()), MIN_HEIGHT_STD_M))


def height_from_truth(traces: Sequence[Any]) -> HeightPrior:
    """The prior of the training runs' truth heights (every truth sample of every trace)."""
    return height_from_heights(np.concatenate([np.asarray(t.truth.pos_enu_m, float)[:, 2] for t in traces]))


def height_from_scenario(scn: Any, n: int = 200) -> HeightPrior:
    """The prior of a scenario's path: the mean height along it, the spread of the heights along it and
    of its run-to-run sag (``path.perturbation.sag_std_m``), at least :data:`MIN_HEIGHT_STD_M`."""
    from ..models.path import compile_path

    geo = compile_path(scn.path)
    u = np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, n))[0], dtype=float)[:, 2]
    sag = float(getattr(scn.path.perturbation, "sag_std_m", 0.0) or 0.0)
    return HeightPrior(float(u.mean()), max(math.hypot(float(u.std()), sag), MIN_HEIGHT_STD_M))
