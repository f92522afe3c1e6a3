"""Physical constants and fixed conventions used across PhySynth."""

G0_MPS2 = 9.80665
"""Standard gravity [m s^-2]."""

SCHEMA_VERSION = 1
"""Version of the on-disk dataset layout (dataset.json + Parquet tables)."""

IMU_FRAME = "enu-gravity-free"
"""IMU convention of every trace: acceleration in the ENU world frame, gravity removed [m s^-2]."""

IMU_BODY_FRAME = "body-flu"
"""Body-frame IMU convention: specific force (gravity included) [m s^-2] and angular rate [rad s^-1] in
the sensor's body frame, x forward, y left, z up (docs/imu.md)."""

GRAVITY_ENU_MPS2 = (0.0, 0.0, -G0_MPS2)
"""Gravity vector in the ENU world frame [m s^-2]."""

DEFAULT_GRID_RATE_HZ = 100.0
"""Evaluation grid rate of DESIGN.md section 5 [Hz]."""
