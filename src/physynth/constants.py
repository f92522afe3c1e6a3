"""Physical constants and fixed conventions used across PhySynth."""

G0_MPS2 = 9.80665
"""Standard gravity [m s^-2]."""

SCHEMA_VERSION = 1
"""Version of the on-disk dataset layout (dataset.json + Parquet tables)."""

IMU_FRAME = "enu-gravity-free"
"""IMU convention of every trace: acceleration in the ENU world frame, gravity removed [m s^-2]."""

DEFAULT_GRID_RATE_HZ = 100.0
"""Evaluation grid rate of docs/data-and-metrics.md (section 3) [Hz]."""
