"""Map-style ``torch.utils.data.Dataset`` s of network windows, over stored and over generated traces.

Every item is one window of :func:`~physynth.track.features.network_arrays` as a dict of tensors:
``x`` (W, A, 9) float32 per-anchor features, ``anchor_ok`` (A,) bool, ``acc`` (W, 3) float32, ``g``
(W, 12) float32 per-step features (15 with the ``ekf`` prior), ``has_imu`` () bool, ``y`` (W, 3) float32
relative truth / length scale, ``y_ok`` (W,) bool. :func:`collate_windows` pads the anchor axis of a batch
to its largest anchor count (``anchor_ok`` False on padding), so traces with different anchor counts mix
in one batch.

- :class:`TraceWindows`: windows of stored traces (a dataset directory, Trace records or TrackInputs).
- :class:`SyntheticWindows`: trace ``i`` is generated on the fly from its own seed
  (``SeedSequence(root_seed, spawn_key=(i, component))``, DESIGN section 3) with an optional
  variation of path (:mod:`physynth.track.synth`) and anchor layout, so item ``j`` is the same in
  every DataLoader worker, epoch and process; a small per-process LRU cache keeps the last few traces.
- :class:`IsometryWindows`: the windows of another dataset, each turned about the vertical axis through
  the anchor centroid by a uniform angle and mirrored with probability 1/2 (a fixed draw per item). A
  range is a distance, so a turned window is what the same run gives in a turned world: a network trained
  on such windows cannot learn the heading of its training paths instead of the geometry.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ArgumentError
from ..transform import isometry_matrix
from . import require_torch
from .features import NetArrays, network_arrays, route_frame, window_starts
from .inputs import TrackInput, track_input

torch = require_torch()


@dataclass(frozen=True, slots=True, kw_only=True)
class WindowSpec:
    """Windows of ``length`` network steps every ``stride`` steps; network step = ``decimation`` grid steps."""

    length: int = 64
    stride: int = 16
    decimation: int = 10
    length_scale_m: float = 10.0
    anchor_scale_m: float = 2.0
    use_imu: bool = False
    age_weighted_direction: bool = True
    route_frame: bool = False  # every trace turned into its own route frame (features.route_frame)
    ekf_prior: bool = False  # the ekf position appended to g (features.network_arrays)

    def arrays(self, inp: TrackInput, *, turn: bool = True) -> NetArrays:
        """The network arrays of ``inp`` under this spec (``turn=False``: not turned into the route frame)."""
        arr = network_arrays(inp, decimation=self.decimation, length_scale_m=self.length_scale_m,
                             anchor_scale_m=self.anchor_scale_m, use_imu=self.use_imu,
                             age_weighted_direction=self.age_weighted_direction, ekf_prior=self.ekf_prior)
        return route_frame(arr)[0] if self.route_frame and turn else arr

    def __post_init__(self) -> None:
        if min(self.length, self.stride, self.decimation) < 1 or self.length_scale_m <= 0:
            raise ArgumentError(f"invalid WindowSpec: {self!r}")


def window_item(arr: NetArrays, start: int, length: int) -> dict[str, Any]:
    """One window of ``arr`` starting at network step ``start`` (zero-padded past the end, y_ok False)."""
    n = arr.x.shape[0]
    sl = slice(start, min(start + length, n))
    pad = length - (sl.stop - sl.start)

    def cut(a: np.ndarray) -> np.ndarray:
        a = a[sl]
        return np.concatenate([a, np.zeros((pad, *a.shape[1:]), a.dtype)]) if pad else a

    return {
        "x": torch.from_numpy(np.ascontiguousarray(cut(arr.x))),
        "anchor_ok": torch.ones(arr.x.shape[1], dtype=torch.bool),
        "acc": torch.from_numpy(np.ascontiguousarray(cut(arr.acc))),
        "g": torch.from_numpy(np.ascontiguousarray(cut(arr.g))),
        "has_imu": torch.tensor(arr.has_imu),
        "y": torch.from_numpy(np.ascontiguousarray(cut(arr.y))),
        "y_ok": torch.from_numpy(np.ascontiguousarray(cut(arr.y_ok))),
    }


def collate_windows(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Stack window items into a batch, padding the anchor axis to the largest anchor count."""
    a_max = max(int(it["x"].shape[1]) for it in items)
    xs, oks = [], []
    for it in items:
        pad = a_max - int(it["x"].shape[1])
        xs.append(torch.nn.functional.pad(it["x"], (0, 0, 0, pad)) if pad else it["x"])
        oks.append(torch.nn.functional.pad(it["anchor_ok"], (0, pad), value=False) if pad else it["anchor_ok"])
    return {
        "x": torch.stack(xs), "anchor_ok": torch.stack(oks),
        "acc": torch.stack([it["acc"] for it in items]), "g": torch.stack([it["g"] for it in items]),
        "has_imu": torch.stack([it["has_imu"] for it in items]),
        "y": torch.stack([it["y"] for it in items]), "y_ok": torch.stack([it["y_ok"] for it in items]),
    }


ISOMETRY_COMPONENT = 11
"""spawn_key component of the per-item draws of :class:`IsometryWindows`."""


def turn_window(item: dict[str, Any], matrix: np.ndarray) -> dict[str, Any]:
    """``item`` as seen in a world moved by the isometry ``matrix`` (about the anchor centroid).

    Every vector feature turns with the world: the anchor positions (``x[..., 1:4]``), the far-field
    directions and their scaled copies (every three columns of ``g``), the ENU acceleration and the target;
    ranges, ages and flags are distances and counts and do not change. The same as building the window
    from the moved trace (``tests/test_isometry.py``). Leading batch axes are allowed; ``y`` is optional.
    """
    m = torch.from_numpy(np.ascontiguousarray(matrix.T, dtype=np.float32)).to(item["x"].device)
    x = item["x"].clone()
    x[..., 1:4] = x[..., 1:4] @ m
    g = item["g"].clone()
    for j in range(0, g.shape[-1], 3):  # every per-step feature is a 3-vector
        g[..., j:j + 3] = g[..., j:j + 3] @ m
    out = {**item, "x": x, "g": g, "acc": item["acc"] @ m}
    if "y" in item:
        out["y"] = item["y"] @ m
    return out


class IsometryWindows(torch.utils.data.Dataset):
    """The items of ``base``, item ``j`` turned by its own isometry (see :func:`turn_window`).

    The angle is uniform on [0, 2 pi) and the mirror has probability ``mirror_prob``, both drawn from
    ``SeedSequence(seed, spawn_key=(j, ISOMETRY_COMPONENT))``: the same in every epoch and process.
    """

    def __init__(self, base: Any, seed: int, *, mirror_prob: float = 0.5) -> None:
        if not 0.0 <= mirror_prob <= 1.0:
            raise ValueError(f"mirror_prob must be in [0, 1], got {mirror_prob}")
        self.base, self.seed, self.mirror_prob = base, int(seed), float(mirror_prob)

    def __len__(self) -> int:
        return len(self.base)

    def matrix(self, j: int) -> np.ndarray:
        """The isometry of item ``j``."""
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(int(j), ISOMETRY_COMPONENT)))
        yaw = float(rng.uniform(0.0, 2.0 * np.pi))
        return isometry_matrix(yaw, bool(rng.random() < self.mirror_prob))

    def __getitem__(self, j: int) -> dict[str, Any]:
        return turn_window(self.base[j], self.matrix(j))


class TraceWindows(torch.utils.data.Dataset):
    """Windows over stored traces: a dataset directory, Trace records or ready :class:`TrackInput` s.

    ``time_offset_s`` is the UWB lag removed before the grid is built (:func:`track_input`); ``height``
    the tag's :class:`~physynth.track.height.HeightPrior` given to traces (TrackInputs keep their own).
    """

    def __init__(self, source: str | os.PathLike | Sequence[Any], spec: WindowSpec = WindowSpec(), *,
                 time_offset_s: float = 0.0, height: Any = None) -> None:
        if isinstance(source, (str, os.PathLike)):
            from ..io.dataset import read_dataset

            source = read_dataset(source).traces
        inputs = [s if isinstance(s, TrackInput) else track_input(s, time_offset_s=time_offset_s, height=height)
                  for s in source]
        self.spec = spec
        self.arrays = [spec.arrays(i) for i in inputs]
        self.index = [(t, int(s)) for t, a in enumerate(self.arrays)
                      for s in window_starts(a.x.shape[0], spec.length, spec.stride)]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict[str, Any]:
        t, s = self.index[i]
        return window_item(self.arrays[t], s, self.spec.length)


class SyntheticWindows(torch.utils.data.Dataset):
    """``windows_per_trace`` windows of each of ``n_traces`` traces generated on the fly.

    Item ``j`` is window ``j % windows_per_trace`` of trace ``j // windows_per_trace``; the windows of a
    trace are evenly spaced over it. Trace ``i`` depends only on ``(scenario, root_seed, i, variation)``.
    ``cache_size`` traces are kept per process (items of one trace are usually requested together);
    ``height``: the tag's :class:`~physynth.track.height.HeightPrior` every trace's input carries.
    """

    def __init__(self, scenario: Any, n_traces: int, root_seed: int, spec: WindowSpec = WindowSpec(), *,
                 windows_per_trace: int = 16, variation: Any = None, cache_size: int = 4,
                 height: Any = None) -> None:
        from ..generate import compile_scenario
        from .synth import with_variation

        if n_traces < 1 or windows_per_trace < 1:
            raise ValueError("n_traces and windows_per_trace must be >= 1")
        self.scenario = scenario
        self.compiled = compile_scenario(scenario if variation is None else with_variation(scenario, variation))
        self.n_traces, self.root_seed = int(n_traces), int(root_seed)
        self.spec, self.windows_per_trace, self.variation = spec, int(windows_per_trace), variation
        self.time_offset_s = float(scenario.uwb.time_offset_s)
        self.cache_size = int(cache_size)
        self.height = height
        self._cache: OrderedDict[int, NetArrays] = OrderedDict()

    def __len__(self) -> int:
        return self.n_traces * self.windows_per_trace

    def trace(self, i: int) -> Any:
        """Trace ``i`` (a :class:`~physynth.records.Trace`)."""
        from ..generate import generate_trace

        return generate_trace(self.compiled, i, self.root_seed)

    def arrays(self, i: int) -> NetArrays:
        """Network arrays of trace ``i`` (cached)."""
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        inp = track_input(self.trace(i), time_offset_s=self.time_offset_s, height=self.height)
        arr = self.spec.arrays(inp)
        self._cache[i] = arr
        while len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return arr

    def __getitem__(self, j: int) -> dict[str, Any]:
        if not 0 <= j < len(self):
            raise IndexError(j)
        i, w = divmod(int(j), self.windows_per_trace)
        arr = self.arrays(i)
        n = arr.x.shape[0]
        last = max(n - self.spec.length, 0)
        start = 0 if self.windows_per_trace == 1 else round(w * last / (self.windows_per_trace - 1))
        return window_item(arr, int(start), self.spec.length)
