"""Compiled collision detection of analytic shapes: placement, tight AABBs, a uniform-grid
broad phase and the closed-form pair functions of `stages/collision/narrowphase.py`.

The numpy narrow phase is the reference: every pair function here is the same algorithm
(the same formulas, the same tie rules, the same manifold reduction), written per pair,
so the contacts agree with it up to round-off and ordering (tests/test_stepped.py checks
it on random pairs). Pairs without a closed form here (anything with a convex hull or a
mesh, cylinders against boxes, capsules and cylinders, mesh proxies re-fitted every
step) are handed back as candidate pairs for the Python detection (`fallback`).

API (usable by any stage; `stages/collision/stepped.py` packs the tables):

    gf   (n_geom, G_SIZE)  the geometry table, one row per geom (`geom_table` in the stage):
                           body, type, pose in the body, radius, half extents, plane,
                           rbound, whether Python must test it, the body's emission step
                           and whether the body moves (not static)
    S    (n_body, 13)      the state rows of kernels.dynamics (position, velocity,
                           quaternion, angular velocity)
    sweep (n_body,)        m: how far any point of each body may move in the step: a pair is
                           reported while its gap is <= sweep_a + sweep_b + tolerance
                           (speculative contacts; 0 and the tolerance give the plain
                           contacts of one instant)

    detect(gf, S, step, sweep, tolerance, planar) -> (k, C, F, nf)
        C (>= k, C_SIZE): contact rows [body_a, body_b, point (3), normal (3), depth,
        rounding a, rounding b] with body_a < body_b, the normal from A to B, depth > 0
        penetrating, < 0 a gap;
        sorted by (body_a, body_b), a pair's points in the order its pair function made
        them (the stepped solver's warm start matches contacts by pair and that rank).
        F (>= nf, 2): geom pairs (g1 < g2) for the Python detection.
        `planar`: 2D scenes, contacts in the z = 0 plane (as `contacts.planar`).

Everything is written out by components (`linalg.py`): no BLAS, no fastmath, the same
bits on every run.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels import linalg as la
from vrsim_cli.kernels.jit import kernel

SPHERE, PLANE, BOX, CAPSULE, CYLINDER, CONVEX, MESH = range(7)  # as model.collision

# geometry table columns
G_BODY, G_TYPE, G_LPOS, G_LQUAT, G_TURNED, G_RADIUS, G_HALF, G_PN, G_PO, G_RBOUND, \
    G_PYTHON, G_EMIT, G_MOVES = 0, 1, 2, 5, 9, 10, 11, 14, 17, 18, 19, 20, 21
G_SIZE = 22
# world geoms W (n_geom, 12): position, then R row-major (its columns: the geom's axes)
W_POS, W_R, W_SIZE = 0, 3, 12
# contact rows; C_ROUND_A, C_ROUND_B: m, the radius of the sphere about each witness point
# that lies in the body (a sphere's or capsule's radius, 0 on a flat face or an edge), so
# the stepped solver carries that sphere's centre, not the witness point (kernels.stepped:
# `end_separations`)
C_A, C_B, C_P, C_N, C_D, C_ROUND_A, C_ROUND_B, C_SIZE = 0, 1, 2, 5, 8, 9, 10, 11

EPS = 1e-12  # as narrowphase._EPS
UP = (0.0, 1.0, 0.0)
LARGE_FACTOR = 8.0  # as broadphase: boxes larger than this many median sizes go to all
GOLDEN_ITERATIONS = 48
PARALLEL_SIN = 1e-3
FLAT_COS = 1.0 - 5e-5  # as narrowphase.FLAT_COS: a cap this close to a plane lies flat
MAX_PER_PAIR = 8  # contacts one pair function can make (box_box: two faces' 4)
TIE_TOL = 1e-9  # as narrowphase.TIE_TOL
PARALLEL_COS = 1e-9  # as narrowphase.PARALLEL_COS


# ----------------------------------------------------------------------------- helpers


@kernel(inline="always")
def _col(R, j):
    """Column j of a row-major 3x3 tuple: the geom's local axis j in world."""
    return (R[j], R[3 + j], R[6 + j])


@kernel(inline="always")
def _pos(W, g):
    return (W[g, 0], W[g, 1], W[g, 2])


@kernel(inline="always")
def _rot(W, g):
    return (W[g, 3], W[g, 4], W[g, 5], W[g, 6], W[g, 7], W[g, 8], W[g, 9], W[g, 10],
            W[g, 11])


@kernel(inline="always")
def _half(gf, g):
    return (gf[g, G_HALF], gf[g, G_HALF + 1], gf[g, G_HALF + 2])


@kernel(inline="always")
def _clip(x, lo, hi):
    return lo if x < lo else (hi if x > hi else x)


@kernel(inline="always")
def _unit(v, fallback):
    """(unit vector, length); a vector no longer than EPS gives `fallback`."""
    length = la.norm(v)
    if length > EPS:
        return (v[0] / length, v[1] / length, v[2] / length), length
    return fallback, length


@kernel
def _grow(C, k, extra):
    """C with room for `extra` more rows after row k."""
    if k + extra <= C.shape[0]:
        return C
    bigger = np.empty((2 * C.shape[0] + extra, C.shape[1]))
    for q in range(k):
        for c in range(C.shape[1]):
            bigger[q, c] = C[q, c]
    return bigger


@kernel(inline="always")
def _put(C, k, point, normal, depth):
    C[k, C_P] = point[0]
    C[k, C_P + 1] = point[1]
    C[k, C_P + 2] = point[2]
    C[k, C_N] = normal[0]
    C[k, C_N + 1] = normal[1]
    C[k, C_N + 2] = normal[2]
    C[k, C_D] = depth


# ----------------------------------------------------------------------------- placement


@kernel
def place(gf, S, W):
    """World poses W (n_geom, 12) of all geoms at the body poses of S (shapes.place):
    position = body position + R_body p_local, R = R_body (R_body R_local when the geom is
    turned in its body); planes at n * offset with R = E."""
    for g in range(gf.shape[0]):
        kind = int(gf[g, G_TYPE])
        if kind == PLANE:
            o = gf[g, G_PO]
            for c in range(3):
                W[g, c] = gf[g, G_PN + c] * o
            for c in range(9):
                W[g, 3 + c] = 1.0 if c % 4 == 0 else 0.0
            continue
        b = int(gf[g, G_BODY])
        q = (S[b, 6], S[b, 7], S[b, 8], S[b, 9])
        Rb = la.quat_to_matrix(q)
        lp = (gf[g, G_LPOS], gf[g, G_LPOS + 1], gf[g, G_LPOS + 2])
        p = la.add((S[b, 0], S[b, 1], S[b, 2]), la.matvec(Rb, lp))
        R = Rb
        if gf[g, G_TURNED] != 0.0:
            lq = (gf[g, G_LQUAT], gf[g, G_LQUAT + 1], gf[g, G_LQUAT + 2], gf[g, G_LQUAT + 3])
            R = la.quat_to_matrix(la.quat_mul(q, lq))
        for c in range(3):
            W[g, c] = p[c]
        for c in range(9):
            W[g, 3 + c] = R[c]


@kernel
def aabbs(gf, S, W, pad, lo, hi):
    """Tight world AABBs (lo, hi) (n_geom, 3) grown by pad (n_geom,) m on every side:
    a sphere's is c +- r (not |R| r), a capsule's the box of its two end spheres, a
    cylinder's |a_i| h + r sqrt(1 - a_i^2) about its centre (a: its axis), a box's |R| h;
    planes are infinite; geoms Python tests get the body's position +- rbound."""
    for g in range(gf.shape[0]):
        kind = int(gf[g, G_TYPE])
        if kind == PLANE:
            for c in range(3):
                lo[g, c] = -math.inf
                hi[g, c] = math.inf
            continue
        centre = _pos(W, g)
        R = _rot(W, g)
        r = gf[g, G_RADIUS]
        h = _half(gf, g)
        if gf[g, G_PYTHON] != 0.0:
            b = int(gf[g, G_BODY])
            centre = (S[b, 0], S[b, 1], S[b, 2])
            e = (gf[g, G_RBOUND], gf[g, G_RBOUND], gf[g, G_RBOUND])
        elif kind == SPHERE:
            e = (r, r, r)
        elif kind == BOX:
            e = (abs(R[0]) * h[0] + abs(R[1]) * h[1] + abs(R[2]) * h[2],
                 abs(R[3]) * h[0] + abs(R[4]) * h[1] + abs(R[5]) * h[2],
                 abs(R[6]) * h[0] + abs(R[7]) * h[1] + abs(R[8]) * h[2])
        elif kind == CAPSULE:
            e = (abs(R[1]) * h[1] + r, abs(R[4]) * h[1] + r, abs(R[7]) * h[1] + r)
        else:  # cylinder
            a = _col(R, 1)
            e = (abs(a[0]) * h[1] + r * math.sqrt(max(0.0, 1.0 - a[0] * a[0])),
                 abs(a[1]) * h[1] + r * math.sqrt(max(0.0, 1.0 - a[1] * a[1])),
                 abs(a[2]) * h[1] + r * math.sqrt(max(0.0, 1.0 - a[2] * a[2])))
        for c in range(3):
            lo[g, c] = centre[c] - e[c] - pad[g]
            hi[g, c] = centre[c] + e[c] + pad[g]


# ----------------------------------------------------------------------------- broad phase


@kernel(inline="always")
def _overlap(lo, hi, i, j):
    for c in range(3):
        if lo[i, c] > hi[j, c] or lo[j, c] > hi[i, c]:
            return False
    return True


@kernel(inline="always")
def _plane_reaches(gf, pad, lo, hi, p, j):
    """Whether geom j's box (lo, hi) reaches plane p's half-space grown by p's pad (its
    sweep and half the tolerance, as the other boxes): the plane's own box is infinite,
    so without this every geom in the scene is a candidate of every plane. The box's
    lowest point along the normal against the plane's offset; boxes grown by their pads
    contain every point a pair function can report within its margin, and the slack of
    1e-9 of the coordinates keeps a pair that round-off would put on the line."""
    if int(gf[j, G_TYPE]) == PLANE:
        return True
    low = 0.0
    scale = abs(gf[p, G_PO]) + pad[p]
    for c in range(3):
        nc = gf[p, G_PN + c]
        low += nc * (lo[j, c] if nc >= 0.0 else hi[j, c])
        scale += abs(lo[j, c]) + abs(hi[j, c])
    return not low - gf[p, G_PO] > pad[p] + 1e-9 * scale  # (NaN: a candidate, as _overlap)


@kernel(inline="always")
def _candidate(gf, pad, lo, hi, i, j):
    """Boxes overlap (a plane: its half-space reaches the other box) and the pair is
    wanted (`_wanted`)."""
    if not _overlap(lo, hi, i, j) or not _wanted(gf, i, j):
        return False
    if int(gf[i, G_TYPE]) == PLANE:
        return _plane_reaches(gf, pad, lo, hi, i, j)
    if int(gf[j, G_TYPE]) == PLANE:
        return _plane_reaches(gf, pad, lo, hi, j, i)
    return True


@kernel
def _push_pair(P, n, i, j):
    if n >= P.shape[0]:
        bigger = np.empty((2 * P.shape[0] + 16, 2), np.int64)
        for q in range(n):
            bigger[q, 0] = P[q, 0]
            bigger[q, 1] = P[q, 1]
        P = bigger
    P[n, 0] = min(i, j)
    P[n, 1] = max(i, j)
    return P


@kernel(inline="always")
def _wanted(gf, i, j):
    """Two geoms of different bodies, at least one of which moves."""
    if int(gf[i, G_BODY]) == int(gf[j, G_BODY]):
        return False
    return gf[i, G_MOVES] != 0.0 or gf[j, G_MOVES] != 0.0


@kernel
def _select(a, kth):
    """The kth smallest of a (partitioned in place; Hoare's quickselect)."""
    lo, hi = 0, a.shape[0] - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if kth <= j:
            hi = j
        elif kth >= i:
            lo = i
        else:
            break
    return a[kth]


@kernel
def _median(values, m):
    """The median of values[:m] (of a copy: quickselect, deterministic)."""
    a = np.empty(m)
    for q in range(m):
        a[q] = values[q]
    if m % 2:
        return _select(a, (m - 1) // 2)
    low = _select(a, m // 2 - 1)
    return 0.5 * (low + _select(a, m // 2))


HASH_X, HASH_Y, HASH_Z = 73856093, 19349663, 83492791  # Teschner et al. 2003


@kernel
def broad_phase(gf, lo, hi, step, pad):
    """Candidate geom pairs (P (m, 2) int64, i < j, and m) whose boxes overlap, among the
    geoms whose body is in the scene at `step` (with a plane: whose half-space, grown by
    the plane's pad (n_geom,) m, reaches the other box; `_plane_reaches`): a uniform hash
    grid over the ordinary
    boxes (cells as large as the largest, each box filed in the cell of its centre and
    paired with the later boxes of its own cell and the boxes of the 13 forward
    neighbour cells, so each pair is found once; cells are hashed into buckets by a
    counting sort, no comparison sort), and every box larger than LARGE_FACTOR median
    sizes (planes, a fast body's swept box) against all."""
    n = gf.shape[0]
    P = np.empty((max(16, 4 * n), 2), np.int64)
    m = np.int64(0)  # not a literal 0: callees would be compiled twice
    active = np.empty(n, np.int64)
    na = 0
    for g in range(n):
        if gf[g, G_EMIT] <= step:
            active[na] = g
            na += 1
    if na < 2:
        return P, 0
    size = np.empty(na)
    finite_sizes = np.empty(na)
    nf = 0
    for q in range(na):
        s = size_of(lo, hi, active[q])
        size[q] = s
        if math.isfinite(s):
            finite_sizes[nf] = s
            nf += 1
    median = _median(finite_sizes, nf) if nf else 0.0
    limit = LARGE_FACTOR * max(median, 1e-300)
    small = np.empty(na, np.int64)
    large = np.empty(na, np.int64)
    ns = nl = 0
    for q in range(na):
        if math.isfinite(size[q]) and size[q] <= limit:
            small[ns] = active[q]
            ns += 1
        else:
            large[nl] = active[q]
            nl += 1
    if ns >= 2:
        cell = 0.0
        cmax_abs = 0.0
        for q in range(ns):
            g = small[q]
            cell = max(cell, size_of(lo, hi, g))
            for c in range(3):
                cmax_abs = max(cmax_abs, abs(0.5 * (lo[g, c] + hi[g, c])))
        # slack of a few ulps: centres carry rounding, and boxes that touch exactly must
        # not land two cells apart
        cell = (cell if cell > 0.0 else 1.0) + 8.0 * 2.220446049250313e-16 * cmax_abs
        key = np.empty((ns, 3), np.int64)
        buckets = 1
        while buckets < 2 * ns:
            buckets *= 2
        start = np.zeros(buckets + 1, np.int64)
        bucket = np.empty(ns, np.int64)
        for q in range(ns):
            g = small[q]
            for c in range(3):
                f = math.floor(0.5 * (lo[g, c] + hi[g, c]) / cell)
                key[q, c] = int(max(-4e18, min(4e18, f)))
            bucket[q] = _hash(key[q, 0], key[q, 1], key[q, 2], buckets)
            start[bucket[q] + 1] += 1
        for b in range(buckets):
            start[b + 1] += start[b]
        fill = np.empty(buckets, np.int64)
        for b in range(buckets):
            fill[b] = start[b]
        members = np.empty(ns, np.int64)  # positions into `small`, grouped by bucket
        for q in range(ns):
            members[fill[bucket[q]]] = q
            fill[bucket[q]] += 1
        for q in range(ns):
            i = small[q]
            kx, ky, kz = key[q, 0], key[q, 1], key[q, 2]
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    for dz in range(-1, 2):
                        same = dx == 0 and dy == 0 and dz == 0
                        if not (same or dx > 0 or (dx == 0 and (dy > 0 or (dy == 0 and
                                                                           dz > 0)))):
                            continue
                        wx, wy, wz = kx + dx, ky + dy, kz + dz
                        b = _hash(wx, wy, wz, buckets)
                        for e in range(start[b], start[b + 1]):
                            o = members[e]
                            if key[o, 0] != wx or key[o, 1] != wy or key[o, 2] != wz:
                                continue  # another cell in the same bucket
                            if same and o <= q:
                                continue  # a cell's own pairs once
                            j = small[o]
                            if _overlap(lo, hi, i, j) and _wanted(gf, i, j):
                                P = _push_pair(P, m, i, j)
                                m += 1
    for p in range(nl):  # each large box against every box, large pairs once
        i = large[p]
        for q in range(na):
            j = active[q]
            if j == i:
                continue
            if not (math.isfinite(size[q]) and size[q] <= limit) and j < i:
                continue
            if _candidate(gf, pad, lo, hi, i, j):
                P = _push_pair(P, m, i, j)
                m += 1
    return P, m


@kernel(inline="always")
def _hash(x, y, z, buckets):
    h = (x * HASH_X) ^ (y * HASH_Y) ^ (z * HASH_Z)
    return h & (buckets - 1)


@kernel(inline="always")
def size_of(lo, hi, g):
    return max(hi[g, 0] - lo[g, 0], hi[g, 1] - lo[g, 1], hi[g, 2] - lo[g, 2])


# ----------------------------------------------------------------------------- pair functions
#
# Each writes its contacts (point, normal from its first geom to its second, depth) into
# C from row k and returns how many; only depths >= -margin are written.


@kernel(inline="always")
def _spheres(ca, ra, cb, rb):
    n, dist = _unit(la.sub(cb, ca), UP)
    depth = ra + rb - dist
    point = la.add(ca, la.scale(ra - 0.5 * depth, n))
    return point, n, depth


@kernel
def sphere_sphere(gf, W, ga, gb, margin, C, k):
    ra, rb = gf[ga, G_RADIUS], gf[gb, G_RADIUS]
    ca, cb = _pos(W, ga), _pos(W, gb)
    if ra + rb - la.norm(la.sub(cb, ca)) < -margin:
        return 0
    point, n, depth = _spheres(ca, ra, cb, rb)
    _put(C, k, point, n, depth)
    return 1


@kernel
def plane_sphere(gf, W, ga, gb, margin, C, k):
    n = (gf[ga, G_PN], gf[ga, G_PN + 1], gf[ga, G_PN + 2])
    c, r = _pos(W, gb), gf[gb, G_RADIUS]
    depth = r - (la.dot(n, c) - gf[ga, G_PO])
    if depth < -margin:
        return 0
    _put(C, k, la.sub(c, la.scale(r - 0.5 * depth, n)), n, depth)
    return 1


@kernel
def _box_point(c, R, half, p, r):
    """Box (c, R, half) against a sphere of radius r at p: (point, normal box->sphere,
    depth). Outside: towards the clamped point; inside: out of the nearest face."""
    local = la.mattvec(R, la.sub(p, c))
    clamped = (_clip(local[0], -half[0], half[0]), _clip(local[1], -half[1], half[1]),
               _clip(local[2], -half[2], half[2]))
    diff, dist = _unit(la.sub(local, clamped), UP)
    fg = (half[0] - abs(local[0]), half[1] - abs(local[1]), half[2] - abs(local[2]))
    if dist <= EPS:
        axis = 0
        if fg[1] < fg[axis]:
            axis = 1
        if fg[2] < fg[axis]:
            axis = 2
        sign = 1.0 if local[axis] >= 0.0 else -1.0
        if axis == 0:
            n_local = (sign, 0.0, 0.0)
            surface = (sign * half[0], local[1], local[2])
        elif axis == 1:
            n_local = (0.0, sign, 0.0)
            surface = (local[0], sign * half[1], local[2])
        else:
            n_local = (0.0, 0.0, sign)
            surface = (local[0], local[1], sign * half[2])
        depth = r - (-fg[axis])
    else:
        n_local = diff
        surface = clamped
        depth = r - dist
    normal = la.matvec(R, n_local)
    world_surface = la.add(c, la.matvec(R, surface))
    point = la.scale(0.5, la.sub(la.add(world_surface, p), la.scale(r, normal)))
    return point, normal, depth


@kernel
def box_sphere(gf, W, ga, gb, margin, C, k):
    point, n, depth = _box_point(_pos(W, ga), _rot(W, ga), _half(gf, ga), _pos(W, gb),
                                 gf[gb, G_RADIUS])
    if depth < -margin:
        return 0
    _put(C, k, point, n, depth)
    return 1


@kernel(inline="always")
def _segment(gf, W, g):
    axis = la.scale(gf[g, G_HALF + 1], _col(_rot(W, g), 1))
    c = _pos(W, g)
    return la.sub(c, axis), la.add(c, axis)


@kernel(inline="always")
def _closest_on_segment(p, a, b):
    ab = la.sub(b, a)
    t = _clip(la.dot(la.sub(p, a), ab) / max(la.dot(ab, ab), EPS), 0.0, 1.0)
    return la.add(a, la.scale(t, ab))


@kernel
def capsule_sphere(gf, W, ga, gb, margin, C, k):
    a, b = _segment(gf, W, ga)
    c = _pos(W, gb)
    point, n, depth = _spheres(_closest_on_segment(c, a, b), gf[ga, G_RADIUS], c,
                               gf[gb, G_RADIUS])
    if depth < -margin:
        return 0
    _put(C, k, point, n, depth)
    return 1


@kernel
def cylinder_sphere(gf, W, ga, gb, margin, C, k):
    """In the cylinder's frame the problem is 2D in (distance from the axis, height): a
    rectangle of half sizes (r, h); outside, towards the closest point; inside, out of the
    nearest side or cap."""
    c, R = _pos(W, ga), _rot(W, ga)
    r, h = gf[ga, G_RADIUS], gf[ga, G_HALF + 1]
    pb = _pos(W, gb)
    local = la.mattvec(R, la.sub(pb, c))
    radial_vec = (local[0], local[1] * 0.0, local[2])
    radial_dir, radial = _unit(radial_vec, (1.0, 0.0, 0.0))
    y = local[1]
    rr = min(radial, r)
    closest = (radial_dir[0] * rr, _clip(y, -h, h), radial_dir[2] * rr)
    diff, dist = _unit(la.sub(local, closest), UP)
    side_gap, cap_gap = r - radial, h - abs(y)
    # inside also where the centre is on the axis to within EPS: there the radial
    # direction is a fallback and `closest` misses the centre by up to 2 radial
    if dist <= EPS or (side_gap >= 0.0 and cap_gap >= 0.0):
        sign = 1.0 if y >= 0.0 else -1.0
        if side_gap <= cap_gap:
            n_local = radial_dir
            surface = (radial_dir[0] * r + y * 0.0, radial_dir[1] * r + y,
                       radial_dir[2] * r + y * 0.0)
        else:
            n_local = (sign * 0.0, sign, sign * 0.0)
            surface = (radial_vec[0] + sign * h * 0.0, radial_vec[1] + sign * h,
                       radial_vec[2] + sign * h * 0.0)
        inner = -min(side_gap, cap_gap)
    else:
        n_local = diff
        surface = closest
        inner = dist
    rs = gf[gb, G_RADIUS]
    depth = rs - inner
    if depth < -margin:
        return 0
    normal = la.matvec(R, n_local)
    world_surface = la.add(c, la.matvec(R, surface))
    point = la.scale(0.5, la.sub(la.add(world_surface, pb), la.scale(rs, normal)))
    _put(C, k, point, normal, depth)
    return 1


@kernel(inline="always")
def _below(p, n, offset):
    """(p, its depth below the plane n . x = offset): a candidate of `_deepest`."""
    return p, offset - la.dot(n, p)


@kernel
def _deepest(cands, n, margin, C, k):
    """The (up to) 4 deepest of 8 candidates (point, depth) below a plane of normal n, kept
    in candidate order (a stable rank for warm starting): contacts at the midpoint between
    each point and the plane. The deepest by (depth, then candidate index), as numpy's
    stable argsort of -depth. The candidates are a tuple and the chosen ones a bit mask
    (bit i: candidate i), not arrays: no heap allocation per pair."""
    chosen = 0
    for _ in range(4):
        best = -1
        for i in range(8):
            if not chosen & (1 << i) and (best < 0 or cands[i][1] > cands[best][1]):
                best = i
        chosen |= 1 << best
    count = 0
    for i in range(8):
        p, depth = cands[i]
        if chosen & (1 << i) and depth >= -margin:
            _put(C, k + count, la.add(p, la.scale(0.5 * depth, n)), n, depth)
            count += 1
    return count


@kernel
def _corner(c, R, h, i):
    """Corner i of the box (c, R, h): its signs along the box's axes are bits 2, 1, 0 of i
    (0: minus)."""
    s = (-1.0 if i & 4 == 0 else 1.0, -1.0 if i & 2 == 0 else 1.0,
         -1.0 if i & 1 == 0 else 1.0)
    return la.add(c, la.matvec(R, (s[0] * h[0], s[1] * h[1], s[2] * h[2])))


@kernel
def plane_box(gf, W, ga, gb, margin, C, k):
    """Half-space against the 8 box corners; the 4 deepest within margin."""
    n = (gf[ga, G_PN], gf[ga, G_PN + 1], gf[ga, G_PN + 2])
    c, R, h = _pos(W, gb), _rot(W, gb), _half(gf, gb)
    o = gf[ga, G_PO]
    # the corners written out into a tuple (no heap arrays per pair)
    corners = (_below(_corner(c, R, h, 0), n, o), _below(_corner(c, R, h, 1), n, o),
               _below(_corner(c, R, h, 2), n, o), _below(_corner(c, R, h, 3), n, o),
               _below(_corner(c, R, h, 4), n, o), _below(_corner(c, R, h, 5), n, o),
               _below(_corner(c, R, h, 6), n, o), _below(_corner(c, R, h, 7), n, o))
    return _deepest(corners, n, margin, C, k)


@kernel
def plane_cylinder(gf, W, ga, gb, margin, C, k):
    """Half-space against the rims of both caps: on each cap the lowest rim point, its
    opposite and the two between; a cap lying flat (FLAT_COS): four rim points fixed in
    the body and the lowest rim point, all in candidate order (narrowphase's)."""
    n = (gf[ga, G_PN], gf[ga, G_PN + 1], gf[ga, G_PN + 2])
    c, R = _pos(W, gb), _rot(W, gb)
    axis = _col(R, 1)
    h, r = gf[gb, G_HALF + 1], gf[gb, G_RADIUS]
    radial = la.sub(n, la.scale(la.dot(n, axis), axis))
    along = la.dot(n, axis)
    if abs(along) >= FLAT_COS:
        s = -1.0 if along > 0.0 else 1.0
        centre = la.add(c, la.scale(s * h, axis))
        x, z = _col(R, 0), _col(R, 2)
        length = la.norm(radial)
        low = la.scale(-1.0 / length if length > 1e-9 else 0.0, radial)
        count = 0
        for j in range(5 if length > 1e-9 else 4):
            d = x if j == 0 else z if j == 1 else la.scale(-1.0, x) if j == 2 else \
                la.scale(-1.0, z) if j == 3 else low
            p = la.add(centre, la.scale(r, d))
            depth = gf[ga, G_PO] - la.dot(n, p)
            if depth >= -margin:
                _put(C, k + count, la.add(p, la.scale(0.5 * depth, n)), n, depth)
                count += 1
        return count
    fallback = _col(R, 0)
    u, length = _unit(radial, fallback)
    if not length > 1e-9:
        u = fallback
    w = la.cross(axis, u)
    rim = ((-u[0] * r, -u[1] * r, -u[2] * r), (u[0] * r, u[1] * r, u[2] * r),
           (w[0] * r, w[1] * r, w[2] * r), (-w[0] * r, -w[1] * r, -w[2] * r))
    low = la.add(c, la.scale(h, la.scale(-1.0, axis)))  # the caps' centres
    high = la.add(c, la.scale(h, la.scale(1.0, axis)))
    o = gf[ga, G_PO]
    # the rim points written out into a tuple (no heap arrays per pair)
    rims = (_below(la.add(low, rim[0]), n, o), _below(la.add(low, rim[1]), n, o),
            _below(la.add(low, rim[2]), n, o), _below(la.add(low, rim[3]), n, o),
            _below(la.add(high, rim[0]), n, o), _below(la.add(high, rim[1]), n, o),
            _below(la.add(high, rim[2]), n, o), _below(la.add(high, rim[3]), n, o))
    return _deepest(rims, n, margin, C, k)


@kernel
def plane_capsule(gf, W, ga, gb, margin, C, k):
    """Half-space against both end spheres: two points when the capsule lies flat."""
    n = (gf[ga, G_PN], gf[ga, G_PN + 1], gf[ga, G_PN + 2])
    a, b = _segment(gf, W, gb)
    r = gf[gb, G_RADIUS]
    count = 0
    for end in (a, b):
        depth = r - (la.dot(n, end) - gf[ga, G_PO])
        if depth >= -margin:
            _put(C, k + count, la.sub(end, la.scale(r - 0.5 * depth, n)), n, depth)
            count += 1
    return count


@kernel
def closest_segment_points(p1, q1, p2, q2):
    """Parameters (s, t) of the closest points p1 + s (q1 - p1), p2 + t (q2 - p2) of two
    segments (Ericson, Real-Time Collision Detection, 5.1.9), as narrowphase's."""
    d1, d2, r = la.sub(q1, p1), la.sub(q2, p2), la.sub(p1, p2)
    a, e, f = la.dot(d1, d1), la.dot(d2, d2), la.dot(d2, r)
    c, b = la.dot(d1, r), la.dot(d1, d2)
    denom = a * e - b * b
    safe_a, safe_e = max(a, EPS), max(e, EPS)
    if denom > EPS * max(a * e, EPS):
        s = _clip((b * f - c * e) / (denom if denom > 0.0 else 1.0), 0.0, 1.0)
    else:
        s = 0.0
    t = (b * s + f) / safe_e
    if t < 0.0:
        s = _clip(-c / safe_a, 0.0, 1.0)
    elif t > 1.0:
        s = _clip((b - c) / safe_a, 0.0, 1.0)
    t = _clip(t, 0.0, 1.0)
    if a <= EPS:
        s = 0.0
        t = _clip(f / safe_e, 0.0, 1.0)
    if e <= EPS:
        t = 0.0
        if a > EPS:
            s = _clip(-c / safe_a, 0.0, 1.0)
    return s, t


@kernel(inline="always")
def _on_segment(p, a, b):
    d = la.sub(b, a)
    return la.add(a, la.scale(_clip(la.dot(la.sub(p, a), d) / max(la.dot(d, d), EPS), 0.0,
                                    1.0), d))


@kernel
def _least_distance_nearly_parallel(a1, b1, a2, b2):
    """narrowphase._least_distance_nearly_parallel: the lines' closest points from cross
    products where both lie inside, else the nearest of the four ends to the other
    segment (the same candidates in the same order); and whether the lines' points won."""
    d1, d2, r = la.sub(b1, a1), la.sub(b2, a2), la.sub(a2, a1)
    n = la.cross(d1, d2)
    nn = la.dot(n, n)
    best_p, best_q = a1, _on_segment(a1, a2, b2)
    best = la.norm(la.sub(best_q, best_p))
    q = _on_segment(b1, a2, b2)
    if la.norm(la.sub(q, b1)) < best:
        best_p, best_q, best = b1, q, la.norm(la.sub(q, b1))
    p = _on_segment(a2, a1, b1)
    if la.norm(la.sub(a2, p)) < best:
        best_p, best_q, best = p, a2, la.norm(la.sub(a2, p))
    p = _on_segment(b2, a1, b1)
    if la.norm(la.sub(b2, p)) < best:
        best_p, best_q, best = p, b2, la.norm(la.sub(b2, p))
    inside = False
    if nn > 0.0:
        s = la.dot(la.cross(r, d2), n) / nn
        t = la.dot(la.cross(r, d1), n) / nn
        if 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0:
            p, q = la.add(a1, la.scale(s, d1)), la.add(a2, la.scale(t, d2))
            if la.norm(la.sub(q, p)) < best:
                best_p, best_q, inside = p, q, True
    return best_p, best_q, inside


@kernel
def capsule_capsule(gf, W, ga, gb, margin, C, k):
    """Closest points of the two axes, then spheres; parallel axes that overlap along
    their length get two contacts, at the two ends of the overlap; the axes' least
    distance, where deeper than both ends, replaces the nearer end (at a capsule's end)
    or joins them (axes crossing between the ends)."""
    a1, b1 = _segment(gf, W, ga)
    a2, b2 = _segment(gf, W, gb)
    ra, rb = gf[ga, G_RADIUS], gf[gb, G_RADIUS]
    u, length = _unit(la.sub(b1, a1), UP)
    u2, _ = _unit(la.sub(b2, a2), UP)
    parallel = la.norm(la.cross(u, u2)) < PARALLEL_SIN
    s_a, s_b = la.dot(la.sub(a2, a1), u), la.dot(la.sub(b2, a1), u)
    lo = max(min(s_a, s_b), 0.0)
    hi = min(max(s_a, s_b), length)
    count = 0
    two = parallel and hi - lo > 1e-9 * (1.0 + length)
    ends_depth = -math.inf
    end_q = (la.sub(a1, a1), la.sub(a1, a1))  # the two ends' contact points, and where
    end_at = (-1, -1)  # they went in C (-1: beyond the margin)
    if two:
        # the ends of the overlap along the bisector of the axes, and both axes' points
        # there: the same contacts whichever capsule comes first (narrowphase)
        w, _ = _unit(la.add(u, la.scale(1.0 if la.dot(u, u2) >= 0.0 else -1.0, u2)), UP)
        s1, e1, s2, e2 = la.dot(a1, w), la.dot(b1, w), la.dot(a2, w), la.dot(b2, w)
        lo = max(min(s1, e1), min(s2, e2))
        hi = min(max(s1, e1), max(s2, e2))
        for e in range(2):
            end = lo if e == 0 else hi
            p1 = la.add(a1, la.scale(_clip((end - s1) / (e1 - s1), 0.0, 1.0),
                                     la.sub(b1, a1)))
            p2 = la.add(a2, la.scale(_clip((end - s2) / (e2 - s2), 0.0, 1.0),
                                     la.sub(b2, a2)))
            q, m, d = _spheres(p1, ra, p2, rb)
            ends_depth = max(ends_depth, d)
            end_q = (q, end_q[1]) if e == 0 else (end_q[0], q)
            if d >= -margin:
                _put(C, k + count, q, m, d)
                end_at = (count, end_at[1]) if e == 0 else (end_at[0], count)
                count += 1
    if two:
        # the least distance, where deeper than both ends beyond round-off (16 eps X for
        # points of magnitude X), replaces the nearer end (at a capsule's end) or joins
        # them (axes crossing between the ends): narrowphase.capsule_capsule
        p1, p2, inside = _least_distance_nearly_parallel(a1, b1, a2, b2)
        point, n, depth = _spheres(p1, ra, p2, rb)
        scale = 1.0 + length + max(abs(a1[0]), abs(a1[1]), abs(a1[2]), abs(a2[0]),
                                   abs(a2[1]), abs(a2[2]))
        if depth > ends_depth + 1e-13 * scale and depth >= -margin:
            if inside:
                _put(C, k + count, point, n, depth)
                count += 1
            else:
                hi_nearer = la.norm(la.sub(point, end_q[1])) < la.norm(la.sub(point,
                                                                              end_q[0]))
                at = end_at[1] if hi_nearer else end_at[0]
                if at < 0:  # that end was beyond the margin: this one is not
                    at = count
                    count += 1
                _put(C, k + at, point, n, depth)
        return count
    s, t = closest_segment_points(a1, b1, a2, b2)
    point, n, depth = _spheres(la.add(a1, la.scale(s, la.sub(b1, a1))), ra,
                               la.add(a2, la.scale(t, la.sub(b2, a2))), rb)
    if depth < -margin:
        return 0
    _put(C, k, point, n, depth)
    return 1


@kernel(inline="always")
def _box_sdf(p, half):
    q = (abs(p[0]) - half[0], abs(p[1]) - half[1], abs(p[2]) - half[2])
    outside = la.norm((max(q[0], 0.0), max(q[1], 0.0), max(q[2], 0.0)))
    return outside + min(max(q[0], q[1], q[2]), 0.0)


@kernel
def box_capsule(gf, W, ga, gb, margin, C, k):
    """The box's signed distance is convex, so along the capsule's axis a golden-section
    search finds the deepest axis point; the ends replace it when both touch the same face
    and one is as deep (the capsule lies on the box)."""
    c, R, half = _pos(W, ga), _rot(W, ga), _half(gf, ga)
    a, b = _segment(gf, W, gb)
    r = gf[gb, G_RADIUS]
    pa = la.mattvec(R, la.sub(a, c))
    pb = la.mattvec(R, la.sub(b, c))
    d = la.sub(pb, pa)
    lo, hi = 0.0, 1.0
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(GOLDEN_ITERATIONS):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        f1 = _box_sdf(la.add(pa, la.scale(x1, d)), half)
        f2 = _box_sdf(la.add(pa, la.scale(x2, d)), half)
        if f1 <= f2:
            hi = x2
        else:
            lo = x1
    s_mid = 0.5 * (lo + hi)
    s, best = 0.0, _box_sdf(la.add(pa, la.scale(0.0, d)), half)
    fm = _box_sdf(la.add(pa, la.scale(s_mid, d)), half)
    if fm < best:
        s, best = s_mid, fm
    if _box_sdf(la.add(pa, la.scale(1.0, d)), half) < best:
        s = 1.0
    p_min = la.add(a, la.scale(s, la.sub(b, a)))
    point, n, depth = _box_point(c, R, half, p_min, r)
    pe0, ne0, de0 = _box_point(c, R, half, a, r)
    pe1, ne1, de1 = _box_point(c, R, half, b, r)
    same = la.dot(ne0, n) > 0.999 and de0 >= -margin and la.dot(ne1, n) > 0.999 and \
        de1 >= -margin
    deepest_end = max(de0, de1) >= depth - 1e-12 * (1.0 + abs(depth))
    if same and deepest_end:
        _put(C, k, pe0, ne0, de0)
        _put(C, k + 1, pe1, ne1, de1)
        return 2
    if depth < -margin:
        return 0
    _put(C, k, point, n, depth)
    return 1


# ---------------------------------------------------------------------------- box - box

FACE_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))  # cyclic order
FACE_CANDIDATES = 24  # contact candidates of a face manifold (`_face_points`)

# box_box runs per box pair and step: it keeps its numbers in tuples, bit masks and one
# scratch array from its caller (`box_scratch`), not in arrays of its own, whose heap
# allocations (16 a pair) were a third of a box stack's step.


@kernel
def box_scratch():
    """Scratch of box_box, one per caller (reused pair after pair): its face manifold's
    candidates, a row each: point (3), depth below the reference face."""
    return np.empty((FACE_CANDIDATES, 4))


@kernel(inline="always")
def _quad_corner(c, fc, u, v, inc_c, inc_u, inc_v, inc_hu, inc_hv):
    """Corner c (FACE_SIGNS) of the incident face in the reference face's frame (fc; u, v)."""
    s0, s1 = FACE_SIGNS[c]
    corner = la.add(la.add(inc_c, la.scale(s0, la.scale(inc_hu, inc_u))),
                    la.scale(s1, la.scale(inc_hv, inc_v)))
    rel = la.sub(corner, fc)
    return la.dot(rel, u), la.dot(rel, v)


@kernel(inline="always")
def _lift(cand, i, x, y, good, fc, u, v, n, inc_n, inc_d, nn):
    """Candidate i: the point (x, y) of the reference face (its centre when not `good`)
    lifted along n onto the incident face's plane (inc_n . p = inc_d; nn = inc_n . n),
    into cand[i] (point, depth: minus its height above the reference face). Returns
    `good`."""
    if not good:
        x = 0.0
        y = 0.0
    base = la.add(la.add(fc, la.scale(x, u)), la.scale(y, v))
    hgt = (inc_d - la.dot(base, inc_n)) / nn
    p = la.add(base, la.scale(hgt, n))
    cand[i, 0], cand[i, 1], cand[i, 2] = p
    cand[i, 3] = -hgt
    return good


@kernel
def _face_points(fc, n, u, v, hu, hv, inc_c, inc_n, inc_u, inc_v, inc_hu, inc_hv, cand):
    """Contact candidates (24) of a reference face (centre fc, outward normal n towards
    the other box, in-plane axes u, v, half sizes hu, hv) and an incident face, as
    narrowphase._face_points: incident corners inside the rectangle, rectangle corners
    inside the incident quad, and edge crossings, lifted onto the incident face along n.
    Fills cand (24, 4) (point, depth below the reference face); returns which are valid
    as a bit mask (bit i: candidate i)."""
    # the quad's corners and edges in 4-tuples, each written out (no heap arrays)
    q0 = _quad_corner(0, fc, u, v, inc_c, inc_u, inc_v, inc_hu, inc_hv)
    q1 = _quad_corner(1, fc, u, v, inc_c, inc_u, inc_v, inc_hu, inc_hv)
    q2 = _quad_corner(2, fc, u, v, inc_c, inc_u, inc_v, inc_hu, inc_hv)
    q3 = _quad_corner(3, fc, u, v, inc_c, inc_u, inc_v, inc_hu, inc_hv)
    qx = (q0[0], q1[0], q2[0], q3[0])
    qy = (q0[1], q1[1], q2[1], q3[1])
    tol = 1e-9 * (1.0 + max(hu, hv))
    ex = (qx[1] - qx[0], qx[2] - qx[1], qx[3] - qx[2], qx[0] - qx[3])  # edge c: c -> c + 1
    ey = (qy[1] - qy[0], qy[2] - qy[1], qy[3] - qy[2], qy[0] - qy[3])
    area = 0.0
    for c in range(4):
        area += qx[c] * qy[(c + 1) % 4] - qx[(c + 1) % 4] * qy[c]
    wind = 1.0 if area >= 0.0 else -1.0
    inc_d = la.dot(inc_n, inc_c)
    nn = la.dot(inc_n, n)
    ok = 0
    for c in range(4):  # (a) incident corners inside the rectangle
        good = abs(qx[c]) <= hu + tol and abs(qy[c]) <= hv + tol
        if _lift(cand, c, qx[c], qy[c], good, fc, u, v, n, inc_n, inc_d, nn):
            ok |= 1 << c
    for c in range(4):  # (b) rectangle corners inside the incident quad
        bx, by = FACE_SIGNS[c][0] * hu, FACE_SIGNS[c][1] * hv
        inside = True
        for e in range(4):
            cr = ex[e] * (by - qy[e]) - ey[e] * (bx - qx[e])
            if not cr * wind >= -tol * (abs(ex[e]) + abs(ey[e])):
                inside = False
        if _lift(cand, 4 + c, bx, by, inside, fc, u, v, n, inc_n, inc_d, nn):
            ok |= 1 << (4 + c)
    slot = 8
    for line in range(2):  # (c) incident edges crossing the rectangle's edge lines
        for side in (-1.0, 1.0):
            for e in range(4):
                if line == 0:
                    q_line, q_along, e_line, e_along = qx[e], qy[e], ex[e], ey[e]
                    h_line, h_along = hu, hv
                else:
                    q_line, q_along, e_line, e_along = qy[e], qx[e], ey[e], ex[e]
                    h_line, h_along = hv, hu
                t = (side * h_line - q_line) / e_line
                w = q_along + t * e_along
                good = math.isfinite(t) and t >= 0.0 and t <= 1.0 and \
                    abs(w) <= h_along + tol
                x = side * h_line
                if line == 0:
                    px, py = x, w
                else:
                    px, py = w, x
                if _lift(cand, slot, px, py, good, fc, u, v, n, inc_n, inc_d, nn):
                    ok |= 1 << slot
                slot += 1
    return ok


@kernel(inline="always")
def _dist_to(pts, i, j):
    return la.norm((pts[i, 0] - pts[j, 0], pts[i, 1] - pts[j, 1], pts[i, 2] - pts[j, 2]))


@kernel
def _reduce(cand, within):
    """At most 4 well-spread points among the candidates cand[i] of bit mask `within`
    (contacts.reduce_manifold): the deepest, then farthest-point sampling. Returns their
    bit mask. Sets are bit masks (bit i: candidate i) walked in candidate order, and the
    picks a tuple in pick order (the order of the minimum over them): no heap arrays."""
    unique = 0
    nu = 0
    for i in range(FACE_CANDIDATES):
        if not within & (1 << i):
            continue
        near = math.inf
        for j in range(i):
            if unique & (1 << j):
                near = min(near, _dist_to(cand, i, j))
        if nu == 0 or near > 1e-9:  # (the first is kept)
            unique |= 1 << i
            nu += 1
    if nu <= 4:
        return unique
    best = -1
    for q in range(FACE_CANDIDATES):
        if unique & (1 << q) and (best < 0 or cand[q, 3] > cand[best, 3]):
            best = q
    taken = 1 << best
    picks = (best, best, best)  # the first 3 picks, in pick order
    for nc in range(1, 4):
        pick, far = -1, -math.inf
        for i in range(FACE_CANDIDATES):
            if not unique & (1 << i) or taken & (1 << i):
                continue
            near = math.inf
            for c in range(nc):
                near = min(near, _dist_to(cand, i, picks[c]))
            if near > far:
                pick, far = i, near
        if pick < 0:  # (only NaN distances left: points of NaN)
            break
        taken |= 1 << pick
        picks = (picks[0], pick if nc == 1 else picks[1], pick if nc == 2 else picks[2])
    return taken


@kernel
def _sat_axis(A, B, ha, hb, t, q):
    """box_box's separating axis q (0-2: A's faces, 3-5: B's, 6-14: the cross of A's axis
    (q - 6) // 3 and B's (q - 6) % 3) for the centres' offset t: (unit axis, the offset
    along it, the overlap of the boxes along it; inf for parallel edges: no axis)."""
    if q < 3:
        ax = _col(A, q)
    elif q < 6:
        ax = _col(B, q - 3)
    else:
        ax = la.cross(_col(A, (q - 6) // 3), _col(B, (q - 6) % 3))
    axu, length = _unit(ax, UP)
    ra = 0.0
    rb = 0.0
    for j in range(3):
        ra += ha[j] * abs(la.dot(_col(A, j), axu))
    for j in range(3):
        rb += hb[j] * abs(la.dot(_col(B, j), axu))
    dist = la.dot(t, axu)
    overlap = ra + rb - abs(dist)
    if q >= 6 and length < 1e-6:  # parallel edges: no axis
        overlap = math.inf
    return axu, dist, overlap


@kernel
def box_box(gf, W, ga, gb, margin, C, k, cand=None):
    """Separating axes (3 + 3 faces, 9 edge crosses), then a face manifold (the overlap
    of the reference and incident faces, up to 4 points) or an edge contact (closest
    points of the two edges). Face axes win unless an edge axis is 5 % shallower. A tie
    of two axes that are not parallel (a face of A and one of B, or two edge pairs,
    equally shallow to TIE_TOL) gives the contacts of both, not of the first body's:
    a box meeting its mirror image corner to corner touches both face planes; an edge
    contact adds the shallowest face's manifold points within the margin
    (narrowphase.box_box). `cand`: scratch (`box_scratch`; one is made when not given)."""
    if cand is None:
        cand = box_scratch()
    ca, cb = _pos(W, ga), _pos(W, gb)
    A, B = _rot(W, ga), _rot(W, gb)
    ha, hb = _half(gf, ga), _half(gf, gb)
    t = la.sub(cb, ca)
    # sat[q]: (unit axis, offset along it, overlap) of axis q, written out into a tuple
    sat = (_sat_axis(A, B, ha, hb, t, 0), _sat_axis(A, B, ha, hb, t, 1),
           _sat_axis(A, B, ha, hb, t, 2), _sat_axis(A, B, ha, hb, t, 3),
           _sat_axis(A, B, ha, hb, t, 4), _sat_axis(A, B, ha, hb, t, 5),
           _sat_axis(A, B, ha, hb, t, 6), _sat_axis(A, B, ha, hb, t, 7),
           _sat_axis(A, B, ha, hb, t, 8), _sat_axis(A, B, ha, hb, t, 9),
           _sat_axis(A, B, ha, hb, t, 10), _sat_axis(A, B, ha, hb, t, 11),
           _sat_axis(A, B, ha, hb, t, 12), _sat_axis(A, B, ha, hb, t, 13),
           _sat_axis(A, B, ha, hb, t, 14))
    face_a = 0
    for q in range(1, 3):
        if sat[q][2] < sat[face_a][2]:
            face_a = q
    face_b = 3
    for q in range(4, 6):
        if sat[q][2] < sat[face_b][2]:
            face_b = q
    face = face_b if sat[face_b][2] < sat[face_a][2] else face_a
    edge = 6
    for q in range(7, 15):
        if sat[q][2] < sat[edge][2]:
            edge = q
    edge2 = -1
    for q in range(6, 15):
        if q != edge and (edge2 < 0 or sat[q][2] < sat[edge2][2]):
            edge2 = q
    f_ov, e_ov = sat[face][2], sat[edge][2]
    use_edge = e_ov < f_ov - 0.05 * abs(f_ov) - 1e-6
    best = edge if use_edge else face
    depth_sat = sat[best][2]
    if not depth_sat >= -margin:
        return 0
    tie_tol = TIE_TOL * (1.0 + max(ha[0], ha[1], ha[2]) + max(hb[0], hb[1], hb[2]))
    other = face_b if face == face_a else face_a
    La, Lb = sat[face_a][0], sat[face_b][0]
    cos = abs(La[0] * Lb[0] + La[1] * Lb[1] + La[2] * Lb[2])
    faces_tie = abs(sat[face_a][2] - sat[face_b][2]) <= tie_tol and \
        cos < 1.0 - PARALLEL_COS
    if use_edge:
        # the shallowest face's manifold points within the margin (what the pair can
        # close in a step) are contacts too, before the edge's: an edge lying across a
        # face (a bar across a table, tilted 1.5 mrad) touches along a segment, and its
        # one edge-edge point at a rim let it rock about that rim, the far end reached
        # the face unseen within a step and the position pass lifted it out (+1e-4 J a
        # step, a pile of 4 boxes rocking for 11 s: tests/test_pile_rest.py). Those points
        # are points of the other box within the margin of the face, inside its rims.
        got = _box_face(ca, cb, A, B, ha, hb, sat[face], face, margin, False, cand, C, k)
        if faces_tie:  # (both faces, as for face contacts: a mirror image's pair)
            got += _box_face(ca, cb, A, B, ha, hb, sat[other], other, margin, False, cand,
                             C, k + got)
        got += _box_edge(ca, cb, A, B, ha, hb, sat[best], best, C, k + got)
        if sat[edge2][2] - e_ov <= tie_tol:
            got += _box_edge(ca, cb, A, B, ha, hb, sat[edge2], edge2, C, k + got)
        return got
    got = _box_face(ca, cb, A, B, ha, hb, sat[best], best, margin, True, cand, C, k)
    if faces_tie:
        got += _box_face(ca, cb, A, B, ha, hb, sat[other], other, margin, True, cand, C,
                         k + got)
    return got


@kernel
def _box_edge(ca, cb, A, B, ha, hb, axis, best, C, k):
    """The edge contact of box_box along edge axis `best` (`axis`: its sat tuple): the
    closest points of the supporting edges of A (towards B) and of B (towards A).
    Returns 1."""
    L, dist, depth_sat = axis
    sgn = 1.0 if dist >= 0.0 else -1.0
    n = (L[0] * sgn, L[1] * sgn, L[2] * sgn)  # A -> B
    i, j = (best - 6) // 3, (best - 6) % 3
    pa, pb = ca, cb
    for q in range(3):
        sa = 1.0 if la.dot(_col(A, q), n) >= 0.0 else -1.0
        sb = -1.0 if la.dot(_col(B, q), n) >= 0.0 else 1.0
        if q != i:
            pa = la.add(pa, la.scale(sa * ha[q], _col(A, q)))
        if q != j:
            pb = la.add(pb, la.scale(sb * hb[q], _col(B, q)))
    da = la.scale(ha[i], _col(A, i))
    db = la.scale(hb[j], _col(B, j))
    s, tt = closest_segment_points(la.sub(pa, da), la.add(pa, da), la.sub(pb, db),
                                   la.add(pb, db))
    wa = la.add(la.sub(pa, da), la.scale(2.0 * s, da))
    wb = la.add(la.sub(pb, db), la.scale(2.0 * tt, db))
    _put(C, k, la.scale(0.5, la.add(wa, wb)), n, depth_sat)
    return 1


@kernel
def _box_face(ca, cb, A, B, ha, hb, axis, best, margin, fallback, cand, C, k):
    """The face manifold of box_box with the reference face of axis `best` (0-2: on A,
    3-5: on B; `axis`: its sat tuple): the overlap of the reference and the incident
    face, up to 4 points within the margin (none: the nearest incident corner if
    `fallback`, else nothing); cand: scratch (`box_scratch`). Returns how many."""
    L, dist, depth_sat = axis
    sgn = 1.0 if dist >= 0.0 else -1.0
    n = (L[0] * sgn, L[1] * sgn, L[2] * sgn)  # A -> B
    on_a = best < 3
    kk = best % 3
    if on_a:
        R_ref, h_ref, c_ref, R_inc, h_inc, c_inc, nr = A, ha, ca, B, hb, cb, n
    else:
        R_ref, h_ref, c_ref, R_inc, h_inc, c_inc, nr = B, hb, cb, A, ha, ca, la.scale(-1.0, n)
    fc = la.add(c_ref, la.scale(h_ref[kk], nr))
    u, v = _col(R_ref, (kk + 1) % 3), _col(R_ref, (kk + 2) % 3)
    hu, hv = h_ref[(kk + 1) % 3], h_ref[(kk + 2) % 3]
    mm = 0
    dots0 = la.dot(_col(R_inc, 0), nr)
    best_dot = dots0
    for q in range(1, 3):
        dq = la.dot(_col(R_inc, q), nr)
        if abs(dq) > abs(best_dot):
            mm, best_dot = q, dq
    sign = -(1.0 if best_dot >= 0.0 else -1.0)
    inc_n = la.scale(sign, _col(R_inc, mm))
    inc_c = la.add(c_inc, la.scale(h_inc[mm], inc_n))
    ok = _face_points(fc, nr, u, v, hu, hv, inc_c, inc_n, _col(R_inc, (mm + 1) % 3),
                      _col(R_inc, (mm + 2) % 3), h_inc[(mm + 1) % 3], h_inc[(mm + 2) % 3],
                      cand)
    within = 0  # the valid candidates within the margin (bit q: candidate q)
    for q in range(FACE_CANDIDATES):
        if ok & (1 << q) and cand[q, 3] >= -margin:
            within |= 1 << q
    if within == 0:
        if not fallback:
            return 0
        # apart within the margin with faces that do not overlap side by side: the
        # incident corner nearest to the reference plane, at the axis' gap
        corner = 0
        for q in range(1, 4):
            if cand[q, 3] > cand[corner, 3]:
                corner = q
        p = (cand[corner, 0], cand[corner, 1], cand[corner, 2])
        _put(C, k, la.add(p, la.scale(0.5 * cand[corner, 3], nr)), n, depth_sat)
        return 1
    keep = _reduce(cand, within)
    nc = 0
    for q in range(FACE_CANDIDATES):  # in candidate order
        if keep & (1 << q):
            p = (cand[q, 0], cand[q, 1], cand[q, 2])
            _put(C, k + nc, la.add(p, la.scale(0.5 * cand[q, 3], nr)), n, cand[q, 3])
            nc += 1
    return nc


# ----------------------------------------------------------------------------- dispatch


@kernel(inline="always")
def _first(ta, tb):
    """Which geom of a pair of types comes first in the pair function (the table of
    narrowphase.DISPATCH): 0 the first as given, 1 the second, -1 no closed form here."""
    if ta == SPHERE and tb == SPHERE:
        return 0
    if ta == PLANE or tb == PLANE:
        if ta == PLANE and tb == PLANE:
            return -1
        other = tb if ta == PLANE else ta
        if other == SPHERE or other == BOX or other == CAPSULE or other == CYLINDER:
            return 0 if ta == PLANE else 1
        return -1
    if ta == BOX and (tb == SPHERE or tb == CAPSULE or tb == BOX):
        return 0
    if tb == BOX and (ta == SPHERE or ta == CAPSULE):
        return 1
    if ta == CAPSULE and (tb == SPHERE or tb == CAPSULE):
        return 0
    if tb == CAPSULE and ta == SPHERE:
        return 1
    if ta == CYLINDER and tb == SPHERE:
        return 0
    if tb == CYLINDER and ta == SPHERE:
        return 1
    return -1


@kernel
def pair_contacts(gf, W, ga, gb, margin, C, k, cand):
    """Contacts of geoms ga (first) and gb whose types have a closed form here, normals
    from ga to gb, written from row k of C; returns how many. cand: box_box's scratch
    (`box_scratch`)."""
    ta, tb = int(gf[ga, G_TYPE]), int(gf[gb, G_TYPE])
    if ta == SPHERE and tb == SPHERE:
        return sphere_sphere(gf, W, ga, gb, margin, C, k)
    if ta == PLANE:
        if tb == SPHERE:
            return plane_sphere(gf, W, ga, gb, margin, C, k)
        if tb == BOX:
            return plane_box(gf, W, ga, gb, margin, C, k)
        if tb == CAPSULE:
            return plane_capsule(gf, W, ga, gb, margin, C, k)
        return plane_cylinder(gf, W, ga, gb, margin, C, k)
    if ta == BOX:
        if tb == SPHERE:
            return box_sphere(gf, W, ga, gb, margin, C, k)
        if tb == CAPSULE:
            return box_capsule(gf, W, ga, gb, margin, C, k)
        return box_box(gf, W, ga, gb, margin, C, k, cand)
    if ta == CAPSULE:
        if tb == SPHERE:
            return capsule_sphere(gf, W, ga, gb, margin, C, k)
        return capsule_capsule(gf, W, ga, gb, margin, C, k)
    return cylinder_sphere(gf, W, ga, gb, margin, C, k)


@kernel(inline="always")
def _rounding(gf, g):
    """m: every closed form here puts a sphere's or capsule's witness point at its radius
    from the sphere (or segment point) it came from; other shapes' points are on faces,
    edges or corners."""
    t = int(gf[g, G_TYPE])
    return gf[g, G_RADIUS] if t == SPHERE or t == CAPSULE else 0.0


@kernel(inline="always")
def own_rows(gf, ga, gb, C, k, got):
    """Rows [k, k + got) that pair_contacts(ga, gb) wrote, given to their bodies: the
    lower body first (the normal turned to point from it), and each side's rounding."""
    ba, bb = int(gf[ga, G_BODY]), int(gf[gb, G_BODY])
    flip = ba > bb
    rga, rgb = _rounding(gf, ga), _rounding(gf, gb)
    for q in range(k, k + got):
        C[q, C_A] = min(ba, bb)
        C[q, C_B] = max(ba, bb)
        C[q, C_ROUND_A] = rgb if flip else rga
        C[q, C_ROUND_B] = rga if flip else rgb
        if flip:
            for c in range(3):
                C[q, C_N + c] = -C[q, C_N + c]


@kernel
def narrow_phase(gf, W, P, m, sweep, tolerance, C):
    """Contacts of the m candidate pairs P: per pair, the closed form with the margin
    sweep_a + sweep_b + tolerance, the normal turned to point from the lower body to the
    higher; pairs without a closed form here into F. Returns (C, k, F, nf), contacts
    sorted by (body_a, body_b) with each pair's points in their order."""
    k = np.int64(0)  # not literal zeros: callees would be compiled twice
    F = np.empty((4, 2), np.int64)
    nf = np.int64(0)
    cand = box_scratch()  # one for all pairs
    for p in range(m):
        g1, g2 = P[p, 0], P[p, 1]
        if gf[g1, G_PYTHON] != 0.0 or gf[g2, G_PYTHON] != 0.0:
            first = -1
        else:
            first = _first(int(gf[g1, G_TYPE]), int(gf[g2, G_TYPE]))
        if first < 0:
            F = _push_pair(F, nf, g1, g2)
            nf += 1
            continue
        ga, gb = (g1, g2) if first == 0 else (g2, g1)
        ba, bb = int(gf[ga, G_BODY]), int(gf[gb, G_BODY])
        margin = sweep[ba] + sweep[bb] + tolerance
        C = _grow(C, k, MAX_PER_PAIR)
        got = pair_contacts(gf, W, ga, gb, margin, C, k, cand)
        own_rows(gf, ga, gb, C, k, got)
        k += got
    if k > 1:
        C = sort_by_pair(C, k)
    return C, k, F, nf


@kernel
def _counting_order(keys, k, buckets, within):
    """Stable order of rows `within` (k,) by integer keys[row] in [0, buckets)."""
    count = np.zeros(buckets + 1, np.int64)
    for q in range(k):
        count[keys[within[q]] + 1] += 1
    for b in range(buckets):
        count[b + 1] += count[b]
    out = np.empty(k, np.int64)
    for q in range(k):
        row = within[q]
        out[count[keys[row]]] = row
        count[keys[row]] += 1
    return out


@kernel
def sort_by_pair(C, k):
    """Rows [0, k) of C sorted by (body_a, body_b), stably (a pair's points keep their
    order): two counting sorts (by b, then by a), no comparison sort. Any table whose
    columns 0 and 1 are the two bodies (kernels.stepped's contact table too)."""
    nb = 1
    ka = np.empty(k, np.int64)
    kb = np.empty(k, np.int64)
    for q in range(k):
        ka[q] = int(C[q, C_A])
        kb[q] = int(C[q, C_B])
        nb = max(nb, kb[q] + 1)
    rows = np.empty(k, np.int64)
    for q in range(k):
        rows[q] = q
    order = _counting_order(ka, k, nb, _counting_order(kb, k, nb, rows))
    out = np.empty((max(k, C.shape[0]), C.shape[1]))
    for q in range(k):
        for c in range(C.shape[1]):
            out[q, c] = C[order[q], c]
    return out


@kernel
def make_planar(C, k):
    """2D: contacts in the z = 0 plane (contacts.planar): z of points and normals dropped
    (normals renormalised), then points of one pair that now coincide (to 1e-9 m) removed,
    keeping the first. Returns the new count."""
    out = 0
    for q in range(k):
        C[q, C_P + 2] = C[q, C_P + 2] * 0.0
        nx, ny = C[q, C_N], C[q, C_N + 1]
        length = math.sqrt(nx * nx + ny * ny + 0.0)
        if length > 0.0:
            C[q, C_N] = nx / length
            C[q, C_N + 1] = ny / length
            C[q, C_N + 2] = 0.0
        dup = False
        kx, ky = round(C[q, C_P] * 1e9), round(C[q, C_P + 1] * 1e9)
        j = out - 1
        while j >= 0 and C[j, C_A] == C[q, C_A] and C[j, C_B] == C[q, C_B]:
            if round(C[j, C_P] * 1e9) == kx and round(C[j, C_P + 1] * 1e9) == ky:
                dup = True
                break
            j -= 1
        if not dup:
            if out != q:
                for c in range(C_SIZE):
                    C[out, c] = C[q, c]
            out += 1
    return out


@kernel
def detect(gf, S, step, sweep, tolerance, planar):
    """The contacts of state S (see the module docstring): place, tight AABBs grown by the
    bodies' sweeps and half the tolerance, broad phase, narrow phase, planar in 2D.
    Returns (k, C, F, nf)."""
    n_geom = gf.shape[0]
    W = np.empty((n_geom, W_SIZE))
    place(gf, S, W)
    pad = np.empty(n_geom)
    for g in range(n_geom):
        pad[g] = sweep[int(gf[g, G_BODY])] + 0.5 * tolerance
    lo = np.empty((n_geom, 3))
    hi = np.empty((n_geom, 3))
    aabbs(gf, S, W, pad, lo, hi)
    P, m = broad_phase(gf, lo, hi, step, pad)
    C = np.empty((max(16, 2 * m), C_SIZE))
    C, k, F, nf = narrow_phase(gf, W, P, m, sweep, tolerance, C)
    if planar:
        k = make_planar(C, k)
    return k, C, F, nf
