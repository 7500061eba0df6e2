"""Loop stage 1, read sensors: the mouse (desktop VR) or the head tracker (CAVE).

Slide 5.0: one loop iteration starts by reading the sensors. The values were resolved per
frame when the model was compiled (`model_observer.compile_input`), so this stage is a
lookup at one fixed point of the frame, and replaying a recorded run gives the same values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.model import Model


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
        """The JSON message written to /vrsim/input (and read back by input.replay)."""
        out = {"t": self.t, "frame": self.frame, "alpha": self.alpha, "beta": self.beta,
               "pitch": self.pitch}
        if self.pose is not None:
            out["pose"] = [float(x) for x in self.pose]
        return out


def read(model: Model, frame: int, t: float) -> Inputs | None:
    """The sensor values of `frame` (starting at time t), or None without an observer."""
    if model.observer is None:
        return None
    alpha, beta, pitch = (float(x) for x in model.inputs.frame_input[frame])
    pose = model.inputs.frame_pose[frame] if model.inputs.frame_pose is not None else None
    return Inputs(t=t, frame=frame, alpha=alpha, beta=beta, pitch=pitch, pose=pose)
