"""Small linear filters shared by the models, without importing scipy.signal (0.9 s) on every command."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

_CACHED_BLOCK = 4096  # longest block whose powers are cached (rho up to ~0.95)


@lru_cache(maxsize=32)
def _powers(rho: float, block: int) -> tuple[np.ndarray, np.ndarray]:
    """(rho^-j, rho^j) for j = 0 .. block - 1, built once per (rho, block) and read-only."""
    j = np.arange(block)
    up, down = rho ** -j, rho ** j
    up.setflags(write=False)
    down.setflags(write=False)
    return up, down


def ar1(x_ck: np.ndarray, rho: float) -> np.ndarray:
    """y_k = x_k + rho y_(k-1) along the last axis (what scipy.signal.lfilter([1], [1, -rho]) computes,
    to rounding), without importing scipy.signal (0.9 s) on every command.

    Closed form per block of B knots: y_(b+j) = rho^j (y_(b-1) rho + sum_(i<=j) x_(b+i) rho^-i), with B
    chosen so that rho^-B stays far from overflow; a loop over blocks (one or a few per trace).
    """
    y = np.empty_like(x_ck, dtype=float)
    n = x_ck.shape[-1]
    if n == 0:
        return y
    if rho <= 0.0:
        y[...] = x_ck
        return y
    longest = n if rho >= 1.0 else int(max(1, np.floor(200.0 / -np.log(rho))))  # rho^-j stays below e^200
    block = min(n, longest)
    if rho < 1.0 and longest <= _CACHED_BLOCK:  # the same powers every trace: cached, the first `block` used
        up, down = _powers(float(rho), longest)
        up, down = up[:block], down[:block]
    else:
        j = np.arange(block)
        up, down = rho ** -j, rho ** j
    prev = np.zeros(x_ck.shape[:-1])
    for b in range(0, n, block):  # a handful of blocks, each vectorised over knots and components
        m = min(block, n - b)
        acc = np.cumsum(x_ck[..., b:b + m] * up[:m], axis=-1)
        acc += (prev * rho)[..., None]
        acc *= down[:m]
        y[..., b:b + m] = acc
        prev = acc[..., -1]
    return y
