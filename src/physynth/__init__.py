"""PhySynth: physics-based synthetic UWB ranging + IMU + availability + AoI traces."""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = ["Anchors", "Imu", "Reason", "Trace", "Truth", "Uwb", "__version__"]


def __getattr__(name: str) -> Any:
    """The records are imported on first use, so ``physynth --help`` does not pay for NumPy."""
    if name in __all__:
        from . import records

        return getattr(records, name)
    raise AttributeError(f"module 'physynth' has no attribute {name!r}")
