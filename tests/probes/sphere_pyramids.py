# Usage: python tests/probes/sphere_pyramids.py REPO_ROOT: pyramids of 5, 14 and 30 spheres
# that statics can hold (tests/test_sphere_pyramids.py's oracle), in the default compiled
# step: how far they move in 3 s and how fast they end (issue 48 (d): "bodies at rest in a
# pile report zero velocity"). Measured 2026-12-07: on c6aac97 5 spheres held to 1e-15 m,
# 14 crept 2e-6..4e-5 m or fell at 1.2 x the least mu, 30 crept 2e-4 m or fell; with
# unsettled_islands (4a5048d) 5 and 14 hold to 2e-10 m at 1.2-3 x, 30 at 2-3 x (1e-13 m)
# but still fall at 1.2 x (statics: 0.613, mu 0.736).
"""Sphere pyramids against statics, in the compiled contact step (issue 48 (d))."""
import sys

import numpy as np

sys.path.insert(0, sys.argv[1] + "/tests")
from test_sphere_pyramids import centres, holds, run_pyramid  # noqa: E402


def least_mu(layers: int) -> float:
    lo, hi = 0.0, 3.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if holds(0.1, 1.0, mid, layers=layers) else (mid, hi)
    return hi


for layers in (2, 3, 4):
    need = least_mu(layers)
    for mu, integrator, dt in ((1.2 * need, "verlet", 1 / 60), (2.0 * need, "rk4", 1 / 120),
                               (3.0 * need, "symplectic-euler", 1 / 60)):
        r, m = 0.1, 1.0
        c = centres(r, layers)
        states, final = run_pyramid(r, m, mu, dt, integrator, layers, 3.0)
        moved = max(float(np.abs(s.body_pos[1:] - c).max()) for s in states)
        speed = float(np.abs(final.body_vel[1:]).max())
        print(f"{len(c):2d} spheres, statics needs mu {need:.3f}, mu {mu:.3f} {integrator} "
              f"dt 1/{round(1 / dt)}: moved {moved:.2e} m, final speed {speed:.2e} m/s",
              flush=True)
