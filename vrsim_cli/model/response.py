"""Compile the collision response of a scene (slide 5.4.2) into frozen arrays.

Layer 2 helper of `model.compile_model`, called only for scenes with a `collision` block.
Per body: the response mode (`collision.response`) and the material (restitution eps,
friction mu; NaN when the body does not set it). Per pair (`collision.pairs`): overrides.

How two bodies combine (`combine`), as Box2D does and for the same reasons:
- restitution: the larger of the two. A bouncy ball on a default (eps = 0) floor bounces
  with its own eps, so setting one body's eps gives exactly that eps at the impact.
- friction: the geometric mean sqrt(mu_A mu_B): ice (mu = 0) on anything is frictionless,
  equal materials keep their value, and the result lies between the two.
A value only one body sets is used as it is; neither: the defaults below. A pair entry
replaces the combination for that pair.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import norm

NONE, STOP, SLIDE, IMPULSE = range(4)
MODES = ("none", "stop", "slide", "impulse")
# When bodies disagree the more restrictive mode wins: none (a ghost), stop, slide, impulse.
PRECEDENCE = (NONE, STOP, SLIDE, IMPULSE)
DEFAULT_RESTITUTION = 0.0
DEFAULT_FRICTION = 0.5
DEFAULT_ITERATIONS = 4
DEFAULT_POSITION_ITERATIONS = 2
DEFAULT_SLOP = 0.0  # m: penetration left by position correction
# The compiled step (stepped) sweeps its resting contacts by Gauss-Seidel from a warm
# start, then solves small islands to convergence (kernels.stepped): 8 sweeps by default.
STEPPED_ITERATIONS = 8
STEPPED_POSITION_ITERATIONS = 16  # a 4-layer pile then rests within 2.5 % of r
# `impacts: auto` is the compiled contact step (`stepped`) for every scene: impulses
# before positions, one numba call per step. Located impacts (each impact found in time,
# the interpreted solver) run only where the scene sets `impacts: located`, until issue
# 49 brings them into the compiled step. A located scene with a dynamic body thinner than
# THIN_FALLS times the fall of a resting body in one free-flight step (share |g| dt^2)
# plus the tolerance is told so (`model.compile_model`'s notes): located mode detects
# resting contacts at the end of the free flight, and a 2 mm plate under another at dt
# 1/60 s (2.7 mm of fall) is passed through; stepped mode's speculative contacts hold it.
THIN_FALLS = 2.0


@dataclass(frozen=True)
class ResponseModel:
    """body_mode: (n_body,) int64 NONE | STOP | SLIDE | IMPULSE
    body_restitution, body_friction: (n_body,) NaN where the body sets no material
    pair_key: (p,) int64 a * n_body + b (a < b) of the pair overrides, sorted;
    pair_mode: (p,) int64, -1 when not overridden; pair_restitution, pair_friction: (p,)
    NaN when not overridden
    rest_speed: m/s, impacts slower than this are plastic (eps = 0)
    iterations, position_iterations: of the resting-contact solver; slop: m
    impacts: "located" (each impact found in time, exact) or "stepped" (all contacts of
    the step solved together by `kernels.stepped`: speculative contacts)
    """

    body_mode: np.ndarray
    body_restitution: np.ndarray
    body_friction: np.ndarray
    pair_key: np.ndarray
    pair_mode: np.ndarray
    pair_restitution: np.ndarray
    pair_friction: np.ndarray
    rest_speed: float
    iterations: int
    position_iterations: int
    slop: float
    impacts: str = "located"
    impacts_why: str = "set in the scene"  # said by `vrsim validate`

    def pair_values(self, a, b):
        """(mode (k,) int64, restitution (k,), friction (k,)) of body pairs a < b."""
        mode = np.minimum(self.body_mode[a], self.body_mode[b])  # PRECEDENCE order
        ea, eb = self.body_restitution[a], self.body_restitution[b]
        fa, fb = self.body_friction[a], self.body_friction[b]
        eps = np.fmax(ea, eb)  # NaN only where both are unset
        eps = np.where(np.isnan(eps), DEFAULT_RESTITUTION, eps)
        mu = np.where(np.isnan(fa), fb, np.where(np.isnan(fb), fa, np.sqrt(fa * fb)))
        mu = np.where(np.isnan(mu), DEFAULT_FRICTION, mu)
        if len(self.pair_key) and len(a):
            key = a * len(self.body_mode) + b
            row = np.clip(np.searchsorted(self.pair_key, key), 0, len(self.pair_key) - 1)
            hit = self.pair_key[row] == key
            pm, pe, pf = self.pair_mode[row], self.pair_restitution[row], \
                self.pair_friction[row]
            mode = np.where(hit & (pm >= 0), pm, mode)
            eps = np.where(hit & ~np.isnan(pe), pe, eps)
            mu = np.where(hit & ~np.isnan(pf), pf, mu)
        return mode, eps, mu


def thin_reason(thin: tuple) -> str:
    """Why a body counts as thin (`compile_response`'s `thin`), for `validate`."""
    name, extent, fall = thin
    return (f"body '{name}' is {extent * 1e3:.3g} mm thin, less than twice the "
            f"{fall * 1e3:.3g} mm a resting body falls in one step plus the tolerance")


def compile_response(scene, n_body: int, gravity, tolerance: float,
                     problems: list) -> ResponseModel | None:
    """The scene's response, or None when no pair can respond (all `none`)."""
    data = scene.data
    top = data.get("collision") or {}
    default_mode = MODES.index(top.get("response", "impulse"))
    mode = np.full(n_body, default_mode, np.int64)
    eps = np.full(n_body, math.nan)
    mu = np.full(n_body, math.nan)
    bodies = data.get("bodies") or []
    index = {b["name"]: i for i, b in enumerate(bodies)}
    for i, body in enumerate(bodies):
        spec = body.get("collision") or {}
        if "response" in spec:
            mode[i] = MODES.index(spec["response"])
        material = body.get("material") or {}
        eps[i] = float(material.get("restitution", math.nan))
        mu[i] = float(material.get("friction", math.nan))
    rows = {}
    for k, pair in enumerate(top.get("pairs") or []):
        at = ("collision", "pairs", k, "bodies")
        names = pair["bodies"]
        missing = [x for x in names if x not in index]
        if missing:
            problems.append(scene.problem(at, f"no body named '{missing[0]}'",
                                          "pairs name two bodies of `bodies`"))
            continue
        a, b = sorted(index[x] for x in names)
        if a == b:
            problems.append(scene.problem(at, "a pair needs two different bodies"))
            continue
        rows[a * n_body + b] = (MODES.index(pair["response"]) if "response" in pair else -1,
                                float(pair.get("restitution", math.nan)),
                                float(pair.get("friction", math.nan)))
    keys = sorted(rows)
    if (mode == NONE).all() and all(rows[k][0] in (-1, NONE) for k in keys):
        return None
    g = float(norm(gravity))
    # An impact slower than sqrt(2 |g| tol) would rebound less than the contact tolerance
    # high: such a hop cannot be told apart from resting contact, so it is made plastic.
    rest_speed = float(top.get("rest_speed", math.sqrt(2.0 * g * tolerance)))
    impacts = top.get("impacts", "auto")
    why = "set in the scene"
    if impacts == "auto":
        impacts = "stepped"
        why = "auto: the compiled contact step, for every scene"
    stepped = impacts == "stepped"
    return ResponseModel(
        body_mode=mode, body_restitution=eps, body_friction=mu,
        pair_key=np.array(keys, np.int64),
        pair_mode=np.array([rows[k][0] for k in keys], np.int64),
        pair_restitution=np.array([rows[k][1] for k in keys], float),
        pair_friction=np.array([rows[k][2] for k in keys], float),
        rest_speed=rest_speed,
        iterations=int(top.get("iterations", STEPPED_ITERATIONS if stepped
                                else DEFAULT_ITERATIONS)),
        position_iterations=int(top.get("position_iterations", STEPPED_POSITION_ITERATIONS
                                        if stepped else DEFAULT_POSITION_ITERATIONS)),
        slop=float(top.get("slop", DEFAULT_SLOP)),
        impacts=impacts,
        impacts_why=why,
    )
