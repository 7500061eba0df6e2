"""Loop stage 1, read sensors: the mouse (desktop VR) or the head tracker (CAVE).

Slide 5.0: one loop iteration starts by reading the sensors. The sensor files were read
when the model was compiled (`model.observer.compile_input`); this stage evaluates their
samples at the frame's start time, at one fixed point of the frame, so replaying a
recorded run gives the same values.
"""

from __future__ import annotations

from vrsim_cli.model.model import Model
from vrsim_cli.model.observer import input_at
from vrsim_cli.model.state import Inputs


def read(model: Model, frame: int, t: float) -> Inputs | None:
    """The sensor values of `frame` (starting at time t), or None without an observer."""
    if model.observer is None:
        return None
    values, pose = input_at(model.inputs, frame, t)
    alpha, beta, pitch = (float(x) for x in values)
    return Inputs(t=t, frame=frame, alpha=alpha, beta=beta, pitch=pitch, pose=pose)
