"""How often the per-body block solve (`solver._patch`, strict, as the shock pass calls it)
answers with an exact Coulomb solution, on random one-body problems: a box (0.1-0.5 m,
0.5-5 kg) falling at g dt onto 1-3 supports that each move with their own small rigid
motion (0-3 cm/s, 0-0.3 rad/s), normals tilted 0-10 mrad per support, gaps of 0, up to
1e-9 m or up to 1e-3 m at each corner (the allowance gap / dt), mu 0.1-1.

    python benchmarks/patch_coulomb.py [draws]      (default 400)

Prints the count of each outcome: ok (every Coulomb condition holds to 1e-9 of the
problem's scale), refused (no answer: the caller keeps the sweeps' impulses), or the
conditions an accepted answer breaks: approach, pull, compl (complementarity), cone,
slide-law (a slipping point without mu lam_n against its slip). A measurement, not a
test: a Coulomb solution exists for these problems, and the solver does not always find
it (docs/collision-response.md, Known limits).
"""

from __future__ import annotations

import sys
from collections import Counter

import numpy as np

from vrsim_cli.stages.collision import solver

DT = 1.0 / 60.0
TOL = 1e-9


def problem(rng):
    m, size = rng.uniform(0.5, 5.0), rng.uniform(0.1, 0.5, 3)
    inertia = m / 12.0 * (size @ size - size ** 2)
    W = np.zeros((6, 6))
    W[:3, :3], W[3:, 3:] = np.eye(3) / m, np.diag(1.0 / inertia)
    n_low = int(rng.integers(1, 4))
    cuts = np.sort(rng.uniform(-0.5, 0.5, n_low - 1)) * size[0]
    edges = np.concatenate([[-size[0] / 2], cuts, [size[0] / 2]])
    v_u = np.array([0.0, -9.81 * DT, 0.0]) + rng.normal(size=3) * rng.choice([0, 1e-3, 3e-2])
    w_u = rng.normal(size=3) * rng.choice([0, 1e-2, 0.3])
    rows, pre, target = [], [], []
    for j in range(n_low):
        tilt = rng.normal(size=2) * rng.choice([0, 1e-3, 1e-2])
        n = np.array([tilt[0], 1.0, tilt[1]])
        n /= np.linalg.norm(n)
        t1 = np.cross(n, [0.0, 0.0, 1.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        v_l = rng.normal(size=3) * rng.choice([0, 1e-3, 3e-2])
        w_l = rng.normal(size=3) * rng.choice([0, 1e-2, 0.3])
        centre = np.array([(edges[j] + edges[j + 1]) / 2, -size[1] / 2 - 0.1, 0.0])
        for x in (edges[j], edges[j + 1]):
            for z in (-size[2] / 2, size[2] / 2):
                p = np.array([x, -size[1] / 2, z])
                gap = rng.choice([0.0, rng.uniform(0, 1e-9), rng.uniform(0, 1e-3)])
                rel = (v_u + np.cross(w_u, p)) - (v_l + np.cross(w_l, p - centre))
                for d in (n, t1, t2):
                    rows.append(np.concatenate([d, np.cross(p, d)]))
                pre.append([rel @ n, rel @ t1, rel @ t2])
                target.append(gap / DT)
    J = np.array(rows)
    return J @ W @ J.T, np.array(pre), np.array(target), np.full(len(pre), rng.uniform(0.1, 1.0))


def broken(A, pre, target, mu, lam) -> str:
    v = pre + (A @ lam.ravel()).reshape(-1, 3)
    size, ls = 1.0 + np.abs(pre).max(), 1.0 + np.abs(lam).max()
    ln, lt = lam[:, 0], np.linalg.norm(lam[:, 1:], axis=1)
    vn, slip = v[:, 0] + target, np.linalg.norm(v[:, 1:], axis=1)
    out = []
    if -vn.min() > TOL:
        out.append("approach")
    if -ln.min() / ls * size > TOL:
        out.append("pull")
    if np.max(np.minimum(np.maximum(ln, 0) / ls * size, np.abs(vn))) > TOL:
        out.append("compl")
    if np.max(np.maximum(lt - mu * ln, 0)) / ls * size > TOL:
        out.append("cone")
    slipping = np.flatnonzero((slip > TOL * size) & (ln > 0))
    if any(np.abs(lam[i, 1:] + mu[i] * ln[i] * v[i, 1:] / slip[i]).max() / ls * size > TOL
           for i in slipping):
        out.append("slide-law")
    return "+".join(out) or "ok"


def main(draws: int) -> None:
    outcomes = Counter()
    for seed in range(draws):
        A, pre, target, mu = problem(np.random.default_rng(seed))
        lam, _ = solver._patch(A, pre, target, mu, None, strict=True)
        outcomes["refused" if lam is None else broken(A, pre, target, mu, lam)] += 1
    print(f"{draws} draws:", dict(sorted(outcomes.items(), key=lambda kv: -kv[1])))


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("draws", type=int, nargs="?", default=400)
    main(parser.parse_args().draws)
