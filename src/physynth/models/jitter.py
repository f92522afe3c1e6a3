"""Motion jitter: a random, band-limited displacement added to the path's motion while the mover moves.

A path and a speed profile describe where a mover goes; they do not describe the shaking of a hand
that carries a sensor, the sway of a walker or the buffeting of a vehicle, which is most of what an
IMU on such a mover reads. The jitter is a zero-mean Gaussian displacement per ENU axis whose
acceleration has a flat power spectral density inside each of a few frequency bands:
``acc_rms_mps2[k][axis]`` is the RMS acceleration the band ``[bands_hz[k], bands_hz[k + 1])`` adds on
that axis (so the displacement's spectrum falls as f^-4 inside the band and is bounded: no drift).

Each trace draws the spectrum's complex coefficients (stream ``jitter``) and builds displacement,
velocity and acceleration from them with exact derivatives (the same trigonometric series
differentiated), so that the truth stays self-consistent. The jitter is faded in and out with
raised-cosine ramps of ``ramp_s`` at the first and last instants of motion: a mover at rest in a
station or on a table stays still. It moves the position only; the attitude follows the path.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Annotated

import numpy as np
from pydantic import Field, model_validator

from ._params import NonNegFloat, ParamsModel, PositiveFloat
from .kinematics import Kinematics

Vec3NonNeg = Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)]


class JitterParams(ParamsModel):
    """Band-limited random displacement while moving (see the module docstring); off by default.

    ``bands_hz``: increasing band edges [Hz] (K + 1 values, the first > 0). ``acc_rms_mps2``: K rows of
    per-axis (E, N, U) RMS acceleration [m s^-2] of each band. ``ramp_s``: fade-in and fade-out [s].
    ``intensity_log_std``: each trace scales the whole jitter by exp(sigma z), z ~ N(0, 1) (a log-normal
    factor of median 1: ``acc_rms_mps2`` is the typical trace's): runs of one mover are not all shaken
    equally hard. Bands at or above the truth's Nyquist frequency contribute only their part below it.
    """

    bands_hz: list[PositiveFloat] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0]
    acc_rms_mps2: list[Vec3NonNeg] = []
    ramp_s: NonNegFloat = 1.0
    intensity_log_std: Annotated[float, Field(ge=0.0, le=3.0)] = 0.0

    @model_validator(mode="after")
    def _check(self) -> JitterParams:
        edges = np.asarray(self.bands_hz, dtype=float)
        if edges.size < 2 or np.any(np.diff(edges) <= 0):
            raise ValueError("jitter bands_hz must hold at least two increasing band edges")
        if self.acc_rms_mps2 and len(self.acc_rms_mps2) != edges.size - 1:
            raise ValueError(f"jitter acc_rms_mps2 needs one [e, n, u] row per band: {edges.size - 1} rows "
                             f"for {edges.size} edges, got {len(self.acc_rms_mps2)}")
        return self

    @property
    def active(self) -> bool:
        return any(any(row) for row in self.acc_rms_mps2)


def band_psd(f_hz: np.ndarray, params: JitterParams) -> np.ndarray:
    """One-sided acceleration PSD (F, 3) [m^2 s^-4 Hz^-1] of the jitter at frequencies ``f_hz``."""
    edges = np.asarray(params.bands_hz, dtype=float)
    level = np.asarray(params.acc_rms_mps2, dtype=float) ** 2 / np.diff(edges)[:, None]  # (K, 3)
    band = np.searchsorted(edges, f_hz, side="right") - 1
    inside = (band >= 0) & (band < level.shape[0])
    out = np.zeros((f_hz.shape[0], 3))
    out[inside] = level[band[inside]]
    return out


def _fade(t_s: np.ndarray, t_on: float, t_off: float, ramp_s: float) -> tuple[np.ndarray, ...]:
    """Window w(t) (0 outside [t_on, t_off], raised-cosine ramps of ``ramp_s`` inside) and w', w''."""
    w, d1, d2 = (np.zeros_like(t_s) for _ in range(3))
    inside = (t_s >= t_on) & (t_s <= t_off)
    w[inside] = 1.0
    ramp = min(ramp_s, 0.5 * (t_off - t_on))
    if ramp > 0:
        k = np.pi / ramp
        for x, sign in ((t_s - t_on, 1.0), (t_off - t_s, -1.0)):  # fade in, fade out (mirror image)
            on = inside & (x < ramp)
            w[on] = 0.5 * (1.0 - np.cos(k * x[on]))
            d1[on] = sign * 0.5 * k * np.sin(k * x[on])
            d2[on] = 0.5 * k * k * np.cos(k * x[on])
    return w, d1, d2


def add_jitter(kin: Kinematics, params: JitterParams, *, rng: np.random.Generator) -> Kinematics:
    """``kin`` with the jitter's displacement, velocity and acceleration added while it moves.

    Returns ``kin`` itself (nothing drawn) when the jitter is off or the mover never moves.
    """
    t = kin.t_s
    moving = np.flatnonzero(np.linalg.norm(kin.vel_enu_mps, axis=1) > 0)
    if not params.active or moving.size < 2 or t.size < 4:
        return kin
    n = t.size
    dt = (t[-1] - t[0]) / (n - 1)
    f = np.fft.rfftfreq(n, dt)
    psd = band_psd(f, params)  # (F, 3)
    psd[0] = 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        amp = np.where(f[:, None] > 0, np.sqrt(psd * n / (4.0 * dt)) / (2.0 * np.pi * f[:, None]) ** 2, 0.0)
    sigma = params.intensity_log_std
    scale = float(np.exp(sigma * rng.standard_normal()))  # the trace's intensity (drawn first)
    coef = amp * (rng.standard_normal((f.size, 3)) + 1j * rng.standard_normal((f.size, 3)))  # displacement
    coef *= scale
    iw = (2j * np.pi * f)[:, None]
    x = np.fft.irfft(coef, n, axis=0)
    v = np.fft.irfft(coef * iw, n, axis=0)
    a = np.fft.irfft(coef * iw * iw, n, axis=0)
    w, w1, w2 = (c[:, None] for c in _fade(t, t[moving[0]], t[moving[-1]], params.ramp_s))
    return replace(kin, pos_enu_m=kin.pos_enu_m + w * x, vel_enu_mps=kin.vel_enu_mps + w * v + w1 * x,
                   acc_enu_mps2=kin.acc_enu_mps2 + w * a + 2.0 * w1 * v + w2 * x)
