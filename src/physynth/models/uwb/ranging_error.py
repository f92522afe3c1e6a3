"""The ranging error: the LOS error N(mu + range term, sigma^2) and the NLOS offset of a mode."""

from __future__ import annotations

import numpy as np

from ..renewal import by_label
from .arrays import ChannelArrays


def sample_nlos_offset(anchor: np.ndarray, ch: ChannelArrays, *, rng: np.random.Generator,
                       mode: np.ndarray | None = None) -> np.ndarray:
    """NLOS offsets delta [m] for rows of the given anchors (Gaussian mixture per anchor).

    ``mode`` fixes each row's mixture component (the episode's reflector); drawn by weight otherwise.
    """
    if mode is None:
        u = rng.random(anchor.shape[0])
        mode = np.minimum((u[:, None] > ch.mode_cumw[anchor]).sum(axis=1), ch.mode_cumw.shape[1] - 1)
    flat = np.multiply(anchor, ch.mode_mean_m.shape[1], dtype=np.intp)  # [anchor, mode] as flat indices
    flat += mode
    return ch.mode_mean_m.ravel().take(flat) + ch.mode_std_m.ravel().take(flat) * rng.standard_normal(anchor.shape[0])


BIAS_RANGE_FLOOR_M = 0.1
"""Ranges below this [m] enter the received-power bias at this value (log10 of 0 is -inf)."""


def range_decades(true_range_m: np.ndarray | float) -> np.ndarray:
    """log10 of the true range in metres (floored at :data:`BIAS_RANGE_FLOOR_M`): the regressor of the
    received-power ranging bias (free-space path loss falls 20 dB per decade of range)."""
    return np.log10(np.maximum(true_range_m, BIAS_RANGE_FLOOR_M))


def los_error_mean(true_range_m: np.ndarray, los_mean_m: np.ndarray | float,
                   range_bias_per_m: np.ndarray | float,
                   range_bias_per_decade_m: np.ndarray | float = 0.0) -> np.ndarray:
    """Mean LOS range error mu_i + beta_i r + gamma_i log10(r / 1 m) [m].

    beta (``range_bias_per_m``) is a clock-scale error; gamma (``range_bias_per_decade_m``) the
    received-power bias of leading-edge detection, which grows with the path loss, i.e. linearly in
    log range. The gamma term is evaluated only where it is not zero, so scenarios without it draw
    exactly what they drew before it existed.
    """
    out = los_mean_m + range_bias_per_m * true_range_m
    if np.asarray(range_bias_per_decade_m).any():  # (a method: no function-wrapper overhead)
        out = out + range_bias_per_decade_m * range_decades(true_range_m)
    return out


def _norm_logpdf(x: np.ndarray, mean: np.ndarray | float, std: np.ndarray | float) -> np.ndarray:
    return -0.5 * ((x - mean) / std) ** 2 - np.log(std) - 0.5 * np.log(2.0 * np.pi)


def range_error_log_components(err_m: np.ndarray, true_range_m: np.ndarray, *, los_mean_m: float,
                               range_bias_per_m: float, los_std_m: float, nlos_prob: float,
                               mode_weights: np.ndarray, mode_mean_m: np.ndarray,
                               mode_std_m: np.ndarray, range_bias_per_decade_m: float = 0.0) -> np.ndarray:
    """Log joint density of each error component, shape (1 + K, N): row 0 LOS, rows 1.. the NLOS modes.

    This is the distribution :func:`range_error` samples from (eq. 3: NLOS replaces the LOS error),
    written as a mixture over the rows' marginal NLOS probability; the calibration's EM fit
    maximises its log-sum-exp.
    """
    comp = [np.log(max(1.0 - nlos_prob, 1e-300))
            + _norm_logpdf(err_m, los_error_mean(true_range_m, los_mean_m, range_bias_per_m, range_bias_per_decade_m),
                           los_std_m)]
    for w, m, sd in zip(mode_weights, mode_mean_m, mode_std_m, strict=True):
        comp.append(np.log(max(nlos_prob * w, 1e-300)) + _norm_logpdf(err_m, m, sd))
    return np.stack(comp)


def los_errors(true_range_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays, z: np.ndarray) -> np.ndarray:
    """LOS range errors [m] of rows from their standard normal draws ``z``: N(mu_i + beta_i r + gamma_i
    log10 r, sigma_i^2) of each row's anchor i."""
    decade = by_label(ch.range_bias_per_decade_m, anchor) if ch.range_bias_per_decade_m.any() else 0.0  # 0: off
    return (los_error_mean(true_range_m, by_label(ch.los_mean_m, anchor), by_label(ch.range_bias_per_m, anchor),
                           decade)
            + by_label(ch.los_std_m, anchor) * z)


def range_error(true_range_m: np.ndarray, anchor: np.ndarray, nlos: np.ndarray, mode: np.ndarray,
                ch: ChannelArrays, *, rng: np.random.Generator, episode: np.ndarray | None = None) -> np.ndarray:
    """Range errors [m] of rows: LOS Gaussian N(mu_i + beta_i r + gamma_i log10 r, sigma_i^2), replaced where
    NLOS by the offset of the episode's mixture mode (rows made NLOS by a zone alone draw a mode by weight).

    Rows of an episode (``episode``: one id per episode, -1 outside) of a mode with a held offset
    share one draw of the offset plus their own jitter; these draws come after all others, so a
    scenario without held modes draws exactly as before.
    """
    err = los_errors(true_range_m, anchor, ch, rng.standard_normal(true_range_m.shape[0]))
    in_episode = mode >= 0
    ep = np.flatnonzero(in_episode)  # row indices: the NLOS rows are few, each gather then a short one
    nl = np.flatnonzero(nlos)
    zone_only = nl[mode.take(nl) < 0]  # NLOS outside an episode
    err[ep] = sample_nlos_offset(anchor.take(ep), ch, rng=rng, mode=mode.take(ep))
    err[zone_only] = sample_nlos_offset(anchor.take(zone_only), ch, rng=rng)
    if episode is not None and ep.size and np.isfinite(ch.mode_held_jitter_m).any():  # a held mode
        jit = np.full(err.shape[0], np.nan)
        jit[in_episode] = ch.mode_held_jitter_m[anchor[in_episode], mode[in_episode]]
        held = np.isfinite(jit)
        if held.any():
            ids, first, inv = np.unique(episode[held], return_index=True, return_inverse=True)
            a_ep, m_ep = anchor[held][first], mode[held][first]
            value = ch.mode_mean_m[a_ep, m_ep] + ch.mode_std_m[a_ep, m_ep] * rng.standard_normal(ids.size)
            err[held] = value[inv] + jit[held] * rng.standard_normal(int(held.sum()))
    return err
