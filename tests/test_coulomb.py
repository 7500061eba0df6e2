"""`kernels.coulomb.polish`, Newton's end of a small island's contact solve (issue 48 item 3).

Truth independent of the solver:
- Coulomb's conditions themselves, checked in numpy on the answer: normal impulses >= 0,
  no row below its target, complementarity, friction in its cone, sticking contacts not
  slipping and sliding ones' friction exactly against their slip;
- frictionless islands: the velocities are unique (the impulses are not, where contacts
  are redundant), and an enumeration of the sets of acting contacts, written here, must
  give them;
- a box sliding on its face on a slope: Coulomb's closed form, friction mu N against the
  slip at every corner whatever the split of the load.
The islands are drawn as the compiled step builds them: bodies with random masses and
inertias, contacts on faces (redundant: four corners), between bodies and on the ground,
targets -gap/dt of random gaps, velocities and mu at random, and warm starts.
"""

from __future__ import annotations

import numpy as np
import pytest

from vrsim_cli.kernels import coulomb

# A row is met to this share of the island's velocity scale: the polish stops at
# coulomb.ROUNDOFF (1e-14) of the impulse scale; 1e-10 leaves the round-off of A's
# products over ~50 terms and of the condition of a 3-body island's A a margin of 1e4.
MET = 1e-10


def _basis(n):
    h = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, h)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def _rot(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _island(rng, kind):
    """(A, normals' count m): the Delassus matrix J M^-1 J^T of a drawn island."""
    if kind == "face":  # one box on the ground: its face's four corners
        nb = 1
    elif kind == "stack":  # two boxes on the ground, one on the other
        nb = 2
    else:  # spheres and boxes touching each other and the ground at random points
        nb = int(rng.integers(1, 4))
    inv_m = 1.0 / rng.uniform(0.2, 10.0, nb)
    inv_i = []
    for _ in range(nb):
        R = _rot(rng)
        inv_i.append(R @ np.diag(1.0 / rng.uniform(0.01, 2.0, 3)) @ R.T)
    rows = []

    def contact(a, b, n, ra, rb):
        t1, t2 = _basis(n)
        Jr = np.zeros((3, 6 * nb))
        for j, d in enumerate((n, t1, t2)):
            Jr[j, 6 * b:6 * b + 3] = d
            Jr[j, 6 * b + 3:6 * b + 6] = np.cross(rb, d)
            if a >= 0:
                Jr[j, 6 * a:6 * a + 3] = -d
                Jr[j, 6 * a + 3:6 * a + 6] = -np.cross(ra, d)
        rows.append(Jr)

    if kind in ("face", "stack"):
        for b in range(nb):
            R = _rot(rng) if kind == "face" else np.eye(3)
            n = R[:, 2]
            half = rng.uniform(0.05, 0.6, 3)
            for sx in (-1, 1):
                for sy in (-1, 1):
                    corner = R @ (half * np.array([sx, sy, -1.0]))
                    contact(b - 1, b, n, corner + 2 * half[2] * n, corner)
    else:
        for _ in range(int(rng.integers(1, 7))):
            b = int(rng.integers(nb))
            a = int(rng.integers(-1, nb))
            if a == b:
                a = -1
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            contact(a, b, n, rng.normal(size=3) * 0.3, rng.normal(size=3) * 0.3)
    J = np.vstack(rows)
    Minv = np.zeros((6 * nb, 6 * nb))
    for b in range(nb):
        Minv[6 * b:6 * b + 3, 6 * b:6 * b + 3] = np.eye(3) * inv_m[b]
        Minv[6 * b + 3:6 * b + 6, 6 * b + 3:6 * b + 6] = inv_i[b]
    return J @ Minv @ J.T, len(rows)


def _feasible_problem(rng, kind):
    """A drawn island with targets that some impulses can meet: the targets are the
    velocities of random pushing impulses minus random slack (each row at or above its
    target there), so the frictionless problem has a solution; mu at random."""
    A, m = _island(rng, kind)
    u0 = rng.normal(size=3 * m)
    push = np.zeros(3 * m)
    push[0::3] = rng.uniform(0.0, 3.0, m)
    reach = u0 + A @ push
    tn = reach[0::3] - rng.uniform(0.0, 0.5, m) * (rng.random(m) < 0.5)
    lam0 = np.zeros(3 * m)
    if rng.random() < 0.5:  # a warm start (impulses already in the velocities)
        lam0[0::3] = rng.uniform(0.0, 1.0, m)
        u0 = u0 + A @ lam0
    mu = rng.uniform(0.0, 1.2, m) * (rng.random(m) < 0.8)
    return A, u0, lam0, tn, mu, m


def coulomb_violations(A, u0, lam0, tn, off, mu, lam, fixed=None, e=None):
    """Coulomb's conditions on lam, in numpy: a list of (contact, what) that fail."""
    m = len(mu)
    u = u0 + A @ (lam - lam0)
    vs = max(np.abs(u0).max(), np.abs(tn).max(), np.abs(u).max(), 1e-300)
    ls = max(np.abs(lam).max(), 1e-300)
    bad = []
    for i in range(m):
        p = 3 * i
        ln, gap = lam[p], u[p] - tn[i]
        lt, w = lam[p + 1:p + 3], u[p + 1:p + 3] + off[i]
        if ln < -MET * ls:
            bad.append((i, "pulls"))
        if gap < -MET * vs:
            bad.append((i, "below its target"))
        if ln > MET * ls and gap > MET * vs:
            bad.append((i, "pushes while opening"))
        if fixed is not None and fixed[i]:
            if np.abs(lt + mu[i] * ln * e[i]).max() > MET * ls:
                bad.append((i, "fixed slide"))
            continue
        if np.linalg.norm(lt) > mu[i] * ln + MET * ls:
            bad.append((i, "outside its cone"))
        if ln <= MET * ls:
            continue
        if np.linalg.norm(w) > MET * vs:  # slips: friction at mu N against the slip
            if abs(np.linalg.norm(lt) - mu[i] * ln) > MET * ls or \
                    mu[i] * ln > MET * ls and \
                    np.linalg.norm(lt / np.linalg.norm(lt) + w / np.linalg.norm(w)) > 1e-8:
                bad.append((i, "slips with friction not against it"))
    return bad


def _sweeps(A, u0, lam0, tn, mu, sweeps=1000, e=None):
    """Projected Gauss-Seidel in numpy (as the compiled step's sweeps, written again):
    the normal towards its target clamped >= 0, then the tangent block's sticking
    impulse if inside the disc, else a step along -w projected onto it (held at
    -mu l_n e where e is given: sliding along a fixed direction).

    A sweep is a function of (lam, u) alone: one that leaves both bit for bit as they
    were has reached its fixed point, and every later sweep would too, so the loop stops
    there with the very bits the remaining sweeps would end on (most draws get there in
    10-700 sweeps). Each tangent block's largest eigenvalue is computed once."""
    lam = lam0.copy()
    u = u0.copy()
    m = len(mu)
    largest = {}  # contact -> np.linalg.eigvalsh(K).max() of its (constant) tangent block
    for _ in range(sweeps):
        before = lam.tobytes() + u.tobytes()
        for i in range(m):
            p = 3 * i
            new = max(lam[p] - (u[p] - tn[i]) / A[p, p], 0.0)
            u += A[:, p] * (new - lam[p])
            lam[p] = new
            K = A[p + 1:p + 3, p + 1:p + 3]
            w = u[p + 1:p + 3]
            s = lam[p + 1:p + 3] - np.linalg.solve(K, w)
            bound = mu[i] * lam[p]
            if e is not None:
                s = -bound * e[i]
            elif s @ s > bound * bound:
                if i not in largest:
                    largest[i] = np.linalg.eigvalsh(K).max()
                s = lam[p + 1:p + 3] - w / largest[i]
                norm = np.linalg.norm(s)
                if norm > bound:
                    s = s * (bound / norm) if norm > 0 else 0 * s
            u += A[:, p + 1:p + 3] @ (s - lam[p + 1:p + 3])
            lam[p + 1:p + 3] = s
        if lam.tobytes() + u.tobytes() == before:
            break
    return lam


def _alart_curnier(A, u0, lam0, tn, mu, lam):
    m = len(mu)
    r = np.empty(3 * m)
    coulomb.rho(A, r)
    F = np.empty(3 * m)
    u = u0 + A @ (lam - lam0)
    return coulomb.residual(u, lam, tn, np.zeros((m, 2)), mu, np.zeros(m, np.bool_),
                            np.zeros((m, 2)), r, F)


# Sweeps that have found the acting and sliding contacts leave F small: within this share
# of the island's impulse scale the polish must end on Coulomb's law (the sweeps' own
# stop, REST_SETTLED, is a relative change of 1e-15 a sweep, not a residual: near the
# cone's edge and on redundant faces they stop at 1e-6 .. 1e-3 of it).
NEAR = 1e-3


@pytest.mark.parametrize("kind", ["face", "stack", "random"])
def test_the_polish_meets_coulombs_conditions_after_sweeps(kind):
    """80 drawn islands of each kind, swept as the step does (1000 sweeps, written here),
    then polished: where the sweeps ended within NEAR of the solution, Coulomb's
    conditions are met to round-off; and in every draw |F| is no larger than the sweeps
    left it."""
    rng = np.random.default_rng({"face": 11, "stack": 12, "random": 13}[kind])
    failures, near = [], 0
    for draw in range(80):
        A, u0, lam0, tn, mu, m = _feasible_problem(rng, kind)
        off = np.zeros((m, 2))
        lam = _sweeps(A, u0, lam0, tn, mu)
        before = _alart_curnier(A, u0, lam0, tn, mu, lam)
        # the problem's own impulse scale (what the targets ask of each row from u0),
        # not the sweeps' impulses (which ran to 5e3 where they had not settled)
        ask = np.abs(u0[0::3] - tn) / np.diag(A)[0::3]
        close = before <= NEAR * max(ask.max(), 1e-300)
        ok, steps = coulomb.polish(A, u0, lam0, tn, off, mu, np.zeros(m, np.bool_),
                                   np.zeros((m, 2)), lam)
        bad = coulomb_violations(A, u0, lam0, tn, off, mu, lam)
        near += close
        after = _alart_curnier(A, u0, lam0, tn, mu, lam)
        # (the polish compares F as it sums it; numpy's sums differ by round-off)
        if close and (not ok or bad) or after > before * (1.0 + 1e-12):
            failures.append((draw, ok, steps, "%.1e" % before, bad[:3]))
    assert not failures, failures[:5]
    assert near >= 60, near  # the class is tested: most draws end near


def test_the_polish_never_moves_away_from_coulombs_law():
    """From cold starts (random impulses, no sweeps), where Newton alone need not
    converge: |F| after the polish is never above |F| before it (the line search)."""
    rng = np.random.default_rng(14)
    for draw in range(120):
        A, u0, lam0, tn, mu, m = _feasible_problem(rng, ("face", "stack", "random")[draw % 3])
        lam = lam0 + np.abs(rng.normal(size=3 * m))
        before = _alart_curnier(A, u0, lam0, tn, mu, lam)
        coulomb.polish(A, u0, lam0, tn, np.zeros((m, 2)), mu, np.zeros(m, np.bool_),
                       np.zeros((m, 2)), lam)
        # (the polish compares F as it sums it; numpy's sums differ by round-off)
        assert _alart_curnier(A, u0, lam0, tn, mu, lam) <= before * (1.0 + 1e-12)


def _enumerated(A, u0, lam0, tn):
    """An independent frictionless solve by enumeration: for every set S of acting
    contacts, the least-squares impulses x_S of A_SS x_S = -b_S; the first set whose x
    is >= 0, meets its rows and leaves the others at or above their targets is a
    solution of the LCP w = A_nn x + b >= 0, x >= 0, x.w = 0 (b = u0_n - A_nn lam0_n -
    tn). Returns the normal velocities at it."""
    from itertools import combinations

    An = A[0::3, 0::3]
    b = u0[0::3] - An @ lam0[0::3] - tn
    m = len(b)
    scale = max(np.abs(b).max(), 1e-300)
    for size in range(m + 1):
        for S in combinations(range(m), size):
            x = np.zeros(m)
            if S:
                idx = list(S)
                x[idx] = np.linalg.lstsq(An[np.ix_(idx, idx)], -b[idx], rcond=1e-12)[0]
            w = An @ x + b
            if (x >= -1e-12 * max(np.abs(x).max(), 1.0)).all() and \
                    (np.abs(w[list(S)]) <= 1e-10 * scale).all() and \
                    (w >= -1e-10 * scale).all():
                return u0[0::3] + An @ (x - lam0[0::3])
    raise AssertionError("no set of acting contacts solves the problem")


@pytest.mark.parametrize("kind", ["face", "stack"])
def test_frictionless_velocities_match_an_independent_solve(kind):
    """mu = 0, after sweeps: the normal velocities the polish ends at are those of an enumeration
    of the acting sets (unique, though the impulses are not), to 1e-9 of the velocity
    scale."""
    rng = np.random.default_rng({"face": 21, "stack": 22}[kind])
    worst = 0.0
    for _ in range(30):
        A, u0, lam0, tn, _, m = _feasible_problem(rng, kind)
        mu = np.zeros(m)
        lam = _sweeps(A, u0, lam0, tn, mu)
        ok, _ = coulomb.polish(A, u0, lam0, tn, np.zeros((m, 2)), mu, np.zeros(m, np.bool_),
                               np.zeros((m, 2)), lam)
        assert ok
        un = (u0 + A @ (lam - lam0))[0::3]
        ref = _enumerated(A, u0, lam0, tn)
        scale = max(np.abs(u0).max(), np.abs(tn).max())
        worst = max(worst, np.abs(un - ref).max() / scale)
    assert worst <= 1e-9, worst


def test_a_face_held_sliding_along_a_direction():
    """`fixed` contacts (slip_stops' re-solve): friction mu N along -e exactly, normals
    complementary, on drawn faces."""
    rng = np.random.default_rng(31)
    for _ in range(40):
        A, u0, lam0, tn, mu, m = _feasible_problem(rng, "face")
        fixed = np.ones(m, np.bool_)
        ang = rng.uniform(0, 2 * np.pi)
        e = np.tile([np.cos(ang), np.sin(ang)], (m, 1))
        off = np.zeros((m, 2))
        lam = _sweeps(A, u0, lam0, tn, mu, e=e)
        ok, _ = coulomb.polish(A, u0, lam0, tn, off, mu, fixed, e, lam)
        assert ok
        assert not coulomb_violations(A, u0, lam0, tn, off, mu, lam, fixed, e)


def test_lu_solve_against_numpy():
    """The elimination against LAPACK on random regular systems (1e-12 relative)."""
    rng = np.random.default_rng(41)
    for size in (1, 3, 12, 48):
        J = rng.normal(size=(size, size)) + size * np.eye(size)
        b = rng.normal(size=size)
        x = np.empty(size)
        assert coulomb.lu_solve(J.copy(), b.copy(), x)
        ref = -np.linalg.solve(J, b)
        assert np.abs(x - ref).max() <= 1e-12 * np.abs(ref).max()


def test_delassus_matches_unit_impulses_through_apply_and_rel():
    """`stepped.delassus` against the step's own velocity path: column q of A is the
    change of every row's relative velocity (`rel`) after a unit impulse along row q
    (`apply`), on random contact rows between moving, static and shared bodies."""
    from vrsim_cli.kernels import stepped as ks

    rng = np.random.default_rng(61)
    for _ in range(20):
        n_body, m = 4, int(rng.integers(1, 7))
        inv_m = np.where(rng.random(n_body) < 0.25, 0.0, 1.0 / rng.uniform(0.2, 5, n_body))
        K = np.zeros((m, ks.K_SIZE))
        for i in range(m):
            a, b = rng.choice(n_body, 2, replace=False)
            K[i, ks.K_A], K[i, ks.K_B] = a, b
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
            t1 /= np.linalg.norm(t1)
            dirs = (n, t1, np.cross(n, t1))
            ra, rb = rng.normal(size=3), rng.normal(size=3)
            for j, d in enumerate(dirs):
                K[i, ks.K_N + 3 * j:ks.K_N + 3 * j + 3] = d
                for body, arm, cc, wc in ((a, ra, ks.K_RNA, ks.K_WNA),
                                          (b, rb, ks.K_RNB, ks.K_WNB)):
                    cross = np.cross(arm, d)
                    K[i, cc + 6 * j:cc + 6 * j + 3] = cross
                    R = np.random.default_rng([61, int(body)]).normal(size=(3, 3))
                    inv_i = (R @ R.T + np.eye(3)) * (inv_m[body] > 0)  # body's, shared
                    K[i, wc + 6 * j:wc + 6 * j + 3] = inv_i @ cross
            K[i, ks.K_IMA], K[i, ks.K_IMB] = inv_m[a], inv_m[b]
        idx = np.arange(m)
        A = np.empty((3 * m, 3 * m))
        ks.delassus(K, idx, m, A)
        ref = np.empty_like(A)
        for q in range(3 * m):
            U, W = np.zeros((n_body, 3)), np.zeros((n_body, 3))
            ks.apply.py_func(K, q // 3, q % 3, 1.0, U, W)
            for p in range(3 * m):
                ref[p, q] = ks.rel.py_func(K, p // 3, p % 3, U, W)
        assert np.abs(A - ref).max() <= 1e-12 * max(np.abs(ref).max(), 1.0)
