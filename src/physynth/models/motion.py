"""Motion model: accelerate-cruise-decelerate speed profile -> s(t) -> kinematics at a fixed rate.

The speed is ``v(t) = v_c * g(u)`` over normalised trip time u = t / T_trip, with a smooth shape g
(max 1). Each run draws its cruise speed (+-12 %, uniform) and effective path length (+-5 %, uniform):
the end stations stay fixed, so the length spread acts on the trip duration T = L_eff / (v_c * mean g)
while the travelled geometry is always the station-to-station path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from numpy.polynomial import polynomial as P
from pydantic import Field, model_validator

from ._params import FiniteFloat, NonNegFloat, ParamsModel, PositiveFloat, Probability
from .jitter import JitterParams
from .kinematics import Kinematics
from .path import PathGeometry, PathPerturbation, perturbed_cf


class SpeedProfileParams(ParamsModel):
    """Shape g(u) of the speed over normalised trip time u in [0, 1], scaled so max g = 1.

    ``trapezoid``: accelerate over ``accel_frac`` of the trip, cruise, decelerate over ``decel_frac``
    (raised-cosine ramps, so acceleration is continuous). ``polynomial``: power-series coefficients
    in u (the paper fits degree 4 to the real speed). ``empirical``: ``samples`` of g at equally
    spaced u (calibration uses it when a polynomial fits poorly), smoothed before differentiation by
    a smoothing spline over u in [0, 1] with penalty ``smoothing`` (``lam`` of
    scipy.interpolate.make_smoothing_spline; smaller keeps more detail, e.g. the stops of a walk).
    """

    kind: Literal["trapezoid", "polynomial", "empirical"] = "trapezoid"
    accel_frac: Probability = 0.15
    decel_frac: Probability = 0.15
    coeffs: list[FiniteFloat] | None = None
    samples: list[NonNegFloat] | None = None
    smoothing: PositiveFloat = 1e-5

    @model_validator(mode="after")
    def _check(self) -> SpeedProfileParams:
        if self.kind == "trapezoid" and self.accel_frac + self.decel_frac > 1:
            raise ValueError("accel_frac + decel_frac must not exceed 1")
        if self.kind == "polynomial" and not self.coeffs:
            raise ValueError("a polynomial speed profile needs coeffs")
        if self.kind == "empirical" and (not self.samples or len(self.samples) < 5):
            raise ValueError("an empirical speed profile needs at least 5 samples (the smoothing spline's minimum)")
        if self.kind in ("polynomial", "empirical"):
            values = (P.polyval(np.linspace(0.0, 1.0, 201), np.asarray(self.coeffs, dtype=float))
                      if self.kind == "polynomial" else np.asarray(self.samples, dtype=float))
            if not np.all(np.isfinite(values)) or not values.max() > 0:
                raise ValueError(f"the {self.kind} speed profile is zero (or not finite) everywhere on [0, 1]")
        return self


class MotionParams(ParamsModel):
    """Trip kinematics: cruise speed, per-run spread (uniform +-frac), rests at the stations.

    ``max_acc_mps2``: the mover's acceleration limit [m s^-2]. Where the path bends so tightly that
    the profile's speed v would need more than it sideways (curvature kappa, v^2 kappa > limit), the
    mover slows to sqrt(limit / kappa), braking before and speeding up after at no more than the limit
    along the path (a walker at a turn or a reversal, a vehicle at a corner); the trip takes longer by
    the time lost. ``None`` (the default): the speed profile alone, whatever the path's curvature.

    ``jitter``: a random band-limited displacement added while the mover moves (the shaking of a
    hand-held sensor, a walker's sway; :mod:`physynth.models.jitter`); off by default.
    """

    cruise_speed_mps: PositiveFloat
    profile: SpeedProfileParams = SpeedProfileParams()
    cruise_speed_spread_frac: Annotated[float, Field(ge=0, lt=1)] = 0.12
    length_spread_frac: Annotated[float, Field(ge=0, lt=1)] = 0.05
    dwell_start_s: NonNegFloat = 0.0
    dwell_end_s: NonNegFloat = 0.0
    max_acc_mps2: PositiveFloat | None = None
    jitter: JitterParams = JitterParams()


_TABLE_N = 4001
SPEED_LIMIT_PASSES = 4
"""Passes of :func:`limit_speed` at most (each on the previous pass's grid)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SpeedShape:
    """Tabulated speed shape over u in [0, 1]: g (max 1), dg/du and G(u) = integral of g."""

    u: np.ndarray
    g: np.ndarray
    dg: np.ndarray
    cum: np.ndarray

    @property
    def mean(self) -> float:
        return float(self.cum[-1])


def compile_speed_shape(params: SpeedProfileParams) -> SpeedShape:
    """Tabulate a speed profile description."""
    u = np.linspace(0.0, 1.0, _TABLE_N)
    if params.kind == "trapezoid":
        g = np.ones_like(u)
        a, d = params.accel_frac, params.decel_frac
        if a > 0:
            up = u < a
            g[up] = 0.5 * (1.0 - np.cos(np.pi * u[up] / a))
        if d > 0:
            down = u > 1.0 - d
            g[down] = 0.5 * (1.0 - np.cos(np.pi * (1.0 - u[down]) / d))
    elif params.kind == "polynomial":
        g = np.clip(P.polyval(u, np.asarray(params.coeffs, dtype=float)), 0.0, None)
    else:
        from scipy.interpolate import make_smoothing_spline  # imported where used (0.7 s)

        samples = np.asarray(params.samples, dtype=float)
        us = np.linspace(0.0, 1.0, samples.size)
        spline = make_smoothing_spline(us, samples, lam=params.smoothing)  # smoothed before differentiation
        g = np.clip(spline(u), 0.0, None)
    peak = g.max()
    if not peak > 0:
        raise ValueError("speed profile is zero everywhere")
    g = g / peak
    dg = np.gradient(g, u)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(u))])
    return SpeedShape(u=u, g=g, dg=dg, cum=cum)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunDraw:
    """Per-run motion factors: cruise speed and effective path length relative to nominal."""

    speed_factor: float
    length_factor: float


def draw_run(params: MotionParams, *, rng: np.random.Generator) -> RunDraw:
    a, b = rng.uniform(-1.0, 1.0, 2)
    return RunDraw(speed_factor=1.0 + a * params.cruise_speed_spread_frac,
                   length_factor=1.0 + b * params.length_spread_frac)


def trip_duration_s(length_m: float, params: MotionParams, shape: SpeedShape, run: RunDraw) -> float:
    """Travel time between the stations [s], without the dwells."""
    v_c = params.cruise_speed_mps * run.speed_factor
    return length_m * run.length_factor / (v_c * shape.mean)


def kinematics(geometry: PathGeometry, pert: PathPerturbation, params: MotionParams, shape: SpeedShape,
               run: RunDraw, *, rate_hz: float, reverse: bool = False,
               lateral_dir: np.ndarray | None = None) -> Kinematics:
    """Sample the run at ``rate_hz`` (dwell at the start station, trip, dwell at the end station)."""
    trip = trip_duration_s(geometry.length_m, params, shape, run)
    total = params.dwell_start_s + trip + params.dwell_end_s
    t = np.arange(int(np.floor(total * rate_hz)) + 1, dtype=np.float64)  # integers as floats: the same values
    t /= rate_hz
    u = t - params.dwell_start_s
    u /= trip
    np.maximum(u, 0.0, out=u)  # numpy.clip's values (a zero's sign aside, which numpy.interp does not see)
    np.minimum(u, 1.0, out=u)
    scale = geometry.length_m / shape.mean
    along = np.interp(u, shape.u, shape.cum)  # distance travelled [m]
    along *= scale
    speed = np.interp(u, shape.u, shape.g)
    speed *= scale / trip
    accel = np.interp(u, shape.u, shape.dg)
    accel *= scale / trip**2
    # zero outside the open interval of motion (dwell_start, dwell_start + trip): the times are sorted
    # (and finite), so that interval is one run of samples and the rest is set in place
    first = int(t.searchsorted(params.dwell_start_s, side="right"))  # t <= dwell_start: at rest
    end = int(t.searchsorted(params.dwell_start_s + trip, side="left"))  # t >= its end: at rest
    for a in (speed, accel):
        a[:first] = 0.0
        a[end:] = 0.0
    s, ds, dds = _signed(geometry.length_m, along, speed, accel, reverse)
    p, d1, d2 = perturbed_cf(geometry, pert, s, lateral_dir)  # (3, T): fast broadcasting over time
    for _ in range(SPEED_LIMIT_PASSES if params.max_acc_mps2 is not None else 0):
        v_lim = np.sqrt(params.max_acc_mps2 / np.maximum(curvature(d1, d2), 1e-300))
        if not np.any(speed > v_lim * (1.0 + 1e-6)):  # nothing (more) to change: bit for bit as before
            break
        # the samples of the slowed run sit closer together where it is slow: the next pass sees the
        # sharpest bends that the previous grid stepped over
        t, along, speed, accel = limit_speed(t, along, speed, v_lim, params.max_acc_mps2, rate_hz)
        s, ds, dds = _signed(geometry.length_m, along, speed, accel, reverse)
        p, d1, d2 = perturbed_cf(geometry, pert, s, lateral_dir)
    vel = d1 * ds
    acc = np.multiply(d2, ds * ds, out=d2)  # d2 (ds)^2 + d1 dds, in the buffers perturbed_cf made
    acc += np.multiply(d1, dds, out=d1)
    return Kinematics(t_s=t, s_m=s, pos_enu_m=p.T, vel_enu_mps=vel.T, acc_enu_mps2=acc.T)


def _signed(length_m: float, along: np.ndarray, speed: np.ndarray, accel: np.ndarray, reverse: bool
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Path coordinate s and its first two time derivatives from the distance travelled."""
    if reverse:
        return length_m - along, -speed, -accel
    return along, speed, accel


def curvature(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Curvature |p' x p''| / |p'|^3 [1/m] of a path from its derivatives (3, T) in any parameter."""
    return np.linalg.norm(np.cross(d1, d2, axis=0), axis=0) / np.maximum(np.linalg.norm(d1, axis=0) ** 3, 1e-300)


def limit_speed(t_s: np.ndarray, along_m: np.ndarray, speed_mps: np.ndarray, v_lim_mps: np.ndarray,
                max_acc_mps2: float, rate_hz: float) -> tuple[np.ndarray, ...]:
    """The run slowed where ``speed`` exceeds ``v_lim`` (:class:`MotionParams`, ``max_acc_mps2``).

    The new speed w over the distance travelled x is min(speed, v_lim), then limited so that
    w^2 changes by at most 2 a dx on the way in and out of each slow stretch (w^2(x_i) <= w_j^2 +
    2 a |x_i - x_j| for every j: a running minimum forwards and backwards). Each step's time grows by
    the ratio of the old to the new mean speed over it; the run is resampled on a uniform grid at
    ``rate_hz`` from its start. Returns (t, x, w, dw/dt) on that grid.
    """
    a2 = 2.0 * max_acc_mps2
    w2 = np.minimum(speed_mps, v_lim_mps) ** 2
    w2 = np.minimum(w2, a2 * along_m + np.minimum.accumulate(w2 - a2 * along_m))  # speeding up after
    w2 = np.minimum(w2, np.minimum.accumulate((w2 + a2 * along_m)[::-1])[::-1] - a2 * along_m)  # braking before
    w = np.sqrt(np.maximum(w2, 0.0))
    old, new = speed_mps[1:] + speed_mps[:-1], w[1:] + w[:-1]
    ratio = np.where(new > 0, old / np.where(new > 0, new, 1.0), 1.0)  # 1 at rest (both 0)
    t_new_of_old = t_s[0] + np.concatenate([[0.0], np.cumsum(np.diff(t_s) * ratio)])
    t = np.arange(int(np.floor((t_new_of_old[-1] - t_s[0]) * rate_hz)) + 1, dtype=np.float64) / rate_hz + t_s[0]
    x = np.interp(t, t_new_of_old, along_m)
    v = np.interp(t, t_new_of_old, w)
    return t, x, v, np.gradient(v, t) if t.size > 1 else np.zeros_like(v)
