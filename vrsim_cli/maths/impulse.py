"""The impulse law of slide 5.4.2, as pure functions vectorised over k contacts.

Layer 0 (numpy only). A contact K between bodies A and B has the point P^K, the normal n
(unit, from A to B) and the lever arms p_A = P^K - S_A, p_B = P^K - S_B from the centres of
mass. The impulse P^K = alpha n acts on B, -P^K on A (momentum is conserved):

    v_B <- v_B + P/m_B,   L_B <- L_B + p_B x P,   omega_B <- omega_B + I_B^-1 (p_B x P)
    v_A <- v_A - P/m_A,   L_A <- L_A - p_A x P,   omega_A <- omega_A - I_A^-1 (p_A x P)

With v_rel = (v_B + omega_B x p_B) - (v_A + omega_A x p_A) at the contact point, the
restitution law n . v_rel_new = -eps (n . v_rel) gives

    alpha = -(1 + eps)(v_rel . n) / K,
    K = 1/m_A + 1/m_B + n.((I_A^-1 (p_A x n)) x p_A) + n.((I_B^-1 (p_B x n)) x p_B).

Derivation: the change of v_rel . n per unit alpha is exactly K (the rotational term of B
is n . ((I_B^-1 (p_B x n)) x p_B) since omega_B changes by alpha I_B^-1 (p_B x n) and the
point velocity by that cross p_B). Static and kinematic bodies, and point masses for
rotation, enter with inverse mass 0 and inverse inertia 0: infinite mass. A kinematic
body still moves: its velocity enters v_rel, so it pushes. The same K along any unit
direction t gives the effective mass 1/K_t of a friction impulse.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.rotation import cross


def point_velocity(vel, angvel, arm):
    """(k, 3) m/s velocity of body points: v + omega x p."""
    return vel + cross(angvel, arm)


def inverse_mass_along(inv_mass_a, inv_mass_b, inv_inertia_a, inv_inertia_b, arm_a, arm_b,
                       direction):
    """K (k,) 1/kg: the change of the relative point velocity along `direction` (k, 3,
    unit) per unit impulse along it (the slide's denominator).

    inv_mass_*: (k,) 1/kg; inv_inertia_*: (k, 3, 3) world frame, 1/(kg m^2); arm_*: (k, 3)
    m from each centre of mass to the contact point."""
    k = inv_mass_a + inv_mass_b
    for inv_inertia, arm in ((inv_inertia_a, arm_a), (inv_inertia_b, arm_b)):
        turn = np.einsum("kij,kj->ki", inv_inertia, cross(arm, direction))
        k = k + (direction * cross(turn, arm)).sum(axis=1)
    return k


def restitution_alpha(v_rel_n, restitution, k):
    """alpha (k,) N s: the slide's impulse magnitude that makes n . v_rel_new = -eps n .
    v_rel. Zero where K is 0 (two bodies of infinite mass: nothing can change)."""
    safe = np.where(k > 0.0, k, 1.0)
    return np.where(k > 0.0, -(1.0 + restitution) * v_rel_n / safe, 0.0)


def body_deltas(n_body: int, body_a, body_b, arm_a, arm_b, impulse):
    """Sum the impulses (k, 3) N s on B (+) and A (-) per body: (dP, dL), each (n_body, 3):
    the change of linear momentum and of angular momentum p x P about each centre of mass."""
    dp = np.zeros((n_body, 3))
    dl = np.zeros((n_body, 3))
    np.add.at(dp, body_b, impulse)
    np.add.at(dp, body_a, -impulse)
    np.add.at(dl, body_b, cross(arm_b, impulse))
    np.add.at(dl, body_a, -cross(arm_a, impulse))
    return dp, dl
