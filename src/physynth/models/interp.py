"""Linear interpolation of several series at the same points, bit for bit what ``numpy.interp`` returns."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _np_interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``numpy.interp`` of a series (1-D) or of each row of a block (2-D, stacked)."""
    if fp.ndim == 2:
        return np.stack([np.interp(x, xp, row) for row in fp]) if fp.shape[0] else np.empty((0, x.shape[0]))
    return np.interp(x, xp, fp)


def interp_many(x: np.ndarray, xp: np.ndarray, fps: Sequence[np.ndarray]) -> list[np.ndarray]:
    """``[numpy.interp(x, xp, fp) for fp in fps]``, bit for bit, with the interval search done once.

    ``xp`` must be increasing (as ``numpy.interp`` requires), ``x`` 1-D and every ``fp`` float64, either
    1-D (one series) or 2-D (C, len(xp)) (a block of C series, e.g. the rows of a component-first
    position: its result is the (C, len(x)) block of the rows' ``numpy.interp``, computed row-wise in
    one pass). The interval of each point is guessed as if ``xp`` were uniformly spaced (the truth times,
    a speed-shape table) and kept only where ``xp[j] <= x < xp[j + 1]`` holds, so it is exactly the one
    numpy's search finds; the other points (outside ``xp``, on its last knot, or a wrong guess on an
    uneven ``xp``) are left to ``numpy.interp`` itself, as is every series whose result holds a NaN
    (numpy's NaN rules). On a point inside, numpy returns ``fp[j]`` where ``x == xp[j]`` and
    ``slope_j * (x - xp[j]) + fp[j]`` otherwise, with ``slope_j = (fp[j+1] - fp[j]) / (xp[j+1] - xp[j])``:
    computed here the same way.
    """
    x = np.asarray(x, dtype=np.float64)
    xp = np.asarray(xp, dtype=np.float64)
    fps = [np.asarray(fp, dtype=np.float64) for fp in fps]
    n = xp.shape[0]
    if x.ndim != 1 or xp.ndim != 1 or n < 2 or x.shape[0] == 0 or not xp[-1] > xp[0]:
        return [_np_interp(x, xp, fp) for fp in fps]
    pos = x - xp[0]
    pos *= (n - 1) / (xp[-1] - xp[0])
    np.maximum(pos, 0.0, out=pos)
    np.minimum(pos, n - 2, out=pos)
    if not np.isfinite(pos.sum()):  # a NaN point
        return [_np_interp(x, xp, fp) for fp in fps]
    j = pos.astype(np.intp)
    lo = xp.take(j)
    hi = xp.take(j + 1)
    other = np.flatnonzero((x < lo) | (x >= hi))  # not inside interval j: numpy.interp decides
    dx = np.subtract(x, lo, out=pos)
    at_knot = np.flatnonzero(dx == 0.0)
    step = xp[1:] - xp[:-1]
    out = []
    with np.errstate(all="ignore"):  # infinite or NaN values: silent, as in numpy.interp (redone below)
        for fp in fps:
            axis = fp.ndim - 1  # along the knots: the series' values, or each row's of a block
            slope = np.subtract(fp[..., 1:], fp[..., :-1])
            slope /= step
            y = slope.take(j, axis=axis)
            y *= dx
            y += fp.take(j, axis=axis)
            if at_knot.size:
                y[..., at_knot] = fp.take(j.take(at_knot), axis=axis)
            if other.size:
                y[..., other] = _np_interp(x.take(other), xp, fp)
            if np.isnan(y.sum()):  # NaN (or inf - inf) somewhere: numpy's own NaN rules, series by series
                if axis == 0:
                    y = np.interp(x, xp, fp)
                else:
                    for c in range(fp.shape[0]):
                        if np.isnan(y[c].sum()):
                            y[c] = np.interp(x, xp, fp[c])
            out.append(y)
    return out
