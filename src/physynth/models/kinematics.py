"""The truth a motion model samples: times, path coordinate and ENU position, velocity, acceleration.

The record the motion model writes and every model above it reads (jitter, IMU, UWB); it sits below
:mod:`~physynth.models.motion` so that a model reading it need not import the motion model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True, kw_only=True)
class Kinematics:
    """Truth at a fixed rate: t (T,), path coordinate s (T,) [m], pos/vel/acc (T, 3) ENU."""

    t_s: np.ndarray
    s_m: np.ndarray
    pos_enu_m: np.ndarray
    vel_enu_mps: np.ndarray
    acc_enu_mps2: np.ndarray
