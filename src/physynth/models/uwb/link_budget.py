"""The link: the soft radio horizon and the link budget (received first-path power with the antenna
pattern, the two-ray ground reflection and the obstacles' losses; its detection probability).
"""

from __future__ import annotations

import numpy as np

from .arrays import ChannelArrays


def link_probability(range_m: np.ndarray, max_range_m: np.ndarray, edge_width_m: np.ndarray) -> np.ndarray:
    """Soft radio horizon: 1 / (1 + exp((r - max_range) / edge_width)), the exponent clipped to [-50, 50]."""
    x = np.subtract(range_m, max_range_m)
    if not isinstance(x, np.ndarray) or x.dtype != np.float64:  # scalars: no buffer to work in
        return 1.0 / (1.0 + np.exp(np.clip(x / edge_width_m, -50.0, 50.0)))
    x /= edge_width_m  # the steps of the line above, in one buffer (numpy.clip's values: max, then min)
    np.maximum(x, -50.0, out=x)
    np.minimum(x, 50.0, out=x)
    np.exp(x, out=x)
    x += 1.0
    return np.divide(1.0, x, out=x)


def ground_gain_db(horiz_m: np.ndarray, h_anchor_m: np.ndarray, h_tag_m: np.ndarray, reflection: np.ndarray,
                   wavelength_m: np.ndarray) -> np.ndarray:
    """Two-ray ground term 20 log10 |1 - rho exp(-j 2 pi Delta / lambda)| [dB] (0 where rho is 0).

    Heights above the ground plane [m] are clipped at 1 cm; Delta is the extra length of the ground path.
    """
    ha = np.maximum(h_anchor_m, 0.01)
    ht = np.maximum(h_tag_m, 0.01)
    delta = np.hypot(horiz_m, ha + ht) - np.hypot(horiz_m, ha - ht)
    phase = 2.0 * np.pi * delta / wavelength_m
    mag = np.hypot(1.0 - reflection * np.cos(phase), reflection * np.sin(phase))
    return 20.0 * np.log10(np.maximum(mag, 1e-6))


def received_power_dbm(tag_enu_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays,
                       obstacle_loss_db: np.ndarray | float = 0.0) -> np.ndarray:
    """Mean first-path power [dBm] of rows (tag (N, 3) [m], anchor index (N,)) under the link budget."""
    lb = ch.link
    assert lb is not None
    d = tag_enu_m - ch.anchor_pos_enu_m[anchor]  # anchor -> tag
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    r0 = lb.ref_distance_m[anchor]
    p = lb.ref_power_dbm[anchor] - 10.0 * lb.path_loss_exponent[anchor] * np.log10(np.maximum(r, r0) / r0)
    bore = lb.boresight_enu[anchor]
    cos_t = np.einsum("ij,ij->i", bore, d) / np.maximum(r, 1e-9)
    has_bore = np.any(bore != 0.0, axis=1)
    p = p - np.where(has_bore, lb.front_back_db[anchor] * (1.0 - cos_t) / 2.0, 0.0)
    rho = lb.ground_reflection[anchor]
    if np.any(rho > 0):
        g = lb.ground_u_m[anchor]
        h_tag = lb.tag_height_m[anchor]
        h_tag = np.where(np.isnan(h_tag), tag_enu_m[:, 2] - g, h_tag)
        p = p + ground_gain_db(np.hypot(d[:, 0], d[:, 1]), ch.anchor_pos_enu_m[anchor, 2] - g, h_tag,
                               rho, lb.wavelength_m[anchor])
    return p - obstacle_loss_db


def detection_probability(power_dbm: np.ndarray, sensitivity_dbm: np.ndarray,
                          shadowing_std_db: np.ndarray) -> np.ndarray:
    """P(power + shadowing > sensitivity) = Phi((power - sensitivity) / sigma) (a step where sigma is 0)."""
    from scipy.special import ndtr

    margin = power_dbm - sensitivity_dbm
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = ndtr(margin / np.where(shadowing_std_db > 0, shadowing_std_db, 1.0))
    return np.where(shadowing_std_db > 0, soft, (margin >= 0).astype(float))


def link_detection_probability(tag_enu_m: np.ndarray, anchor: np.ndarray, ch: ChannelArrays,
                               obstacle_loss_db: np.ndarray | float = 0.0) -> np.ndarray:
    """Per-row detection probability of the link budget (1 for anchors without one)."""
    lb = ch.link
    if lb is None:
        return np.ones(anchor.shape[0])
    p = detection_probability(received_power_dbm(tag_enu_m, anchor, ch, obstacle_loss_db),
                              lb.sensitivity_dbm[anchor], lb.shadowing_std_db[anchor])
    return np.where(lb.enabled[anchor], p, 1.0)
