"""PhySynth: physics-based synthetic UWB ranging + IMU + availability + AoI traces."""

__version__ = "0.1.0"

from .records import Anchors, Imu, Reason, Trace, Truth, Uwb  # noqa: E402

__all__ = ["Anchors", "Imu", "Reason", "Trace", "Truth", "Uwb", "__version__"]
