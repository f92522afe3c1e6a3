"""Attitude model: the orientation of the tag's body frame along the trajectory.

The body frame is FLU (x forward, y left, z up); the world frame ENU. The attitude is the rotation
``R_wb`` (body to ENU), stored as a Hamilton quaternion scalar-first ``(w, x, y, z)``. Kinds:

- ``tangent``: body x along the horizontal velocity, level (roll = pitch = 0): a vehicle, a walking
  person's torso. The heading is held while the horizontal speed is below ``min_speed_mps``; where the
  path's direction turns faster than ``max_turn_rate_radps`` (a walker who turned about while nearly
  standing, a tight bend at walking pace), the body turns at that rate and catches up
  (:func:`limit_turn_rate`), as a person or vehicle does, rather than in one truth step (a spike of
  hundreds of rad/s in the truth rate and the gyroscope).
- ``pendulum``: a cabin hanging from a cable: tangent heading, plus a damped swing of the hanger
  excited by the pivot's acceleration. Pitch ``theta`` (about body y) and roll ``phi`` (about body x)
  follow ``theta'' + 2 zeta w0 theta' + w0^2 theta = w0^2 a_fwd / g`` and
  ``phi'' + 2 zeta w0 phi' + w0^2 phi = -w0^2 a_left / g`` (small angles, ``w0 = 2 pi / period``),
  so a steady acceleration tilts the hanger by ``atan(a / g)`` as a pendulum does; the cabin starts at
  rest. Discretised exactly for a piecewise-constant input (zero-order hold).
- ``tumble``: a free particle: body angular velocity an Ornstein-Uhlenbeck process per axis with
  standard deviation ``tumble_rate_std_radps`` and correlation time ``tumble_correlation_s``, from a
  uniformly random initial attitude. Draws from the ``attitude`` random stream. With
  ``tumble_spectrum: smooth`` the rate is instead a second-order Gauss-Markov process (power spectral
  density proportional to 1 / (1 + (2 pi f tau)^2)^2, autocorrelation (1 + |t| / tau) exp(-|t| / tau),
  tau = ``tumble_correlation_s``): its angular acceleration is continuous, as a hand's or a tumbling
  body's is, where the Ornstein-Uhlenbeck rate jumps from sample to sample and so turns the body
  faster than any truth system resolves (calibration writes ``smooth``). Synthesised per trace from
  its spectrum over the trace (circular), stationary from the first sample.
- ``fixed``: ``fixed_quat_wxyz`` throughout.

Angular velocity convention (what makes integration exact): between two truth samples the body turns
at the constant body rate ``omega_k = log(R_k^T R_{k+1}) / dt`` (rotation vector), so
``R_{k+1} = R_k exp(omega_k dt)`` holds to numerical precision, and a gyroscope sampled at any
integer multiple of the truth rate integrates back to the truth attitude exactly. Row k of the truth
table gives ``omega_k``, the rate over ``[t_k, t_{k+1})``; the last row repeats the one before.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
from pydantic import Field

from ..constants import G0_MPS2
from ._filters import ar1
from ._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


class AttitudeParams(ParamsModel):
    """How the body frame turns along the path (see the module docstring for each ``kind``)."""

    kind: Literal["tangent", "pendulum", "tumble", "fixed"] = "tangent"
    min_speed_mps: PositiveFloat = 0.05
    max_turn_rate_radps: PositiveFloat = 3.0
    pendulum_period_s: PositiveFloat = 4.0
    pendulum_damping_ratio: Annotated[float, Field(ge=0, lt=1)] = 0.05
    tumble_rate_std_radps: NonNegFloat = 1.0
    tumble_correlation_s: PositiveFloat = 0.5
    tumble_spectrum: Literal["ou", "smooth"] = "ou"
    fixed_quat_wxyz: Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)] = [1.0, 0.0, 0.0, 0.0]


@dataclass(frozen=True, slots=True, kw_only=True)
class Attitude:
    """Attitude at the truth times: ``quat_wxyz`` (T, 4) Hamilton unit quaternions body -> ENU, scalar
    first; ``omega_body_radps`` (T, 3); ``rot`` the same attitude as scipy rotations (built on use:
    scipy.spatial costs 0.4 s to import, and only the body-frame IMU needs it)."""

    quat_wxyz: np.ndarray
    omega_body_radps: np.ndarray

    @classmethod
    def from_rotation(cls, rot: Rotation, omega_body_radps: np.ndarray) -> Attitude:
        return cls(quat_wxyz=rot.as_quat(scalar_first=True), omega_body_radps=omega_body_radps)

    @property
    def rot(self) -> Rotation:
        """(T) rotations body -> ENU."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.quat_wxyz, scalar_first=True)


def heading_rad(vel_enu_mps: np.ndarray, min_speed_mps: float) -> np.ndarray:
    """(T,) unwrapped heading of the horizontal velocity [rad, from east towards north].

    Samples slower than ``min_speed_mps`` keep the last heading (the first moving one before any
    motion; 0 = east when the tag never moves).
    """
    v = np.asarray(vel_enu_mps, dtype=float)
    moving = at_least(v[:, 0], v[:, 1], min_speed_mps)
    if not moving.any():
        return np.zeros(v.shape[0])
    # arctan2 of every sample (elementwise: the same values as of the samples it is read from), then
    # only the slow samples take the heading of the last moving one before them (of the first moving
    # one when none is before): usually a handful at the stations, not a gather of every sample
    heading = np.arctan2(v[:, 1], v[:, 0])
    if not moving.all():
        still, moved = np.flatnonzero(~moving), np.flatnonzero(moving)
        last = np.searchsorted(moved, still) - 1  # moving samples before each slow one, minus one
        heading[still] = heading[moved[np.maximum(last, 0)]]
    return unwrap(heading)


_SQUARE_MARGIN = 1e-9
"""Relative margin around min_speed^2 outside which the squared speed decides :func:`at_least` (its
rounding error is below 4e-16 relative; hypot's below one ulp)."""


def at_least(x: np.ndarray, y: np.ndarray, limit: float) -> np.ndarray:
    """``numpy.hypot(x, y) >= limit``, bit for bit, with hypot (16x dearer than a square) evaluated only
    where x^2 + y^2 lies within :data:`_SQUARE_MARGIN` of limit^2 or is not finite (NaN). Squares
    decide only for 1e-100 < limit < 1e100, where limit^2 is normal: a square's underflow then errs by
    far less than the margin, and an overflow to inf means a speed far above the limit."""
    limit = float(limit)
    if not 1e-100 < limit < 1e100:
        return np.hypot(x, y) >= limit
    with np.errstate(over="ignore"):  # an overflow to inf decides as hypot does, and hypot is silent
        sq = x * x
        sq += y * y
    lim2 = limit * limit
    above = sq >= lim2 * (1.0 + _SQUARE_MARGIN)
    unsure = np.flatnonzero(~(above | (sq <= lim2 * (1.0 - _SQUARE_MARGIN))))
    if unsure.size:
        above[unsure] = np.hypot(x.take(unsure), y.take(unsure)) >= limit
    return above


def _lindley(excess: np.ndarray) -> np.ndarray:
    """D_k = max(0, D_(k-1) + excess_k), D_(-1) = 0, in closed form (a running minimum of the cumulative
    sum): how far a follower whose steps are capped lags behind, vectorised."""
    w = np.cumsum(excess)
    return w - np.minimum(np.minimum.accumulate(w), 0.0)


def limit_turn_rate(yaw: np.ndarray, t_s: np.ndarray, max_rate_radps: float) -> np.ndarray:
    """An unwrapped heading (T,) that turns no faster than ``max_rate_radps``: where it would turn faster,
    it follows at that rate until it has caught up (a rate limiter, one pass per direction: the lag of
    the turns to the left, then to the right, each in closed form by :func:`_lindley`). A heading that
    never turns faster is returned as it was."""
    if yaw.size < 2:
        return yaw
    cap = max_rate_radps * np.diff(t_s)
    step = np.diff(yaw)
    if not np.any(np.abs(step) > cap):
        return yaw
    out = yaw.copy()
    out[1:] -= _lindley(step - cap)  # left turns (yaw increasing) capped
    out[1:] += _lindley(-np.diff(out) - cap)  # then right turns
    return out


def unwrap(p: np.ndarray) -> np.ndarray:
    """``numpy.unwrap(p)`` of a 1-D float64 array, bit for bit, with the modular correction computed only
    at the steps it changes (|step| >= pi or NaN; a heading has a handful, where numpy.unwrap's full-length
    np.mod pass dominates)."""
    dd = np.diff(p)
    jump = np.flatnonzero(~(np.abs(dd) < np.pi))  # numpy.unwrap zeroes the correction where |dd| < pi
    up = np.array(p, dtype=np.float64)
    if jump.size == 0:
        return up
    d = dd[jump]
    ddmod = np.mod(d + np.pi, 2.0 * np.pi) - np.pi  # numpy.unwrap's interval [-pi, pi), then pi for steps > 0
    ddmod[(ddmod == -np.pi) & (d > 0)] = np.pi
    correction = np.zeros(dd.shape[0])
    correction[jump] = ddmod - d
    up[1:] = p[1:] + correction.cumsum()
    return up


@lru_cache(maxsize=64)
def _swing_filter(dt: float, period_s: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.signal import cont2discrete  # imported where used (0.9 s)

    w0 = 2.0 * np.pi / period_s
    num, den, _ = cont2discrete(([w0 * w0], [1.0, 2.0 * zeta * w0, w0 * w0]), dt, method="zoh")
    return np.ravel(num), np.asarray(den, dtype=float)


def _swing(u: np.ndarray, dt: float, period_s: float, zeta: float) -> np.ndarray:
    """Response theta of theta'' + 2 zeta w0 theta' + w0^2 theta = w0^2 u, from rest (ZOH exact)."""
    from scipy.signal import lfilter  # imported where used (0.9 s)

    num, den = _swing_filter(float(dt), float(period_s), float(zeta))
    return lfilter(num, den, u)


def _ou(n: int, dt: float, std: float, tau_s: float, *, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) stationary Ornstein-Uhlenbeck samples (exact AR(1) recursion)."""
    rho = np.exp(-dt / tau_s)
    e = rng.standard_normal((3, n)) * std
    e[:, 1:] *= np.sqrt(1.0 - rho * rho)
    return ar1(e, rho).T


def _smooth_rates(n: int, dt: float, std: float, tau_s: float, *, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) samples of the second-order Gauss-Markov process of ``tumble_spectrum: smooth``: complex
    Gaussian coefficients shaped by the spectrum, inverse real FFT, scaled to the variance ``std^2``
    the coefficients give on average (not each trace's own: a trace's sample variance scatters)."""
    f = np.fft.rfftfreq(n, dt)
    amp = 1.0 / (1.0 + (2.0 * np.pi * f * tau_s) ** 2)  # sqrt of the spectrum's shape
    coef = amp[:, None] * (rng.standard_normal((f.size, 3)) + 1j * rng.standard_normal((f.size, 3)))
    # irfft's variance per unit of amp^2: the DC (and, n even, the Nyquist) bin enter through their real
    # part once, every other bin twice with both parts
    weight = np.full(f.size, 4.0)
    weight[0] = 1.0
    if n % 2 == 0 and f.size > 1:
        weight[-1] = 1.0
    var = float(np.sum(weight * amp**2)) / n**2
    return np.fft.irfft(coef, n, axis=0) * (std / np.sqrt(var)) if var > 0 else np.zeros((n, 3))


def _quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a b of (N, 4) quaternions in scipy's scalar-last order (x, y, z, w): the rotation
    a * b of :class:`scipy.spatial.transform.Rotation` (b applied first), without its per-call overhead."""
    ax, ay, az, aw = a.T
    bx, by, bz, bw = b.T
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=1)


def cumulative_compose(first: Rotation, steps: Rotation) -> Rotation:
    """R_0 = first, R_{k+1} = R_k * steps[k]: a prefix product in log2(K) vectorised compositions
    (quaternion products in NumPy: scipy's composition costs ~20 ms per pass over 50,000 rotations)."""
    from scipy.spatial.transform import Rotation

    acc = steps.as_quat()  # (K, 4) unit quaternions, scalar last
    n = acc.shape[0]
    shift = 1
    while shift < n:  # Hillis-Steele scan: each pass composes with the partial product `shift` back
        acc = np.concatenate([acc[:shift], _quat_product(acc[: n - shift], acc[shift:])])
        shift *= 2
    q0 = first.as_quat()[None, :]
    return Rotation.from_quat(np.concatenate([q0, _quat_product(np.broadcast_to(q0, acc.shape), acc)]))


def body_rates(rot: Rotation, t_s: np.ndarray) -> np.ndarray:
    """(T, 3) body angular velocity [rad/s] constant over each truth interval (last row repeated)."""
    n = len(rot)
    out = np.zeros((n, 3))
    if n > 1:
        dt = np.diff(t_s)
        out[:-1] = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt[:, None]
        out[-1] = out[-2]
    return out


def body_rates_from_quat(t_s: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    """(T, 3) body rates [rad/s] of a recorded attitude (T, 4), NaN rows allowed (masked samples).

    Same convention as :func:`body_rates`: row k is the constant rate taking R_k to R_{k+1}; NaN
    where either sample is missing; the last row repeats the one before.
    """
    q = np.asarray(quat_wxyz, dtype=float)
    n = q.shape[0]
    out = np.full((n, 3), np.nan)
    if n < 2:
        return out
    ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(np.nan_to_num(q), axis=1) > 0)
    pair = np.flatnonzero(ok[:-1] & ok[1:])
    if pair.size:
        from scipy.spatial.transform import Rotation

        r0 = Rotation.from_quat(q[pair], scalar_first=True)
        r1 = Rotation.from_quat(q[pair + 1], scalar_first=True)
        out[pair] = (r0.inv() * r1).as_rotvec() / np.diff(np.asarray(t_s, dtype=float))[pair, None]
    out[-1] = out[-2]
    return out


def simulate_attitude(t_s: np.ndarray, vel_enu_mps: np.ndarray, acc_enu_mps2: np.ndarray, params: AttitudeParams,
                      *, rng: np.random.Generator | None = None) -> Attitude:
    """Attitude at uniform truth times ``t_s`` (T,) from the velocity and acceleration (T, 3) ENU.

    ``rng`` is used (and required) only by ``tumble``. The inputs are not modified.
    """
    t = np.asarray(t_s, dtype=float)
    n = t.shape[0]
    if params.kind == "fixed":
        q = np.asarray(params.fixed_quat_wxyz, dtype=float)
        if not np.linalg.norm(q) > 0:
            raise ValueError("attitude.fixed_quat_wxyz must not be zero")
        return Attitude(quat_wxyz=np.tile(q / np.linalg.norm(q), (n, 1)), omega_body_radps=np.zeros((n, 3)))
    dt = float(t[1] - t[0]) if n > 1 else 1.0
    if params.kind == "tumble":
        if rng is None:
            raise ValueError("a tumbling attitude needs a random generator")
        from scipy.spatial.transform import Rotation

        rates = _ou if params.tumble_spectrum == "ou" else _smooth_rates
        omega = rates(n, dt, params.tumble_rate_std_radps, params.tumble_correlation_s, rng=rng)
        first = Rotation.random(random_state=rng)
        if n == 1:
            return Attitude.from_rotation(Rotation.concatenate([first]), omega)
        rot = cumulative_compose(first, Rotation.from_rotvec(omega[:-1] * np.diff(t)[:, None]))
        omega[-1] = omega[-2]
        return Attitude.from_rotation(rot, omega)
    yaw = limit_turn_rate(heading_rad(vel_enu_mps, params.min_speed_mps), t, params.max_turn_rate_radps)
    if params.kind == "tangent":  # turns about the fixed world z axis add up: exact rates without logs
        half = 0.5 * yaw
        q = np.zeros((n, 4))
        np.cos(half, out=q[:, 0])  # into the columns: no temporaries
        np.sin(half, out=q[:, 3])
        omega = np.zeros((n, 3))
        if n > 1:
            omega[:-1, 2] = (yaw[1:] - yaw[:-1]) / (t[1:] - t[:-1])  # numpy.diff's values, without its overhead
            omega[-1, 2] = omega[-2, 2]
        return Attitude(quat_wxyz=q, omega_body_radps=omega)
    else:  # pendulum
        from scipy.spatial.transform import Rotation

        acc = np.asarray(acc_enu_mps2, dtype=float)
        c, s = np.cos(yaw), np.sin(yaw)
        a_fwd = acc[:, 0] * c + acc[:, 1] * s
        a_left = -acc[:, 0] * s + acc[:, 1] * c
        pitch = _swing(a_fwd / G0_MPS2, dt, params.pendulum_period_s, params.pendulum_damping_ratio)
        roll = _swing(-a_left / G0_MPS2, dt, params.pendulum_period_s, params.pendulum_damping_ratio)
        zeros = np.zeros(n)
        rot = (Rotation.from_rotvec(np.stack([zeros, zeros, yaw], axis=1))  # intrinsic z-y-x: yaw, pitch, roll
               * Rotation.from_rotvec(np.stack([zeros, pitch, zeros], axis=1))
               * Rotation.from_rotvec(np.stack([roll, zeros, zeros], axis=1)))
    return Attitude.from_rotation(rot, body_rates(rot, t))
