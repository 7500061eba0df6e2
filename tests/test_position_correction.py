"""The position pass (`solver.correct_positions`) moves bodies by about their
penetration, never by metres, whatever the contact set.

A box of a 27-box pile (located impacts, dt 1/30 s), wedged between two lower boxes, got
contact rows with no solution (normals nearly opposite at nearly one place); their
minimum-norm least-squares solve moved it by 50 m and turned another by 1926 rad in one
pass, and the run stopped with the energy 1e4 J up. Bound here: removing a penetration
d needs a contact point to move by d along its normal, and a correction of several
contacts moves a body's points by a few times the deepest; the pass may move them by at
most `10.0` (10) times the deepest penetration per pass (the body's largest
point movement bounded by |dpos| + |dtheta| |arm|). On the tree before, 12 of these 40
wedges moved further.
"""

from __future__ import annotations

import numpy as np
import pytest

from vrsim_cli.stages.collision import solver


def _wedged(rng, tilt):
    """A movable box (body 2) between two fixed bodies (0 below, 1 above) touching it at
    nearly one point with nearly opposite normals (the upper one tilted by `tilt` rad),
    both penetrating by 1-10 mm; plus two ordinary contacts of the box on body 0."""
    m = float(rng.uniform(0.5, 5.0))
    size = rng.uniform(0.1, 0.5, 3)
    inertia = np.diag(m / 12.0 * np.array([size[1] ** 2 + size[2] ** 2,
                                           size[0] ** 2 + size[2] ** 2,
                                           size[0] ** 2 + size[1] ** 2]))
    inv_i = np.stack([np.zeros((3, 3)), np.zeros((3, 3)), np.linalg.inv(inertia)])
    bodies = solver.Bodies(np.array([0.0, 0.0, 1.0 / m]), inv_i, np.zeros((3, 3)),
                           np.zeros((3, 3)), np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0],
                                                       [0.0, 0.0, 0.0]]))
    spot = rng.uniform(-0.5, 0.5, 3) * size
    axis = rng.normal(size=3)
    axis -= axis[1] * np.array([0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    down = -np.cos(tilt) * np.array([0.0, 1.0, 0.0]) + np.sin(tilt) * axis
    points = np.array([spot, spot + 1e-6 * axis, [size[0] / 2, -size[1] / 2, 0.0],
                       [-size[0] / 2, -size[1] / 2, 0.0]])
    normals = np.array([[0.0, 1.0, 0.0], down, [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    depth = rng.uniform(1e-3, 1e-2, 4)
    c = solver.prepare(bodies, np.array([0, 1, 0, 0]), np.array([2, 2, 2, 2]), points,
                       normals, depth, np.zeros(4), np.full(4, 0.5))
    return bodies, c, points, depth


@pytest.mark.parametrize("tilt", [0.0, 1e-9, 1e-7, 1e-5, 1e-3])
@pytest.mark.parametrize("seed", range(8))
def test_a_wedged_body_is_not_thrown_by_the_position_pass(seed, tilt):
    rng = np.random.default_rng(seed)
    bodies, c, points, depth = _wedged(rng, tilt)
    iterations = 4
    dpos, dtheta = solver.correct_positions(bodies, c, 0.0, iterations)
    reach = float(np.linalg.norm(points, axis=1).max())
    move = float(np.linalg.norm(dpos[2]) + np.linalg.norm(dtheta[2]) * reach)
    assert np.isfinite(move)
    assert move <= iterations * solver.MOVE_CAP * depth.max() * (1.0 + 1e-9), \
        (move, depth.max())
