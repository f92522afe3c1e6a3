"""Streaming statistics with memory that does not grow with the number of traces.

Pooled metrics over a dataset of any size are combined from per-trace parts:

- counts and sums (fractions, mean AoI, durations) are added exactly;
- means and standard deviations come from exact running moments (:class:`Moments`, Chan et al.'s
  pairwise update), equal to NumPy's two-pass result to floating-point rounding;
- quantiles (median, P95, P99 of residuals, gap lengths, AoI values) come from a
  :class:`QuantileSketch`: it keeps every value **exactly** until it holds :data:`EXACT_LIMIT`
  values, so datasets of up to a few hundred traces give the same numbers as NumPy; beyond that it
  folds the values into a logarithmic histogram (the DDSketch construction) of relative accuracy
  :data:`RELATIVE_ACCURACY`: every quantile it returns is within 0.01 % (relative) of a sample
  value of that rank, and values of magnitude below :data:`ZERO_TOLERANCE` count as 0. Its size is
  bounded by the dynamic range of the values, not by their number: at most 23,000 bins (16 bytes
  each) per decade between 1e-6 and the largest magnitude, per sign, e.g. 6.4 MB for residuals up to
  1 km.

Two-sample statistics on sketched data (KS, Wasserstein-1, Anderson-Darling in validation) are
computed on :meth:`QuantileSketch.values`: the exact values while exact, otherwise
:data:`REPRESENTATIVES` evenly spaced quantiles (ranks ``(i + 0.5) / k``), which moves the KS
statistic by at most ``1 / k`` plus the sketch's 0.01 % relative error in value.
"""

from __future__ import annotations

import numpy as np

EXACT_LIMIT = 1 << 19
"""A sketch keeps up to this many values exactly (4 MB of float64) before it folds them into bins."""

RELATIVE_ACCURACY = 1e-4
"""Relative accuracy alpha of a folded sketch: a returned quantile q' of a true quantile q has
|q' - q| <= alpha |q|."""

ZERO_TOLERANCE = 1e-6
"""Values with |x| below this (1 um for a residual, 1 us for a time) count as 0 in a folded sketch."""

REPRESENTATIVES = 100_000
"""Number of evenly spaced quantiles that stand for a folded sketch in two-sample statistics."""

_GAMMA = (1.0 + RELATIVE_ACCURACY) / (1.0 - RELATIVE_ACCURACY)
_LOG_GAMMA = float(np.log(_GAMMA))


class Moments:
    """Exact running count, mean and sum of squared deviations of (N, C) or (N,) batches."""

    def __init__(self, n_components: int = 1) -> None:
        self.n = 0
        self.mean = np.zeros(n_components)
        self.m2 = np.zeros(n_components)

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64)
        nb = x.shape[0]
        if nb == 0:
            return
        x = x.reshape(nb, -1)
        mb = x.mean(axis=0)
        m2b = ((x - mb) ** 2).sum(axis=0)
        n = self.n + nb
        delta = mb - self.mean
        self.mean = self.mean + delta * (nb / n)
        self.m2 = self.m2 + m2b + delta**2 * (self.n * nb / n)
        self.n = n

    def std(self) -> np.ndarray:
        """Population standard deviation (ddof 0), NaN when empty."""
        if self.n == 0:
            return np.full(self.mean.shape, np.nan)
        return np.sqrt(self.m2 / self.n)


class QuantileSketch:
    """Exact values up to :data:`EXACT_LIMIT`, then a logarithmic histogram of bounded relative error."""

    def __init__(self, exact_limit: int = EXACT_LIMIT) -> None:
        self.exact_limit = int(exact_limit)
        self._parts: list[np.ndarray] = []
        self._n_buffered = 0
        self._keys = np.zeros(0, dtype=np.int64)  # signed bin keys, 0 = the zero bin
        self._counts = np.zeros(0, dtype=np.int64)
        self.folded = False
        self.n = 0

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64).ravel()
        x = x[np.isfinite(x)]
        if x.size == 0:
            return
        self._parts.append(x)
        self._n_buffered += x.size
        self.n += x.size
        if self._n_buffered > self.exact_limit:
            self._fold()

    @staticmethod
    def _key(x: np.ndarray) -> np.ndarray:
        a = np.abs(x)
        k = np.zeros(x.shape, dtype=np.int64)
        big = a >= ZERO_TOLERANCE
        # bin k >= 1 holds |x| / ZERO_TOLERANCE in (gamma^(k-2), gamma^(k-1)]
        k[big] = np.ceil(np.log(a[big] / ZERO_TOLERANCE) / _LOG_GAMMA).astype(np.int64) + 1
        return np.where(x < 0, -k, k)

    @staticmethod
    def _value(k: np.ndarray) -> np.ndarray:
        mag = ZERO_TOLERANCE * 2.0 * _GAMMA ** (np.abs(k) - 1) / (_GAMMA + 1.0)
        return np.where(k == 0, 0.0, np.sign(k) * mag)

    def _merge_bins(self, keys: np.ndarray, counts: np.ndarray) -> None:
        allk = np.concatenate([self._keys, keys])
        allc = np.concatenate([self._counts, counts])
        uk, inv = np.unique(allk, return_inverse=True)
        self._keys, self._counts = uk, np.bincount(inv, weights=allc).astype(np.int64)

    def _fold(self) -> None:
        if not self._parts:
            self.folded = True
            return
        x = np.concatenate(self._parts)
        self._parts, self._n_buffered = [], 0
        uk, cnt = np.unique(self._key(x), return_counts=True)
        self._merge_bins(uk, cnt.astype(np.int64))
        self.folded = True

    def _exact(self) -> np.ndarray:
        if len(self._parts) > 1:
            self._parts = [np.concatenate(self._parts)]
        return self._parts[0] if self._parts else np.zeros(0)

    def quantile(self, q: float | np.ndarray) -> np.ndarray | float:
        """Quantiles ``q`` in [0, 1] (NumPy's linear interpolation while exact); NaN when empty."""
        qa = np.asarray(q, dtype=float)
        if self.n == 0:
            out = np.full(qa.shape, np.nan)
        elif not self.folded:
            out = np.quantile(self._exact(), qa)
        else:
            self._fold()
            cum = np.cumsum(self._counts)
            rank = np.clip(np.round(qa * (self.n - 1)), 0, self.n - 1)
            out = self._value(self._keys[np.searchsorted(cum, rank, side="right")])
        return float(out) if np.ndim(out) == 0 else out

    def values(self, k: int = REPRESENTATIVES) -> np.ndarray:
        """The exact values while exact; otherwise ``k`` evenly spaced quantiles standing for them."""
        if not self.folded:
            return self._exact().copy()
        return np.asarray(self.quantile((np.arange(k) + 0.5) / k))

    @property
    def nbytes(self) -> int:
        return int(sum(p.nbytes for p in self._parts) + self._keys.nbytes + self._counts.nbytes)
