"""The one small interface every tracker follows, and the tracker names (:func:`physynth.track.trackers.make_tracker`
builds one by name).

A tracker is fitted on a sequence of :class:`~physynth.track.inputs.TrackInput` (training traces on the
grid) and predicts one position per grid step of another::

    tracker = make_tracker("ekf")
    tracker.fit(train_inputs)                 # learned trackers train; classical ones tune noise levels
    est_enu_m = tracker.predict(test_input)   # (K, 3) ENU [m], one row per grid step
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from ..inputs import TrackInput

ProgressFn = Callable[[str], None]

TRACKER_NAMES = ("aoi-fusion", "bilstm", "ls", "ekf")


class Tracker(Protocol):
    """Fit on training inputs; predict (K, 3) ENU positions [m] on every grid step of one input."""

    name: str

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> Tracker: ...

    def predict(self, inp: TrackInput) -> np.ndarray: ...
