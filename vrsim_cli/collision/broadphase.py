"""Broad phase: candidate pairs whose world AABBs overlap, without testing all n^2 pairs.

Two vectorised methods (numpy, no Python loop over bodies), chosen by
`collision.broad_phase` (benchmarks/collision_bench.py measures both, docs/benchmarks.md):
- grid (default): a uniform hash grid with cells as large as the biggest ordinary box;
  every box lands in at most 8 cells; pairs are formed within cells and kept only in the
  cell that holds the lower corner of their overlap, so each pair appears once. O(n + k).
- sap: sweep and prune along the axis of largest spread: sort the boxes' lower ends once,
  then each box pairs with the boxes starting before its upper end. O(n log n + k_axis).
Infinite or unusually large boxes (planes, a ground slab) would blow up either method;
they are tested against all boxes directly (O(n) each).
brute: all pairs, for checking the others.
"""

from __future__ import annotations

import numpy as np

LARGE_FACTOR = 8.0  # boxes larger than this many median sizes are tested against all


def _overlap(lo, hi, i, j):
    """(k,) bool: do boxes i and j (k,) overlap (touching counts)? Axis by axis, so
    each comparison touches one column (3x less memory traffic than on (k, 3) rows)."""
    keep = (lo[i, 0] <= hi[j, 0]) & (lo[j, 0] <= hi[i, 0])
    for axis in (1, 2):
        keep &= (lo[i, axis] <= hi[j, axis]) & (lo[j, axis] <= hi[i, axis])
    return keep


def _pairs_in_runs(start, end):
    """For sorted positions p with run [start_p, end_p): all (p, q) with p < q < end_p."""
    counts = np.maximum(end - np.arange(len(start)) - 1, 0)
    total = int(counts.sum())
    first = np.repeat(np.arange(len(start)), counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return first, first + 1 + offsets


def sweep_and_prune(lo, hi):
    """Pairs (i, j) of overlapping boxes among lo, hi (n, 3), finite."""
    n = len(lo)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    axis = int(np.argmax(np.var(lo + hi, axis=0)))
    order = np.argsort(lo[:, axis], kind="stable")
    lo_s = lo[order, axis]
    end = np.searchsorted(lo_s, hi[order, axis], side="right")
    p, q = _pairs_in_runs(np.arange(n), end)
    i, j = order[p], order[q]
    keep = _overlap(lo, hi, i, j)
    i, j = i[keep], j[keep]
    return np.minimum(i, j), np.maximum(i, j)


def uniform_grid(lo, hi):
    """Pairs (i, j) of overlapping boxes among lo, hi (n, 3), finite."""
    n = len(lo)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    size = float((hi - lo).max())
    cell = size if size > 0.0 else 1.0
    origin = lo.min(axis=0)
    c_lo = np.floor((lo - origin) / cell).astype(np.int64)
    c_hi = np.floor((hi - origin) / cell).astype(np.int64)  # c_hi - c_lo <= 1 per axis
    corner = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    cells = c_lo[:, None, :] + corner[None]  # (n, 8, 3)
    valid = np.all(cells <= c_hi[:, None, :], axis=2)
    body = np.repeat(np.arange(n), 8)[valid.ravel()]
    cells = cells.reshape(-1, 3)[valid.ravel()]
    span = cells.max(axis=0) + 1
    if float(np.prod(span.astype(float))) >= 2.0 ** 62:  # too sparse to key: sort instead
        return sweep_and_prune(lo, hi)
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    order = np.lexsort((body, key))
    key, body, cells = key[order], body[order], cells[order]
    run_end = np.searchsorted(key, key, side="right")
    p, q = _pairs_in_runs(np.arange(len(key)), run_end)
    i, j = body[p], body[q]
    # Keep a pair only in the cell holding the lower corner of the two boxes' overlap
    # (cheap integer test first, then the exact overlap on the survivors).
    home = np.floor((np.maximum(lo[i], lo[j]) - origin) / cell).astype(np.int64)
    once = np.all(home == cells[p], axis=1)
    i, j = i[once], j[once]
    keep = _overlap(lo, hi, i, j)
    i, j = i[keep], j[keep]
    return np.minimum(i, j), np.maximum(i, j)


def brute_force(lo, hi):
    i, j = np.triu_indices(len(lo), k=1)
    keep = _overlap(lo, hi, i, j)
    return i[keep], j[keep]


METHODS = {"grid": uniform_grid, "sap": sweep_and_prune, "brute": brute_force}


def candidate_pairs(lo, hi, method: str = "grid"):
    """Sorted unique pairs (i, j), i < j, (k,) each, of boxes lo, hi (n, 3) that overlap."""
    n = len(lo)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    size = (hi - lo).max(axis=1)
    finite = np.isfinite(size)
    median = np.median(size[finite]) if finite.any() else 0.0
    large = ~finite | (size > LARGE_FACTOR * max(median, 1e-300)) if method != "brute" \
        else np.zeros(n, bool)
    small = np.flatnonzero(~large)
    si, sj = METHODS[method](lo[small], hi[small])
    parts_i, parts_j = [small[si]], [small[sj]]
    for g in np.flatnonzero(large):  # each large box against every box
        others = np.arange(n)
        others = others[others != g]
        hit = np.all((lo[others] <= hi[g]) & (lo[g] <= hi[others]), axis=1)
        o = others[hit]
        o = o[~large[o] | (o > g)]  # large-large pairs once
        parts_i.append(np.minimum(o, g))
        parts_j.append(np.maximum(o, g))
    i, j = np.concatenate(parts_i), np.concatenate(parts_j)
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    return i.astype(np.int64), j.astype(np.int64)
