"""Trackers: ``aoi-fusion`` and ``bilstm`` (PyTorch, :mod:`.nets`), ``ls`` (:mod:`.ls`), ``ekf`` (:mod:`.ekf`).

:func:`make_tracker` lives here, above the tracker modules, so that :mod:`.base` (which every tracker
imports) imports none of them.
"""

from typing import Any

from ...errors import PhySynthError
from .base import TRACKER_NAMES, Tracker

__all__ = ["TRACKER_NAMES", "Tracker", "make_tracker"]


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
