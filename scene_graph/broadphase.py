"""Candidate pairs of overlapping axis-aligned bounds: sort-and-prune (sweep along x).

Both relation steps (support candidates, proximal relations) only need pairs whose bounds meet;
testing every pair exactly is O(N^2) geometry. Sorting the intervals along x and sweeping keeps
only pairs that overlap in x (vectorised with searchsorted), then filters them on the remaining
axes. ``all_pairs`` is the naive reference the benchmark compares against.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def sweep_pairs(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> NDArray[np.int64]:
    """(K, 2) index pairs i < j whose boxes [lo, hi] (N, D) overlap on every axis (touching counts)."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    n = len(lo)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    order = np.argsort(lo[:, 0], kind="stable")
    starts = lo[order, 0]
    # For the k-th interval in x order, the later intervals starting before its end overlap it in x.
    stop = np.searchsorted(starts, hi[order, 0], side="right")
    counts = np.maximum(stop - np.arange(n) - 1, 0)
    if counts.sum() == 0:
        return np.zeros((0, 2), np.int64)
    first = np.repeat(np.arange(n), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    second = first + 1 + offsets
    a, b = order[first], order[second]
    ok = np.all((lo[a, 1:] <= hi[b, 1:]) & (lo[b, 1:] <= hi[a, 1:]), axis=1)
    pairs = np.sort(np.c_[a[ok], b[ok]], axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def all_pairs(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> NDArray[np.int64]:
    """Every pair i < j (the naive baseline: no pruning at all)."""
    n = len(lo)
    i, j = np.triu_indices(n, 1)
    return np.c_[i, j].astype(np.int64)


def candidate_pairs(lo: NDArray[np.float64], hi: NDArray[np.float64], method: str = "sweep") -> NDArray[np.int64]:
    if method == "sweep":
        return sweep_pairs(lo, hi)
    if method == "all_pairs":
        return all_pairs(lo, hi)
    raise ValueError(f"unknown broad phase {method!r} (sweep, all_pairs)")
