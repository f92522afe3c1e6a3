"""Antenna sway: a slow ranging error common to the anchors, on a clock of time, distance or motion."""

from __future__ import annotations

import numpy as np

from ..kinematics import Kinematics
from .params import UwbParams

SWAY_STEPS_PER_TAU = 20
"""Grid steps per correlation time on which the antenna sway is drawn (then read linearly at the
attempts): 5 % of tau apart, where the process moves by sqrt(2 x 0.05) = 0.32 of its std."""


def antenna_sway(t_s: np.ndarray, t0_s: float, t1_s: float, std_m: float, tau_s: float, *,
                 rng: np.random.Generator) -> np.ndarray:
    """(N, 3) offset [m] of the UWB antenna from the truth point at the times ``t_s`` in [t0, t1]: three
    independent Ornstein-Uhlenbeck processes (std ``std_m``, correlation time ``tau_s``), stationary
    at ``t0_s``, drawn exactly on a grid of tau / :data:`SWAY_STEPS_PER_TAU` and read linearly."""
    from .._filters import ar1

    dt = tau_s / SWAY_STEPS_PER_TAU
    n = int(np.ceil(max(t1_s - t0_s, 0.0) / dt)) + 2
    rho = float(np.exp(-dt / tau_s))
    x = rng.standard_normal((3, n))
    x[:, 1:] *= std_m * np.sqrt(1.0 - rho * rho)  # innovations of the exact discretisation
    x[:, 0] *= std_m  # the stationary start
    path = ar1(x, rho)
    grid = t0_s + dt * np.arange(n)
    return np.stack([np.interp(t_s, grid, path[k]) for k in range(3)], axis=1)


def travelled_m(t_s: np.ndarray, vel_enu_mps: np.ndarray) -> np.ndarray:
    """Distance travelled [m] since the first of the times ``t_s`` (T,): the speed |v| of the velocities
    ``vel_enu_mps`` (T, 3) integrated by the trapezoidal rule (non-decreasing; NaN speeds count as 0)."""
    speed = np.nan_to_num(np.sqrt(np.einsum("ij,ij->i", vel_enu_mps, vel_enu_mps)))
    out = np.zeros(t_s.shape[0])
    if t_s.shape[0] > 1:
        np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t_s), out=out[1:])
    return out


TURN_MIN_SPEED_MPS = 0.3
"""Below this horizontal speed the direction of travel is no heading: :func:`turned_rad` counts no turn."""


def turned_rad(t_s: np.ndarray, vel_enu_mps: np.ndarray, omega_body_radps: np.ndarray | None = None) -> np.ndarray:
    """Angle [rad] the carrier has turned since the first of the times ``t_s`` (T,), non-decreasing: the
    body rate |omega| integrated (``omega_body_radps`` (T, 3), each row held over its step, as the truth
    stores it), or without it the changes of the direction of horizontal travel between samples both
    moving faster than :data:`TURN_MIN_SPEED_MPS`."""
    out = np.zeros(t_s.shape[0])
    if t_s.shape[0] < 2:
        return out
    if omega_body_radps is not None:
        rate = np.nan_to_num(np.sqrt(np.einsum("ij,ij->i", omega_body_radps, omega_body_radps)))
        np.cumsum(rate[:-1] * np.diff(t_s), out=out[1:])
        return out
    v = np.nan_to_num(vel_enu_mps[:, :2])
    speed = np.hypot(v[:, 0], v[:, 1])
    step = np.abs(np.angle(np.exp(1j * np.diff(np.arctan2(v[:, 1], v[:, 0])))))  # wrapped to [0, pi]
    step[(speed[1:] < TURN_MIN_SPEED_MPS) | (speed[:-1] < TURN_MIN_SPEED_MPS)] = 0.0
    np.cumsum(step, out=out[1:])
    return out


def motion_clock(t_s: np.ndarray, vel_enu_mps: np.ndarray, omega_body_radps: np.ndarray | None, length_m: float,
                 turn_rad: float) -> np.ndarray:
    """The antenna sway's ``motion`` clock (T,): distance travelled over ``length_m`` plus angle turned
    over ``turn_rad`` (:func:`travelled_m`, :func:`turned_rad`); ``turn_rad`` inf: the distance alone."""
    clock = travelled_m(t_s, vel_enu_mps) / length_m
    if np.isfinite(turn_rad):
        clock += turned_rad(t_s, vel_enu_mps, omega_body_radps) / turn_rad
    return clock


def sway_at(t_s: np.ndarray, kin: Kinematics, params: UwbParams, *, rng: np.random.Generator,
            omega_body_radps: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) antenna offset [m] at the times ``t_s`` of a run: :func:`antenna_sway` on the scenario's
    clock, the time, or the truth's motion (:func:`motion_clock`; ``omega_body_radps``: the truth's body
    rate, for the angle turned)."""
    if params.antenna_sway_clock == "time":
        return antenna_sway(t_s, float(kin.t_s[0]), float(kin.t_s[-1]), params.antenna_sway_std_m,
                            params.antenna_sway_tau_s, rng=rng)
    turn = params.antenna_sway_turn_rad if params.antenna_sway_clock == "motion" else np.inf
    c = motion_clock(kin.t_s, kin.vel_enu_mps, omega_body_radps, params.antenna_sway_length_m, turn)
    return antenna_sway(np.interp(t_s, kin.t_s, c), 0.0, float(c[-1]), params.antenna_sway_std_m, 1.0, rng=rng)
