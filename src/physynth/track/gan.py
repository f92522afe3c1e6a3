"""AUG_GAN: a small conditional GAN of UWB range residuals, and traces augmented with its samples.

The residual of a real range is ``e = r - ||p(t - offset) - a_i||`` (measured minus geometric range at
the truth position, the UWB lag removed). The generator ``G(z, g / L) -> e`` (noise ``z`` of
``noise_dim``, geometric range ``g`` scaled by ``L = length_scale_m``) is trained against a discriminator
``D(e, g / L)`` with the non-saturating GAN loss (Adam, seeded), so the residual distribution may depend
on the range (the range-proportional bias and spread of the Hanyang runs).

:func:`augment_trace` replaces the noise of every valid real range: ``r' = g + G(z, g / L)``; times,
anchors and availability stay the real ones. Residuals are drawn independently per range (no time
correlation; the physics generator is the one that models NLOS episodes and bias drift).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..records import Trace, Uwb
from . import require_torch

torch = require_torch()
nn = torch.nn


def range_residuals(trace: Trace, time_offset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row index, geometric range [m], residual [m]) of the valid UWB rows with a known truth position."""
    u = trace.uwb
    pos = trace.truth.position_at(u.t_s - time_offset_s)
    geo = np.linalg.norm(pos - trace.anchors.pos_enu_m[u.anchor], axis=1)
    ok = u.valid & np.isfinite(geo)
    rows = np.flatnonzero(ok)
    return rows, geo[rows], u.range_m[rows] - geo[rows]


@dataclass(frozen=True, slots=True, kw_only=True)
class GanConfig:
    """Size and schedule of the residual GAN."""

    noise_dim: int = 4
    hidden: int = 64
    steps: int = 2000
    batch_size: int = 256
    lr: float = 1e-3
    length_scale_m: float = 10.0
    residual_scale_m: float = 0.5
    seed: int = 0


class ResidualGan:
    """Conditional GAN of range residuals; :meth:`fit` on real traces, :meth:`sample` per range."""

    def __init__(self, config: GanConfig | None = None) -> None:
        self.config = config or GanConfig()
        c = self.config
        torch.manual_seed(c.seed)
        self.gen = nn.Sequential(nn.Linear(c.noise_dim + 1, c.hidden), nn.LeakyReLU(0.2),
                                 nn.Linear(c.hidden, c.hidden), nn.LeakyReLU(0.2), nn.Linear(c.hidden, 1))
        self.disc = nn.Sequential(nn.Linear(2, c.hidden), nn.LeakyReLU(0.2),
                                  nn.Linear(c.hidden, c.hidden), nn.LeakyReLU(0.2), nn.Linear(c.hidden, 1))
        self.history: dict[str, list[float]] = {"d_loss": [], "g_loss": []}

    def fit(self, traces: Sequence[Trace], time_offset_s: float, progress: Any = None) -> ResidualGan:
        """Train on the residuals of ``traces`` for ``config.steps`` steps."""
        c = self.config
        parts = [range_residuals(t, time_offset_s) for t in traces]
        geo = np.concatenate([p[1] for p in parts]) / c.length_scale_m
        res = np.concatenate([p[2] for p in parts]) / c.residual_scale_m
        if res.size < 10:
            from ..errors import PhySynthError

            raise PhySynthError("AUG_GAN: fewer than 10 range residuals in the training runs")
        data = torch.tensor(np.stack([res, geo], axis=1), dtype=torch.float32)
        gen = torch.Generator().manual_seed(c.seed)
        opt_g = torch.optim.Adam(self.gen.parameters(), lr=c.lr, betas=(0.5, 0.9))
        opt_d = torch.optim.Adam(self.disc.parameters(), lr=c.lr, betas=(0.5, 0.9))
        bce = nn.functional.binary_cross_entropy_with_logits
        for step in range(c.steps):
            idx = torch.randint(0, data.shape[0], (c.batch_size,), generator=gen)
            real = data[idx]
            z = torch.randn(c.batch_size, c.noise_dim, generator=gen)
            fake = torch.cat([self.gen(torch.cat([z, real[:, 1:]], dim=1)), real[:, 1:]], dim=1)
            d_loss = (bce(self.disc(real), torch.ones(c.batch_size, 1))
                      + bce(self.disc(fake.detach()), torch.zeros(c.batch_size, 1)))
            opt_d.zero_grad()
            d_loss.backward()
            opt_d.step()
            g_loss = bce(self.disc(fake), torch.ones(c.batch_size, 1))
            opt_g.zero_grad()
            g_loss.backward()
            opt_g.step()
            self.history["d_loss"].append(float(d_loss.detach()))
            self.history["g_loss"].append(float(g_loss.detach()))
            if progress is not None and (step + 1) % 500 == 0:
                progress(f"AUG_GAN: GAN step {step + 1}/{c.steps}")
        return self

    def sample(self, geo_m: np.ndarray, seed: int) -> np.ndarray:
        """Residuals [m] (N,) for geometric ranges ``geo_m`` (N,) [m], reproducible for ``seed``."""
        c = self.config
        gen = torch.Generator().manual_seed(int(seed))
        z = torch.randn(geo_m.shape[0], c.noise_dim, generator=gen)
        g = torch.tensor(geo_m / c.length_scale_m, dtype=torch.float32)[:, None]
        with torch.no_grad():
            return self.gen(torch.cat([z, g], dim=1))[:, 0].numpy().astype(np.float64) * c.residual_scale_m


def augment_trace(trace: Trace, gan: ResidualGan, time_offset_s: float, seed: int) -> Trace:
    """``trace`` with the noise of every valid range (known truth) replaced by a GAN sample."""
    rows, geo, _ = range_residuals(trace, time_offset_s)
    r = trace.uwb.range_m.copy()
    r[rows] = np.maximum(geo + gan.sample(geo, seed), 0.0)
    u = trace.uwb
    uwb = Uwb(t_s=u.t_s, anchor=u.anchor, range_m=r, true_range_m=u.true_range_m, nlos=u.nlos, burst=u.burst,
              reason=u.reason, nlos_known=u.nlos_known)
    return Trace(truth=trace.truth, uwb=uwb, anchors=trace.anchors, imu=trace.imu,
                 meta={**trace.meta, "augmented": f"AUG_GAN residuals, seed {seed}"})
