# Usage: python tests/probes/energy_scenes.py REPO_ROOT: per-step energy gain and final speed of
# domino rows and box piles in impacts: stepped (issue 48 (d)); compare two checkouts.
"""Per-step energy gain of domino rows and box piles in stepped mode (issue 48 (d))."""
import sys, math, numpy as np
sys.path.insert(0, sys.argv[1] + '/tests')
import vrsim_cli
from conftest import simulate
G = 9.81

def qm(q):
    w, x, y, z = q
    return np.array([[1-2*(y*y+z*z), 2*(x*y-w*z), 2*(x*z+w*y)],[2*(x*y+w*z), 1-2*(x*x+z*z), 2*(y*z-w*x)],[2*(x*z-w*y), 2*(y*z+w*x), 1-2*(x*x+y*y)]])

def energy(states, masses, inertias):
    E = []
    for s in states:
        e = 0.0
        for b, (m, I) in enumerate(zip(masses, inertias), start=1):
            wb = qm(s.body_quat[b]).T @ s.body_angvel[b]
            e += 0.5*m*float(s.body_vel[b] @ s.body_vel[b]) + 0.5*float((I*wb) @ wb) + m*G*float(s.body_pos[b, 1])
        E.append(e)
    E = np.array(E)
    return float(np.diff(E).max() / np.abs(E).max()), float((E.max() - E[0]) / np.abs(E).max())

def dominoes(seed, integ, dt):
    rng = np.random.default_rng([48, 9, seed])
    n = 8
    a, b, c = 0.01, 0.1, 0.05
    m = 0.05
    bodies = ["  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}, material: {friction: 0.5, restitution: 0}}"]
    gap = float(rng.uniform(0.04, 0.07))
    for i in range(n):
        w = f", angular_velocity: [0, 0, {-float(rng.uniform(2, 5))!r}]" if i == 0 else ""
        bodies.append(f"  - {{name: d{i}, mass: {m}, position: [{i*gap!r}, {b/2!r}, 0], shape: {{type: box, size: [{a}, {b}, {c}]}}, material: {{friction: 0.5, restitution: 0}}{w}}}")
    src = f"vrsim: 1\nduration: 2.0\nframe_rate: {1/dt!r}\ndt: {dt!r}\nintegrator: {integ}\ngravity: [0, -9.81, 0]\ncollision: {{impacts: stepped}}\nbodies:\n" + "\n".join(bodies) + "\n"
    _, states, _ = simulate(src)
    I = m/12*np.array([b*b+c*c, a*a+c*c, a*a+b*b])
    return energy(states, [m]*n, [I]*n)

def pile(seed, integ, dt):
    rng = np.random.default_rng([48, 10, seed])
    bodies = ["  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}, material: {friction: 0.6, restitution: 0}}"]
    ms, Is = [], []
    for i in range(20):
        s = rng.uniform(0.05, 0.15, 3); m = float(rng.uniform(0.2, 2))
        q = rng.normal(size=4); q /= np.linalg.norm(q)
        p = [float(rng.uniform(-0.2, 0.2)), 0.1 + 0.18*i, float(rng.uniform(-0.2, 0.2))]
        bodies.append(f"  - {{name: b{i}, mass: {m!r}, position: {p}, orientation: {[float(x) for x in q]}, shape: {{type: box, size: {[float(x) for x in s]}}}, material: {{friction: 0.6, restitution: 0}}}}")
        ms.append(m); Is.append(m/12*np.array([s[1]**2+s[2]**2, s[0]**2+s[2]**2, s[0]**2+s[1]**2]))
    src = f"vrsim: 1\nduration: 4.0\nframe_rate: {1/dt!r}\ndt: {dt!r}\nintegrator: {integ}\ngravity: [0, -9.81, 0]\ncollision: {{impacts: stepped}}\nbodies:\n" + "\n".join(bodies) + "\n"
    _, states, final = simulate(src)
    g = energy(states, ms, Is)
    return g + (float(np.abs(final.body_vel[1:]).max()),)

for seed in range(4):
    integ = ("verlet", "rk4")[seed % 2]
    dt = (1/120, 1/240)[seed // 2 % 2]
    print("dominoes", seed, integ, round(1/dt), "max step gain %.2e, above start %.2e" % dominoes(seed, integ, dt), flush=True)
for seed in range(2):
    integ = ("verlet", "rk4")[seed % 2]
    print("pile", seed, integ, "max step gain %.2e, above start %.2e, final speed %.2e" % pile(seed, integ, 1/120), flush=True)
