"""The one small interface every tracker follows, and the registry of tracker names.

A tracker is fitted on a sequence of :class:`~physynth.track.inputs.TrackInput` (training traces on the
grid) and predicts one position per grid step of another::

    tracker = make_tracker("ekf")
    tracker.fit(train_inputs)                 # learned trackers train; classical ones tune noise levels
    est_enu_m = tracker.predict(test_input)   # (K, 3) ENU [m], one row per grid step
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from ...errors import PhySynthError
from ..inputs import TrackInput

ProgressFn = Callable[[str], None]

TRACKER_NAMES = ("aoi-fusion", "bilstm", "ls", "ekf")


class Tracker(Protocol):
    """Fit on training inputs; predict (K, 3) ENU positions [m] on every grid step of one input."""

    name: str

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> Tracker: ...

    def predict(self, inp: TrackInput) -> np.ndarray: ...


def make_tracker(name: str, **options: Any) -> Tracker:
    """A tracker by name (``aoi-fusion``, ``bilstm``, ``ls``, ``ekf``) with its keyword options."""
    if name == "ls":
        from .ls import LsTracker

        return LsTracker(**options)
    if name == "ekf":
        from .ekf import EkfTracker

        return EkfTracker(**options)
    if name in ("aoi-fusion", "bilstm"):
        from .nets import NetTracker

        return NetTracker(arch=name, **options)
    raise PhySynthError(f"unknown tracker '{name}' (choose from {', '.join(TRACKER_NAMES)})")
