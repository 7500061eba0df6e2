"""The mutable part of a run: positions, velocities, orientations at one instant.

Layer 2, beside the model (MuJoCo's mjData beside mjModel). Structure-of-arrays numpy over bodies, named `body_<property>` with shape and
unit. Step functions take a State and return a new one (`replace`), so a stage can never
half-update the state another stage reads.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import norm

from vrsim_cli.maths.spatial import look_rotation, quat_rotate
from vrsim_cli.model.model import Model
from vrsim_cli.model.observer import input_at


@dataclass(frozen=True)
class State:
    """Dynamic variables at time `t = step * model.dt`.

    body_pos: (n_body, 3) m, centre of mass in world coordinates
    body_vel: (n_body, 3) m/s
    body_quat: (n_body, 4) orientation [w, x, y, z]
    body_angvel: (n_body, 3) rad/s, world frame
    observer_pos: (3,) m, eye position V           (None when the scene has no observer)
    observer_dir: (3,) view direction d, unnormalised as on slide 5.1
    observer_quat: (4,) camera orientation (looks along local -z, local +y up)
    observer_vel: (3,) m/s, velocity over the last frame
    observer_angvel: (3,) rad/s, world frame, over the last frame
    observer_fall: m/s along up while falling (walk), else 0
    rot_matrix: (n_rot, 3, 3) R of the rotating bodies (model.rigid.rot_index); it is the
        orientation the dynamics integrates (body_quat is its quaternion, for output)
    rot_angmom: (n_rot, 3) kg m^2/s, angular momentum L in the world frame
    ode_step: s, the adaptive integrator's proposed step for the next interval (0: none)
    contacts: collision.Contacts found by loop stage 2.3 at this step (None: the scene
        has no collision block); an intermediate result like MuJoCo's mjData.contact,
        not part of the state hash
    contact_impulse: (len(contacts), 3) N s, world: the impulse collision response gave
        body_b at each contact during this step (body_a got minus it); None without
        response. Also an intermediate result (it warm-starts the next step's solver)
    contact_rest: (len(contacts), 3) N s, world: the resting part of contact_impulse (the
        compiled step's, without its impacts); with second-order integrators the next
        step warm-starts from it. None elsewhere.
    """

    step: int
    t: float
    body_pos: np.ndarray
    body_vel: np.ndarray
    body_quat: np.ndarray
    body_angvel: np.ndarray
    observer_pos: np.ndarray | None = None
    observer_dir: np.ndarray | None = None
    observer_quat: np.ndarray | None = None
    observer_vel: np.ndarray | None = None
    observer_angvel: np.ndarray | None = None
    observer_fall: float | None = None  # m/s along up while falling (walk), else 0
    rot_matrix: np.ndarray | None = None
    rot_angmom: np.ndarray | None = None
    ode_step: float = 0.0
    rot_energy0: np.ndarray | None = None  # (n_body,) J: the energy guard's baseline, once
    # windowed forces have ended (None: the model's energy at t = 0)
    contacts: object | None = None  # collision.Contacts of this step (stage 2.3)
    contact_impulse: np.ndarray | None = None  # (k, 3) N s on body_b per contact (response)
    contact_rest: np.ndarray | None = None  # (k, 3) N s: its resting part (compiled step)

    def replace(self, **changes) -> "State":
        return dataclasses.replace(self, **changes)

    def __repr__(self) -> str:  # one line: the arrays are the fields (docs/api.md)
        n = len(self.body_pos)
        return (f"<State step {self.step}, t = {self.t:g} s: {n} bod"
                f"{'y' if n == 1 else 'ies'}{', observer' if self.observer_pos is not None else ''}"
                f"{'' if self.contacts is None else f', {len(self.contacts.depth)} contacts'}>")


def make_state(model: Model) -> State:
    """The state at t = 0. Emitted particles wait at the nozzle with zero velocity."""
    waiting = model.body_emit_step > 0
    vel = np.where(waiting[:, None], 0.0, model.body_vel0)
    observer = {}
    if model.observer is not None:
        ob = model.observer
        pos, direction = ob.position0.copy(), ob.direction0.copy()
        quat = look_rotation(direction, ob.up)
        if ob.mode == "attached":  # the body's initial pose (world, or local to a parent
            i = ob.body            # until the scene graph's first update, before any sample)
            pos, quat = model.body_pos0[i].copy(), model.body_quat0[i].copy()
            direction = norm(direction) * quat_rotate(quat, [0.0, 0.0, -1.0])
        pose = input_at(model.inputs, 0, 0.0)[1]
        if pose is not None:  # tracked: the first tracker pose
            pos, quat = pose[:3].copy(), pose[3:].copy()
            direction = quat_rotate(quat, [0.0, 0.0, -1.0])
        observer = dict(observer_pos=pos, observer_dir=direction, observer_quat=quat,
                        observer_vel=np.zeros(3), observer_angvel=np.zeros(3),
                        observer_fall=0.0)
    return State(
        step=0,
        t=0.0,
        body_pos=np.array(model.body_pos0, dtype=float),
        body_vel=np.array(vel, dtype=float),
        body_quat=np.array(model.body_quat0, dtype=float),
        body_angvel=_angvel0(model),
        rot_matrix=None if model.rigid is None else np.array(model.rigid.rot_matrix0),
        rot_angmom=None if model.rigid is None else np.array(model.rigid.rot_angmom0),
        **observer,
    )


def _angvel0(model: Model) -> np.ndarray:
    angvel = np.zeros((model.n_body, 3))
    if model.rigid is not None:
        angvel[model.rigid.rot_index] = model.rigid.rot_angvel0
    return angvel


@dataclass(frozen=True)
class Inputs:
    """Sensor values for one frame.

    alpha: speed along the view direction in [-1, 1]; beta: turn in [-1, 1] (beta < 0 turns
    right); pitch: fly pitch in [-1, 1]; pose: (7,) px py pz qw qx qy qz from a tracker.
    """

    t: float
    frame: int
    alpha: float = 0.0
    beta: float = 0.0
    pitch: float = 0.0
    pose: np.ndarray | None = None

    def record(self) -> dict:
        """The fields of the /vrsim/input message (read back by input.replay)."""
        out = {"t": self.t, "frame": self.frame, "alpha": self.alpha, "beta": self.beta,
               "pitch": self.pitch}
        if self.pose is not None:
            out["pose"] = [float(x) for x in self.pose]
        return out


STATE_ARRAYS = ("body_pos", "body_vel", "body_quat", "body_angvel", "observer_pos",
                "observer_dir", "observer_quat", "observer_vel", "observer_angvel", "observer_fall")


def state_hash(state: State) -> str:
    """sha256 of the state's time and arrays (little-endian float64): equal hashes mean
    bit-identical states."""
    digest = hashlib.sha256()
    digest.update(np.int64(state.step).astype("<i8").tobytes())
    digest.update(np.float64(state.t).astype("<f8").tobytes())
    for name in STATE_ARRAYS:
        if getattr(state, name) is None:
            continue
        digest.update(np.ascontiguousarray(getattr(state, name), dtype="<f8").tobytes())
    return digest.hexdigest()
