"""Broad phase: candidate pairs whose world AABBs overlap, without testing all n^2 pairs.

Two vectorised methods (numpy, no Python loop over bodies), chosen by
`collision.broad_phase` (benchmarks/collision_bench.py measures both, docs/benchmarks.md):
- grid (default): a uniform grid with cells as large as the biggest ordinary box; every
  box is filed in the cell of its centre and pairs with the boxes of its own cell and of
  the 13 forward neighbour cells (binary search in the boxes sorted by cell), so each
  pair appears once. O(n log n + k).
- sap: sweep and prune along the axis of largest spread: sort the boxes' lower ends once,
  then each box pairs with the boxes starting before its upper end. O(n log n + k_axis).
Infinite or unusually large boxes (planes, a ground slab) would blow up either method;
they are tested against all boxes directly (O(n) each).
brute: all pairs, for checking the others.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.model.model import BODY_STATIC

# Up to this many boxes all pairs are tested at once (at most 120): a located step calls
# the broad phase twice for a scene of a few bodies, where the grid's median, split and
# sort cost several times the 120 comparisons.
ALL_PAIRS_N = 16
LARGE_FACTOR = 8.0  # boxes larger than this many median sizes are tested against all


def _overlap(lo, hi, i, j):
    """(k,) bool: do boxes i and j (k,) overlap (touching counts)? Axis by axis on
    contiguous columns (`take` from a 1D column is 2-3 times faster than lo[i, axis])."""
    keep = np.ones(len(i), bool)
    for l, h in zip(np.ascontiguousarray(lo.T), np.ascontiguousarray(hi.T)):
        keep &= (l.take(i) <= h.take(j)) & (l.take(j) <= h.take(i))
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


# The 13 neighbour cells "after" a cell (half of its 26 neighbours): visiting only these
# finds each pair of neighbouring cells once.
_FORWARD = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                     if (x, y, z) > (0, 0, 0)], dtype=np.int64)


def uniform_grid(lo, hi):
    """Pairs (i, j) of overlapping boxes among lo, hi (n, 3), finite.

    Cells are as large as the biggest box, and each box is filed once, in the cell of its
    centre: two overlapping boxes have centres closer than that size on every axis, so
    their cells are the same or neighbours. Pairs come from each cell's own run of boxes
    and from its 13 forward neighbours' runs, found all at once by binary search in the
    boxes sorted by cell key."""
    n = len(lo)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    size = float((hi - lo).max())
    centre = 0.5 * (lo + hi)
    # slack of a few ulps: centres carry rounding, and boxes that touch exactly must not
    # land two cells apart
    cell = (size if size > 0.0 else 1.0) + 8.0 * float(np.spacing(np.abs(centre).max()))
    c = np.floor((centre - centre.min(axis=0)) / cell)  # float first: no overflowing cast
    span = c.max(axis=0) + 3.0
    if float(np.prod(span)) >= 2.0 ** 62:  # too sparse to key: sort instead
        return sweep_and_prune(lo, hi)
    c = c.astype(np.int64) + 1  # -1 stays >= 0
    span = span.astype(np.int64)
    key = (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]
    order = np.argsort(key, kind="stable")
    key = key[order]
    p, q = _pairs_in_runs(np.arange(n), np.searchsorted(key, key, side="right"))
    step = (_FORWARD[:, 0] * span[1] + _FORWARD[:, 1]) * span[2] + _FORWARD[:, 2]
    wanted = (key[:, None] + step[None, :]).ravel()  # (n * 13,) neighbour cell keys
    start = np.searchsorted(key, wanted, side="left")
    count = np.searchsorted(key, wanted, side="right") - start
    total = int(count.sum())
    src = np.repeat(np.repeat(np.arange(n), len(step)), count)
    dst = np.repeat(start, count) + np.arange(total) - np.repeat(np.cumsum(count) - count,
                                                                    count)
    i = order[np.concatenate([p, src])]
    j = order[np.concatenate([q, dst])]
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
    if n <= ALL_PAIRS_N:  # every pair at once: the same pairs, in the same (i, j) order
        i, j = np.triu_indices(n, k=1)
        keep = _overlap(lo, hi, i, j)
        return i[keep].astype(np.int64), j[keep].astype(np.int64)
    size = (hi - lo).max(axis=1)
    finite = np.isfinite(size)
    median = np.median(size[finite]) if finite.any() else 0.0
    large = ~finite | (size > LARGE_FACTOR * max(median, 1e-300)) if method != "brute" \
        else np.zeros(n, bool)
    small = np.flatnonzero(~large)
    si, sj = METHODS[method](lo[small], hi[small])
    parts_i, parts_j = [small[si]], [small[sj]]
    big = np.flatnonzero(large)
    if len(big):  # each large box against every box, all at once: (n_large, n)
        hit = np.ones((len(big), n), bool)
        for axis in range(3):
            hit &= (lo[None, :, axis] <= hi[big, None, axis]) & \
                (lo[big, None, axis] <= hi[None, :, axis])
        hit[np.arange(len(big)), big] = False
        hit &= ~large[None, :] | (np.arange(n)[None, :] > big[:, None])  # large pairs once
        g, o = np.nonzero(hit)
        parts_i.append(np.minimum(o, big[g]))
        parts_j.append(np.maximum(o, big[g]))
    i, j = np.concatenate(parts_i).astype(np.int64), np.concatenate(parts_j).astype(np.int64)
    order = np.argsort(i * n + j, kind="stable")  # by (i, j): one key sorts faster
    return i[order], j[order]


def broad_phase(model, lo, hi, step: int):
    """Candidate geom pairs (ia, ib) among the world AABBs lo, hi (n_geom, 3): only geoms
    whose body is in the scene at `step` (particles waiting at a nozzle all sit at one
    point and would pair with each other), no pairs of one body or of two static bodies."""
    cm = model.collision
    idx = np.flatnonzero(model.body_emit_step[cm.geom_body] <= step)
    ia, ib = candidate_pairs(lo[idx], hi[idx], cm.broad_phase)
    ia, ib = idx[ia], idx[ib]
    ba, bb = cm.geom_body[ia], cm.geom_body[ib]
    moves = np.asarray(model.body_type) != BODY_STATIC
    keep = (ba != bb) & (moves[ba] | moves[bb])
    return ia[keep], ib[keep]
