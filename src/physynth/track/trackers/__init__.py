"""Trackers: ``aoi-fusion`` and ``bilstm`` (PyTorch, :mod:`.nets`), ``ls`` (:mod:`.ls`), ``ekf`` (:mod:`.ekf`)."""

from .base import TRACKER_NAMES, Tracker, make_tracker

__all__ = ["TRACKER_NAMES", "Tracker", "make_tracker"]
