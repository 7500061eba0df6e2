"""The integrators, their orders, and what each does to translation (slide 5.3).

The methods run compiled (`kernels/dynamics.py`); for the translational part, with the
acceleration a(t0) constant over a step as gravity and constant forces are:

- euler (slide 5.3, explicit): x1 = x0 + dt v0, v1 = v0 + dt a(t0).
  Order 1. Under constant a: x_n = x0 + v0 t + a t^2/2 - a dt t/2.
- symplectic-euler (semi-implicit): v1 = v0 + dt a(t0), x1 = x0 + dt v1.
  Order 1, symplectic (bounded energy error). Under constant a: error + a dt t/2.
- rk4 (classical Runge-Kutta): order 4; exact up to round-off for accelerations that are
  polynomials of degree <= 3 in t, so projectiles come out exact.
- verlet (Stormer-Verlet, kick-drift-kick): v_half = v0 + dt/2 a(t0, x0, v0),
  x1 = x0 + dt v_half, v1 = v_half + dt/2 a(x1, v0 + dt a0). Order 2; symplectic and
  time-reversible when forces do not depend on velocities; exact under constant a.
- dopri5 (Dormand-Prince 5(4)): adaptive steps inside [t0, t0 + dt] to a tolerance;
  order 5; exact under constant a.

Time windows of forces are read at the step's start for every stage, so a windowed force
acts on whole steps with every integrator. Rotation: `kernels/dynamics.py`,
docs/dynamics.md.
"""

INTEGRATORS = ("euler", "symplectic-euler", "rk4", "verlet", "dopri5")
ORDER = {"euler": 1, "symplectic-euler": 1, "rk4": 4, "verlet": 2, "dopri5": 5}
ADAPTIVE = ("dopri5",)
