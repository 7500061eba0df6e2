"""Time integrators for translational motion: (x, v) at t -> (x, v) at t + dt.

Each takes `accel(t, x, v) -> a` (arrays of the same shape as x) and is exact in its own
way for the constant-acceleration case, which is what the tests compare against:

- euler (slide 5.3, explicit): x1 = x0 + dt v0, v1 = v0 + dt a(t0).
  Order 1. Under constant a: x_n = x0 + v0 t + a t^2/2 - a dt t/2.
- symplectic-euler (semi-implicit): v1 = v0 + dt a(t0), x1 = x0 + dt v1.
  Order 1, symplectic (bounded energy error). Under constant a: error + a dt t/2.
- rk4 (classical Runge-Kutta): order 4; exact up to round-off for accelerations that are
  polynomials of degree <= 3 in t, so projectiles come out exact.
- verlet (Stormer-Verlet, kick-drift-kick): v_half = v0 + dt/2 a(t0, x0),
  x1 = x0 + dt v_half, v1 = v_half + dt/2 a(t0, x1). Order 2, symplectic, time-reversible;
  exact under constant a. The second kick reads time windows at the step's start t0, so a
  time-windowed force acts on whole steps as with the other integrators.
- dopri5 (Dormand-Prince 5(4), `adaptive.py`): adaptive steps inside [t0, t0 + dt] to a
  tolerance; order 5; exact under constant a. Scenes with this integrator run through
  `rigid.step` (which carries the proposed step from one interval to the next); this
  function is the same method for the translational state alone.

Rotation and the rigid-body forms of these methods: `rigid.py`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Accel = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


def euler(accel: Accel, t: float, dt: float, x: np.ndarray, v: np.ndarray):
    return x + dt * v, v + dt * accel(t, x, v)


def symplectic_euler(accel: Accel, t: float, dt: float, x: np.ndarray, v: np.ndarray):
    v1 = v + dt * accel(t, x, v)
    return x + dt * v1, v1


def rk4(accel: Accel, t: float, dt: float, x: np.ndarray, v: np.ndarray):
    h = 0.5 * dt
    k1x, k1v = v, accel(t, x, v)
    k2x, k2v = v + h * k1v, accel(t + h, x + h * k1x, v + h * k1v)
    k3x, k3v = v + h * k2v, accel(t + h, x + h * k2x, v + h * k2v)
    k4x, k4v = v + dt * k3v, accel(t + dt, x + dt * k3x, v + dt * k3v)
    sixth = dt / 6.0
    return (x + sixth * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            v + sixth * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


def verlet(accel: Accel, t: float, dt: float, x: np.ndarray, v: np.ndarray):
    v_half = v + (0.5 * dt) * accel(t, x, v)
    x1 = x + dt * v_half
    return x1, v_half + (0.5 * dt) * accel(t, x1, v_half)


def dopri5(accel: Accel, t: float, dt: float, x: np.ndarray, v: np.ndarray,
           tolerance: float = 1e-6):
    from vrsim_cli.maths import adaptive

    n = x.size

    def f(tt, y):
        xx, vv = y[:n].reshape(x.shape), y[n:].reshape(v.shape)
        return np.concatenate([vv.ravel(), accel(tt, xx, vv).ravel()])

    y, _, _, _ = adaptive.integrate(f, t, t + dt, np.concatenate([x.ravel(), v.ravel()]),
                                    dt, tolerance)
    return y[:n].reshape(x.shape), y[n:].reshape(v.shape)


INTEGRATORS = {"euler": euler, "symplectic-euler": symplectic_euler, "rk4": rk4,
               "verlet": verlet, "dopri5": dopri5}
ORDER = {"euler": 1, "symplectic-euler": 1, "rk4": 4, "verlet": 2, "dopri5": 5}
ADAPTIVE = ("dopri5",)
