"""Learned trackers: ``aoi-fusion`` (AoI-aware attention fusion) and ``bilstm``, trained with PyTorch.

Both read the windows of :mod:`physynth.track.torch_data` (per-anchor features on every
``decimation``-th grid step) and regress the position relative to the anchor centroid, divided by
``length_scale_m``. The loss is the mean squared position error over the steps of a window after its
first ``burn_in_steps`` (the recurrent state has warmed up) where the truth is known.

``aoi-fusion`` (in the spirit of AoI-FusionNet, paper ref. [9]):

- a shared per-anchor embedding ``e_i = MLP(range_i, anchor_pos_i, fresh_i, aoi_i, has_range_i)``;
- ``heads`` attention heads with logits ``w_h . e_i - softplus(g_h(aoi_i))``: a learned, per-head AoI
  penalty, so stale anchors lose weight; anchors without a range and padding are masked, and a learned
  "null" slot keeps the softmax defined when no anchor has a range; the pooled values of all heads
  and the masked mean embedding form the fused vector. Any number and layout of anchors;
- an IMU branch (MLP of the bin-mean acceleration, multiplied by the has-IMU flag, so it can be absent);
- a recurrent temporal model (``rnn="gru"`` or ``"lstm"``) and an MLP position head.

With ``likelihood`` (the default) the head also gives a log-variance per axis and the loss is the
beta-NLL (:func:`masked_loss`); prediction floors the vertical variance by what the geometry allows and
combines the vertical with what is known without the ranges (:mod:`physynth.track.fallback`).

``bilstm``: the anchors' features concatenated in their order (padded to the anchor count seen in
training) and the acceleration, a linear layer, a bidirectional LSTM and a linear head.

Prediction runs the network over windows of ``window_steps`` overlapping by ``burn_in_steps`` (the
training conditions), keeps each window's steps after the burn-in, and interpolates the positions back
onto every grid step. Training runs on the GPU when one is present (``device="auto"``) and is
deterministic for a seed on the CPU.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from ...errors import PhySynthError
from .. import require_torch
from ..features import (
    EKF_PRIOR_COAST_S,
    N_ANCHOR_FEATURES,
    N_EKF_FEATURES,
    N_GLOBAL_FEATURES,
    check_ekf_prior,
    route_frame,
    upsample,
    window_starts,
)
from ..inputs import TrackInput
from ..torch_data import WindowSpec
from .base import ProgressFn

torch = require_torch()
nn = torch.nn
F = torch.nn.functional


@dataclass(frozen=True, slots=True, kw_only=True)
class NetConfig:
    """Architecture, windows and schedule of a learned tracker (lengths in network steps).

    ``window.age_weighted_direction``: the far-field direction input weights each range by its age
    (:func:`~physynth.track.features.network_arrays`); False restores the unweighted solve.
    ``random_isometry``: every training window is turned about the vertical through the anchor
    centroid by a uniform angle and mirrored with probability 1/2
    (:class:`~physynth.track.torch_data.IsometryWindows`), so the network learns the geometry of
    ranges and anchors, not the heading of its training paths; a test run along another direction then
    works (docs/tracking.md, "Runs in other directions"). Such a network also predicts on
    ``test_isometries`` copies of the test run (1, 2, 4 or 8: the turns by multiples of 90 deg, with their
    mirror images from 2 on) and averages the predictions moved back (test-time augmentation; 1: none).
    ``window.route_frame``: every run, for training and for prediction, is turned so that its route heading,
    estimated from its own ranges, points east (:func:`~physynth.track.features.route_frame`): the network
    learns the shape of the routes relative to their heading, not their compass heading, and is lost on
    a route of another shape (docs/tracking.md, the synthetic loop). Excludes ``random_isometry``.
    """

    hidden: int = 64
    heads: int = 4
    rnn: str = "gru"
    layers: int = 1
    window: WindowSpec = WindowSpec()
    """The windows the network reads and how their features are built (length and stride in network steps,
    the decimation, the scales, IMU, direction weighting, route frame); its ``ekf_prior`` follows
    :attr:`ekf_prior` (``none``: False)."""
    burn_in_steps: int = 8
    batch_size: int = 32
    epochs: int = 200
    lr: float = 1e-3
    weight_decay: float = 0.0
    grad_clip: float = 5.0
    lr_schedule: str = "constant"
    """``constant``: Adam at the stage's learning rate throughout; ``cosine``: the rate falls from the
    stage's value to 0 over its steps along half a cosine (``torch.optim.lr_scheduler.CosineAnnealingLR``),
    so each stage ends on small steps instead of stopping wherever the last large one landed."""
    weight_average: str = "none"
    """``none``: each stage ends on its last weights; ``swa``: on the equal-weight average of the weights
    after each epoch of the stage's second half (stochastic weight averaging at the stage's constant rate,
    ``torch.optim.swa_utils.AveragedModel``; the nets have no batch statistics to recompute)."""
    ekf_prior: str = "none"
    """``none``; ``input``: the position of the classical ``ekf`` tracker run on the same inputs is one more
    per-step input (:func:`~physynth.track.features.ekf_prior_rel_m`); ``residual``: that input, and the
    network's output is added to it, so the network learns a correction of the filter (where it coasts
    through an outage or follows a wrong range) instead of the position itself."""
    random_isometry: bool = False
    test_isometries: int = 8
    likelihood: bool = True
    """The head gives a mean and a log-variance per axis, trained with the beta-NLL (Gaussian negative
    log-likelihood weighted by the detached variance to the power ``nll_beta``, so the mean learns as
    with squared error); prediction then floors the vertical variance by the geometry's and falls back to
    the known height or the ``ekf`` (:mod:`physynth.track.fallback`). False: the mean alone, squared error."""
    nll_beta: float = 0.5
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        if isinstance(self.window, dict):  # as :meth:`to_dict` gives it
            object.__setattr__(self, "window", WindowSpec(**self.window))
        if not isinstance(self.window, WindowSpec):
            raise PhySynthError(f"window must be a WindowSpec, got {type(self.window).__name__}")
        if self.window.ekf_prior != (self.ekf_prior != "none"):  # the windows carry the prior the net uses
            object.__setattr__(self, "window", replace(self.window, ekf_prior=self.ekf_prior != "none"))
        if self.test_isometries not in (1, 2, 4, 8):
            raise PhySynthError(f"test_isometries must be 1, 2, 4 or 8, got {self.test_isometries}")
        if self.window.route_frame and self.random_isometry:
            raise PhySynthError("route_frame and random_isometry exclude each other (a route frame keeps the "
                                "routes' heading relative to themselves; random turns remove it)")
        if self.lr_schedule not in ("constant", "cosine"):
            raise PhySynthError(f"lr_schedule must be constant or cosine, got '{self.lr_schedule}'")
        check_ekf_prior(self.ekf_prior)
        if self.weight_average not in ("none", "swa"):
            raise PhySynthError(f"weight_average must be none or swa, got '{self.weight_average}'")
        if not 0.0 <= self.nll_beta <= 1.0:
            raise PhySynthError(f"nll_beta must be in [0, 1], got {self.nll_beta}")
        if self.rnn not in ("gru", "lstm"):
            raise PhySynthError(f"unknown recurrent model '{self.rnn}' (gru or lstm)")
        if self.burn_in_steps >= self.window.length:
            raise PhySynthError("burn_in_steps must be smaller than window_steps")
        if min(self.hidden, self.heads, self.layers, self.batch_size) < 1 or self.hidden % self.heads:
            raise PhySynthError(f"invalid network configuration: {self!r}")

    @classmethod
    def from_settings(cls, **settings: Any) -> NetConfig:
        """A configuration from its settings by name (:data:`NET_SETTINGS`: the fields, with the window's
        by their own names, ``window_steps=32``; see :meth:`with_settings`)."""
        return cls().with_settings(**settings)

    def with_settings(self, **settings: Any) -> NetConfig:
        """This configuration with ``settings`` changed: fields of its own, or the fields of its window by
        their names in :data:`WINDOW_SETTINGS` (``window_steps``, ``stride_steps``, ``decimation``,
        ``length_scale_m``, ``anchor_scale_m``, ``use_imu``, ``age_weighted_direction``, ``route_frame``);
        ``window`` itself as a :class:`~physynth.track.torch_data.WindowSpec` or a mapping of the fields it
        changes. How a study's ``net`` overrides, ``NetTracker(**overrides)`` and a saved state (:meth:`to_dict`)
        set a configuration."""
        own = {k: v for k, v in settings.items() if k not in WINDOW_SETTINGS}
        window = own.pop("window", self.window)
        if isinstance(window, dict):
            window = replace(self.window, **window)
        moved = {WINDOW_SETTINGS[k]: v for k, v in settings.items() if k in WINDOW_SETTINGS}
        return replace(self, window=replace(window, **moved) if moved else window, **own)

    def to_dict(self) -> dict[str, Any]:
        """The fields, the window's as a mapping of its own: ``NetConfig(**d)`` and :meth:`from_settings`
        take it back (a saved state's; one of a release before the window, with the window's fields
        among the others, reads back with :meth:`from_settings`)."""
        return asdict(self)

    @property
    def n_global(self) -> int:
        """Per-step features the networks read (``g``): 12, 15 with the ``ekf`` prior."""
        return N_GLOBAL_FEATURES + (N_EKF_FEATURES if self.ekf_prior != "none" else 0)


WINDOW_SETTINGS = {"window_steps": "length", "stride_steps": "stride", "decimation": "decimation",
                   "length_scale_m": "length_scale_m", "anchor_scale_m": "anchor_scale_m", "use_imu": "use_imu",
                   "age_weighted_direction": "age_weighted_direction", "route_frame": "route_frame"}
"""The settings of :class:`NetConfig` that are fields of its window (:attr:`NetConfig.window`), by setting
name: the field of :class:`~physynth.track.torch_data.WindowSpec` each one sets."""
NET_SETTINGS = frozenset({*(f.name for f in fields(NetConfig) if f.name != "window"), *WINDOW_SETTINGS})
"""The settings of a :class:`NetConfig` by name (:meth:`NetConfig.with_settings`): a study's ``net``
overrides (:class:`~physynth.studies.tracking_config.StudyConfig`), ``NetTracker(**overrides)``."""


LOG_VAR_RANGE = (-12.0, 6.0)
"""Clamp of the predicted log-variance (in units of ``length_scale_m``^2: about 2.5 mm to 200 m of spread
at 10 m)."""


def _n_out(cfg: NetConfig) -> int:
    """Head outputs: the position (3), and its log-variance per axis (3) with ``likelihood``."""
    return 6 if cfg.likelihood else 3


def _with_prior(out: Any, g: Any, cfg: NetConfig) -> Any:
    """The network output, plus the ``ekf`` position (the last three columns of ``g``) for ``residual``
    (the position part only; a log-variance part is clamped to :data:`LOG_VAR_RANGE`)."""
    mean = out[..., :3] + g[..., -N_EKF_FEATURES:] if cfg.ekf_prior == "residual" else out[..., :3]
    if not cfg.likelihood:
        return mean
    return torch.cat([mean, out[..., 3:].clamp(*LOG_VAR_RANGE)], dim=-1)


def _mlp(n_in: int, hidden: int, n_out: int) -> nn.Module:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.GELU(), nn.Linear(hidden, n_out))


class AoIFusionNet(nn.Module):
    """AoI-aware attention fusion over a set of anchors, then a recurrent model (module docstring)."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        h, self.heads, self.cfg = cfg.hidden, cfg.heads, cfg
        self.embed = nn.Sequential(nn.Linear(N_ANCHOR_FEATURES, h), nn.GELU(), nn.Linear(h, h), nn.GELU())
        self.score = nn.Linear(h, cfg.heads)
        self.aoi_penalty = _mlp(1, 16, cfg.heads)
        self.value = nn.Linear(h, h)
        self.null_logit = nn.Parameter(torch.zeros(cfg.heads))
        self.null_value = nn.Parameter(torch.zeros(h))
        self.imu = _mlp(3, h // 2, h // 2)
        self.fuse = nn.Sequential(nn.Linear(2 * h + h // 2 + cfg.n_global, h), nn.GELU())
        rnn = nn.GRU if cfg.rnn == "gru" else nn.LSTM
        self.rnn = rnn(h, h, num_layers=cfg.layers, batch_first=True)
        self.head = _mlp(h, h, _n_out(cfg))

    def forward(self, x: Any, anchor_ok: Any, acc: Any, has_imu: Any, g: Any) -> Any:
        """x (B, T, A, 9), anchor_ok (B, A), acc (B, T, 3), has_imu (B,), g (B, T, 6) -> positions (B, T, 3)."""
        b, t, a, _ = x.shape
        e = self.embed(x)  # (B, T, A, H)
        avail = anchor_ok[:, None, :] & (x[..., 6] > 0.5)  # (B, T, A)
        logits = self.score(e) - F.softplus(self.aoi_penalty(x[..., 5:6]))  # (B, T, A, heads)
        logits = logits.masked_fill(~avail[..., None], float("-inf"))
        logits = torch.cat([logits, self.null_logit.expand(b, t, 1, self.heads)], dim=2)
        w = torch.softmax(logits, dim=2)  # over anchors + null slot
        v = torch.cat([self.value(e), self.null_value.expand(b, t, 1, -1)], dim=2)
        dh = v.shape[-1] // self.heads
        pooled = torch.einsum("btah,btahd->bthd", w, v.view(b, t, a + 1, self.heads, dh)).reshape(b, t, -1)
        m = avail[..., None].to(e.dtype)
        mean = (e * m).sum(dim=2) / m.sum(dim=2).clamp(min=1.0)
        imu = self.imu(acc) * has_imu[:, None, None].to(e.dtype)
        z = self.fuse(torch.cat([pooled, mean, imu, g], dim=-1))
        out, _ = self.rnn(z)
        return _with_prior(self.head(out), g, self.cfg)


class BiLstmNet(nn.Module):
    """Concatenated per-anchor features (fixed anchor order) -> bidirectional LSTM -> position."""

    def __init__(self, cfg: NetConfig, n_anchors: int) -> None:
        super().__init__()
        self.n_anchors, self.cfg = n_anchors, cfg
        n_in = n_anchors * N_ANCHOR_FEATURES + 3 + cfg.n_global
        self.inp = nn.Sequential(nn.Linear(n_in, cfg.hidden), nn.GELU())
        self.rnn = nn.LSTM(cfg.hidden, cfg.hidden, num_layers=cfg.layers, batch_first=True, bidirectional=True)
        self.head = nn.Linear(2 * cfg.hidden, _n_out(cfg))

    def forward(self, x: Any, anchor_ok: Any, acc: Any, has_imu: Any, g: Any) -> Any:
        b, t, a, f = x.shape
        if a > self.n_anchors:
            raise PhySynthError(f"bilstm was trained on {self.n_anchors} anchors, got a trace with {a}")
        x = x * anchor_ok[:, None, :, None].to(x.dtype)
        if a < self.n_anchors:
            x = F.pad(x, (0, 0, 0, self.n_anchors - a))
        flat = torch.cat([x.reshape(b, t, -1), acc * has_imu[:, None, None].to(x.dtype), g], dim=-1)
        out, _ = self.rnn(self.inp(flat))
        return _with_prior(self.head(out), g, self.cfg)


def masked_loss(pred: Any, batch: dict[str, Any], burn_in: int, nll_beta: float | None = None) -> Any:
    """Mean loss over the steps after ``burn_in`` where the truth is known: the squared position error for
    a (B, T, 3) prediction; for a (B, T, 6) one (mean, log-variance) the beta-NLL
    ``sum_axes (log v + (y - m)^2 / v) / 2 * v.detach()^beta`` (Seitzer et al., ICLR 2022: beta 0 is the
    Gaussian NLL, beta 1 trains the mean as squared error does)."""
    ok = batch["y_ok"].clone()
    ok[:, :burn_in] = False
    err2 = (pred[..., :3] - batch["y"]) ** 2
    if pred.shape[-1] == 3:
        per = err2.sum(dim=-1)
    else:
        log_v = pred[..., 3:]
        var = log_v.exp()
        per = (0.5 * (log_v + err2 / var) * var.detach() ** float(nll_beta or 0.0)).sum(dim=-1)
    return (per * ok).sum() / ok.sum().clamp(min=1)


def mean_sq_error(pred: Any, batch: dict[str, Any], burn_in: int) -> Any:
    """The mean squared position error of the same steps as :func:`masked_loss` (for the training log)."""
    ok = batch["y_ok"].clone()
    ok[:, :burn_in] = False
    return ((((pred[..., :3] - batch["y"]) ** 2).sum(dim=-1)) * ok).sum() / ok.sum().clamp(min=1)


class NetTracker:
    """A learned tracker (``aoi-fusion`` or ``bilstm``) behind the :class:`~.base.Tracker` interface.

    ``fit(inputs)`` trains from scratch (or continues, see :meth:`train`) for ``config.epochs`` at
    ``config.lr``. :meth:`train` takes any window dataset (e.g. synthetic traces generated on the fly)
    with its own epochs and learning rate, which is how pre-training and fine-tuning are done.
    """

    def __init__(self, arch: str = "aoi-fusion", config: NetConfig | None = None, **overrides: Any) -> None:
        if arch not in ("aoi-fusion", "bilstm"):
            raise PhySynthError(f"unknown network '{arch}' (aoi-fusion or bilstm)")
        self.arch = arch
        self.name = arch
        self.config = (config or NetConfig()).with_settings(**overrides)
        self.model: Any = None
        self.n_anchors = 0
        self.history: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ training
    def window_spec(self) -> WindowSpec:
        """The windows the network reads (``config.window``)."""
        return self.config.window

    def device(self) -> Any:
        """``config.device``; ``auto``: the GPU when one is present, else the CPU (deterministic there)."""
        if self.config.device == "auto":
            return torch.device("cuda" if torch.cuda.is_available() else "cpu")
        return torch.device(self.config.device)

    def _build(self, n_anchors: int) -> None:
        torch.manual_seed(self.config.seed)
        self.n_anchors = n_anchors
        model = AoIFusionNet(self.config) if self.arch == "aoi-fusion" else BiLstmNet(self.config, n_anchors)
        self.model = model.to(self.device())

    def fit(self, inputs: Sequence[TrackInput], *, progress: ProgressFn | None = None) -> NetTracker:
        """Train on the windows of ``inputs`` for ``config.epochs`` epochs at ``config.lr``."""
        from ..torch_data import TraceWindows

        self.train(TraceWindows(list(inputs), self.window_spec()), epochs=self.config.epochs, lr=self.config.lr,
                   stage="train", progress=progress)
        return self

    def train(self, dataset: Any, *, epochs: int, lr: float, stage: str = "train",
              progress: ProgressFn | None = None) -> list[float]:
        """Adam for ``epochs`` passes over ``dataset`` (shuffled by a seeded generator); mean loss per epoch."""
        from ..torch_data import collate_windows

        if len(dataset) == 0:
            raise PhySynthError(f"{stage}: no training windows")
        if self.model is None:
            self._build(int(dataset[0]["x"].shape[1]) if self.arch == "bilstm" else 0)
        c = self.config
        gen = torch.Generator().manual_seed(c.seed * 1000 + len(self.history))
        if c.random_isometry:
            from ..torch_data import IsometryWindows

            dataset = IsometryWindows(dataset, c.seed * 1000 + len(self.history))
        loader = torch.utils.data.DataLoader(dataset, batch_size=c.batch_size, shuffle=True, generator=gen,
                                             collate_fn=collate_windows, num_workers=0)
        opt = torch.optim.Adam(self.model.parameters(), lr=lr, weight_decay=c.weight_decay)
        sched = (torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(epochs * len(loader), 1))
                 if c.lr_schedule == "cosine" else None)
        swa = torch.optim.swa_utils.AveragedModel(self.model) if c.weight_average == "swa" else None
        self.model.train()
        dev = self.device()
        losses = []
        for ep in range(epochs):
            total, n = 0.0, 0
            for batch in loader:
                batch = {k: v.to(dev) for k, v in batch.items()}
                pred = self.model(batch["x"], batch["anchor_ok"], batch["acc"], batch["has_imu"], batch["g"])
                loss = masked_loss(pred, batch, c.burn_in_steps, c.nll_beta)
                opt.zero_grad()
                loss.backward()
                if c.grad_clip > 0:
                    nn.utils.clip_grad_norm_(self.model.parameters(), c.grad_clip)
                opt.step()
                if sched is not None:
                    sched.step()
                total += float(mean_sq_error(pred.detach(), batch, c.burn_in_steps)) * len(batch["x"])
                n += len(batch["x"])
            losses.append(total / max(n, 1))
            if swa is not None and ep >= epochs // 2:
                swa.update_parameters(self.model)
            if progress is not None:
                rmse = math.sqrt(max(losses[-1], 0.0)) * c.window.length_scale_m
                progress(f"{self.name} {stage}: epoch {ep + 1}/{epochs}, training RMSE {rmse:.3f} m")
        if swa is not None:
            self.model.load_state_dict(swa.module.state_dict())
        self.history.append({"stage": stage, "epochs": epochs, "lr": lr, "lr_schedule": c.lr_schedule,
                             "final_lr": float(opt.param_groups[0]["lr"]), "windows": len(dataset),
                             "weight_average": c.weight_average,
                             "averaged_epochs": 0 if swa is None else int(swa.n_averaged),
                             "random_isometry": c.random_isometry, "route_frame": c.window.route_frame,
                             "loss": losses})
        self.model.eval()
        return losses

    # ------------------------------------------------------------------ prediction
    def predict(self, inp: TrackInput) -> np.ndarray:
        """(K, 3) ENU [m]: overlapping windows, their steps after the burn-in, interpolated to the grid
        (with ``likelihood``, the vertical after the fallback of :meth:`predict_dist`)."""
        return self.predict_dist(inp)[0]

    def predict_dist(self, inp: TrackInput) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) ENU positions [m] and (K, 3) their variance per axis [m^2] (NaN without ``likelihood``).

        With ``likelihood`` the vertical variance is floored by the geometry's (one set of ranges at the
        estimate, :func:`~physynth.track.fallback.geometry_vertical_var`) and the vertical combined with
        what is known without the ranges (:func:`~physynth.track.fallback.fuse_vertical`): the input's
        height prior, or else the ``ekf``'s vertical and its variance.
        """
        if self.model is None:
            raise PhySynthError(f"{self.name}: predict before fit")
        c = self.config
        arr = self.window_spec().arrays(inp, turn=False)
        frame = np.eye(3)
        if c.window.route_frame:
            arr, frame = route_frame(arr)
        n, w, burn = arr.x.shape[0], c.window.length, c.burn_in_steps
        starts = window_starts(n, w, w - burn)
        idx = np.minimum(starts[:, None] + np.arange(w), n - 1)
        dev = self.device()
        x = torch.from_numpy(arr.x[idx]).to(dev)
        acc = torch.from_numpy(arr.acc[idx]).to(dev)
        ok = torch.ones(len(starts), arr.x.shape[1], dtype=torch.bool, device=dev)
        imu = torch.full((len(starts),), arr.has_imu, device=dev)
        g = torch.from_numpy(arr.g[idx]).to(dev)
        with torch.no_grad():
            pred = self._predict_windows(x, ok, acc, imu, g)
        out = np.full((n, pred.shape[-1]), np.nan)
        for j, s in enumerate(starts):  # each window's warm steps (all of the first window)
            keep = np.arange(w) >= (0 if s == 0 else burn)
            out[idx[j][keep]] = pred[j][keep]
        mean = (out[:, :3] @ frame) * c.window.length_scale_m  # back from the route frame
        var = np.full_like(mean, np.nan)
        if c.likelihood:
            var = (out[:, 3:] @ (frame * frame)) * c.window.length_scale_m**2
            mean, var = self._fallback(inp, arr, mean, var)
        pos = upsample(inp, arr.step, mean)
        var_k = upsample(inp, arr.step, var) - inp.ref_enu_m if c.likelihood else np.full_like(pos, np.nan)
        pos[inp.t_s < inp.first_range_s] = np.nan
        return pos, var_k

    def _fallback(self, inp: TrackInput, arr: Any, mean: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The vertical of ``mean``/``var`` (T, 3) [m, m^2] at the network steps ``arr.step`` after the
        geometry floor and the fallback (:meth:`predict_dist`)."""
        from ..fallback import fuse_vertical, geometry_vertical_var

        has = arr.x[:, :, 6] > 0.5
        var = var.copy()
        var[:, 2] = np.maximum(var[:, 2], geometry_vertical_var(mean, inp.anchor_pos_rel_m, has))
        if inp.height is not None:
            known_z, known_var = inp.height_rel_m, inp.height.std_m**2
        else:
            from .ekf import EkfTracker

            ekf = EkfTracker(use_imu=arr.has_imu, fit_range_std=False, max_coast_s=EKF_PRIOR_COAST_S)
            pos, vz = ekf.predict_rel_var(inp)
            known_z, known_var = pos[arr.step, 2], vz[arr.step]
        mean = mean.copy()
        mean[:, 2], var[:, 2] = fuse_vertical(mean[:, 2], var[:, 2], known_z, known_var)
        return mean, var

    def _isometries(self) -> list[np.ndarray]:
        from ...transform import isometry_matrix

        k = self.config.test_isometries if self.config.random_isometry else 1
        mirrors = (False, True) if k >= 2 else (False,)
        turns = max(k // len(mirrors), 1)
        return [isometry_matrix(2.0 * np.pi * i / turns, m) for m in mirrors for i in range(turns)]

    def _predict_windows(self, x: Any, ok: Any, acc: Any, imu: Any, g: Any) -> np.ndarray:
        """Network outputs (B, W, 3) in the test frame, averaged over the test-time isometries; with
        ``likelihood`` (B, W, 6): the mean and the variance per axis of the mixture of the turned copies
        (in units of ``length_scale_m``)."""
        from ..torch_data import turn_window

        mats = self._isometries()
        n = x.shape[0]
        if len(mats) == 1:
            outs = [self.model(x, ok, acc, imu, g).cpu().numpy().astype(np.float64)]
        else:
            moved = [turn_window({"x": x, "g": g, "acc": acc}, m) for m in mats]
            out = self.model(torch.cat([d["x"] for d in moved]), ok.repeat(len(mats), 1),
                             torch.cat([d["acc"] for d in moved]), imu.repeat(len(mats)),
                             torch.cat([d["g"] for d in moved])).cpu().numpy().astype(np.float64)
            outs = [out[i * n:(i + 1) * n] for i in range(len(mats))]
        means = np.stack([o[..., :3] @ m for o, m in zip(outs, mats, strict=True)])  # y = y' M for y' = y M^T
        if not self.config.likelihood:
            return means.mean(axis=0)
        var = np.mean([np.exp(o[..., 3:]) @ (m * m) for o, m in zip(outs, mats, strict=True)], axis=0)
        return np.concatenate([means.mean(axis=0), var + means.var(axis=0)], axis=-1)

    # ------------------------------------------------------------------ persistence
    def state(self) -> dict[str, Any]:
        """A torch-saveable dict: architecture, configuration, anchor count and weights."""
        weights = None if self.model is None else {k: v.cpu() for k, v in self.model.state_dict().items()}
        return {"arch": self.arch, "config": self.config.to_dict(), "n_anchors": self.n_anchors, "weights": weights}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> NetTracker:
        # a state saved before the likelihood head has none: its config leaves the field out
        tr = cls(state["arch"], NetConfig.from_settings(**{"likelihood": False, **state["config"]}))
        tr._build(state["n_anchors"])
        try:
            tr.model.load_state_dict(state["weights"])
        except RuntimeError as exc:  # a state saved by a release with other inputs (e.g. 6 per-step features)
            raise PhySynthError(f"this network state does not fit this release's {state['arch']} inputs "
                                f"({tr.config.n_global} per-step features); retrain it: "
                                f"{str(exc).splitlines()[0]}") from None
        tr.model.eval()
        return tr
