"""Random streams: one independent stream per (trace index, model component).

Trace ``i`` of a dataset draws from ``SeedSequence(root, spawn_key=(i, COMPONENT_ID[name]))``, so it is
identical whatever the batch size, worker count or generation order (docs/data-and-metrics.md, section 2).
"""

from __future__ import annotations

import numpy as np

COMPONENT_ID = {"path": 0, "motion": 1, "imu": 2, "uwb": 3, "availability": 4, "attitude": 5, "imu_body": 6,
                "jitter": 7, "uwb_sway": 8, "uwb_tag": 9, "uwb_late": 10,
                "site": 100}
"""``site`` (the scenario's ``variation``: anchor layout and path per trace) is 100, the component the
tracking study's site variation has always drawn from, so its traces are those of the same section."""


def new_root_seed() -> int:
    """Fresh OS entropy as an int, to be stored in the dataset metadata when the user gave no seed."""
    return int(np.random.SeedSequence().entropy)


def component_rng(root_seed: int, trace_index: int, component: str) -> np.random.Generator:
    """The generator of one model component of one trace."""
    key = (int(trace_index), COMPONENT_ID[component])
    return np.random.default_rng(np.random.SeedSequence(int(root_seed), spawn_key=key))


def standard_normal_rows(rng: np.random.Generator, rows: int, n: int) -> np.ndarray:
    """(rows, n) independent standard normal draws, by the Box-Muller transform: 2.3x faster than
    ``rng.standard_normal`` for the 400 Hz IMU noise, where it was a third of a trace's time.

    Each pair is ``sqrt(-2 ln(1 - u)) * (cos, sin)(2 pi v)`` with ``u`` uniform in float64 (the radius:
    tails reach 8.6 sigma, as with NumPy's own float64 sampler) and ``v`` uniform in float32 (the angle:
    2^24 of them, 3.7e-7 rad apart; cos and sin in float32, relative error ~1e-7, as the IMU is written
    in float32). Exactly Gaussian in exact arithmetic, not an approximation of it; the stream differs
    from ``rng.standard_normal``'s (docs/data-and-metrics.md, section 2).
    """
    total = rows * n
    half = (total + 1) // 2
    radius = rng.random(half)
    np.subtract(1.0, radius, out=radius)  # (0, 1]: the log is finite
    np.log(radius, out=radius)
    radius *= -2.0
    np.sqrt(radius, out=radius)
    angle = rng.random(half, dtype=np.float32)
    angle *= np.float32(2.0 * np.pi)
    out = np.empty(2 * half)
    trig = np.empty(half, dtype=np.float32)  # cos, then sin, in float32; each times the radius into `out`
    np.multiply(np.cos(angle, out=trig), radius, out=out[:half])  # (float32 -> float64 is exact: the same
    np.multiply(np.sin(angle, out=trig), radius, out=out[half:])  # products as casting first, one pass fewer)
    return out[:total].reshape(rows, n)
