"""Reductions on small arrays without numpy's per-call overhead, bit for bit what numpy returns.

The association takes medians of a few keypoints or frames hundreds of thousands of times per sequence;
``np.median`` spends some 25 us per call on dispatch, NaN checks and a partition, most of it overhead at
that size.  :func:`median` sorts instead and picks the middle (the mean of the two middle values for an
even count, computed as ``np.mean`` computes it: their sum over two), so its value is the same.
"""
from __future__ import annotations

import numpy as np


def median(values, axis: int | None = None):
    """``np.median(values, axis=axis)`` for float (or integer) input: the same values, NaN where a reduced
    slice holds a NaN.  ``axis`` None: over the flattened array (a numpy scalar); else along that axis.
    An empty slice is left to ``np.median`` (NaN, with its warning)."""
    if axis is None:                                        # the common case, kept short
        ordered = np.sort(np.asarray(values, dtype=float), axis=None)
        n = len(ordered)
        if n == 0:
            return np.median(ordered)
        if ordered[n - 1] != ordered[n - 1]:                # np.sort puts NaN last
            return np.float64(np.nan)
        half = n // 2
        return ordered[half] if n % 2 else (ordered[half - 1] + ordered[half]) / 2.0
    a = np.asarray(values, dtype=float)
    n = a.shape[axis]
    if n == 0:
        return np.median(a, axis=axis)
    ordered = np.sort(a, axis=axis)
    half = n // 2
    if n % 2:
        middle = np.take(ordered, half, axis=axis)
    else:
        middle = (np.take(ordered, half - 1, axis=axis) + np.take(ordered, half, axis=axis)) / 2.0
    last = np.take(ordered, n - 1, axis=axis)              # np.sort puts NaN last
    return np.where(np.isnan(last), np.nan, middle)
