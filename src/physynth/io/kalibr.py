"""Kalibr ``imu.yaml`` files: read into and write from :class:`physynth.models.imu.BodyImuParams`.

Kalibr's keys: ``accelerometer_noise_density`` [m s^-2 Hz^-1/2], ``accelerometer_random_walk``
[m s^-3 Hz^-1/2], ``gyroscope_noise_density`` [rad s^-1 Hz^-1/2], ``gyroscope_random_walk``
[rad s^-2 Hz^-1/2], ``update_rate`` [Hz], ``rostopic``. Other PhySynth fields keep their defaults.
"""

from __future__ import annotations

import os
from pathlib import Path

import yaml
from pydantic import ValidationError

from ..errors import ScenarioError
from ..models.imu import KALIBR_KEYS, BodyImuParams, body_imu_to_kalibr
from .atomic import atomic_write_text


def read_kalibr_imu(path: str | os.PathLike) -> BodyImuParams:
    """The body-frame IMU of a Kalibr ``imu.yaml`` (one clear error on a bad file)."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"cannot read Kalibr IMU file {p}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or not any(k in data for k in KALIBR_KEYS):
        raise ScenarioError(f"{p}: not a Kalibr imu.yaml (none of {', '.join(KALIBR_KEYS)})")
    try:
        return BodyImuParams.model_validate({k: v for k, v in data.items() if k in KALIBR_KEYS})
    except ValidationError as exc:
        e = exc.errors()[0]
        raise ScenarioError(f"{p}: {'.'.join(map(str, e['loc']))}: {e['msg']}") from None


def write_kalibr_imu(params: BodyImuParams, path: str | os.PathLike, *, rostopic: str = "/imu0") -> Path:
    """Write the Kalibr ``imu.yaml`` of a body-frame IMU (atomically)."""
    p = Path(path)
    atomic_write_text(p, yaml.safe_dump(body_imu_to_kalibr(params, rostopic), sort_keys=False))
    return p
