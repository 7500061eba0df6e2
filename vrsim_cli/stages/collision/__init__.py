"""Collision detection (slide 5.4.1), loop stage 2.3: the contacts, not the response.

Public API (pure functions of model and state, consumed by collision response):
- `detect(model, state) -> Contacts`: contacts of one state;
- `step(model, before, after) -> Contacts`: what the loop calls after each physics step
  (discrete contacts at `after` plus continuous time-of-impact contacts);
- `time_of_impact(cm, body_pos, body_quat, body_vel, body_angvel, ia, ib, dt)`: TOI of
  geom pairs within `collision.tolerance`;
- `queries.ray_cast`, `queries.sphere_cast`: for navigation, meshes included.
Modules: shapes (geoms and proxies), broadphase, narrowphase (closed-form pair functions
and the dispatch table), cylinder_pairs (manifolds of box and cylinder pairs around fcl's
point), fcl_adapter (hulls, meshes, cylinders), continuous, meshes
(trimesh loading, proxy errors), queries, contacts. trimesh and python-fcl are imported
only by scenes that need them.
"""

from vrsim_cli.stages.collision.contacts import Contacts
from vrsim_cli.stages.collision.continuous import time_of_impact
from vrsim_cli.stages.collision.detect import detect, step

__all__ = ["Contacts", "detect", "step", "time_of_impact"]
