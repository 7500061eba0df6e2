"""Keyframe tracks (slide 5.2): key times t_i and key values P_i -> a curve C(t) with
C(t_i) = P_i, and its derivative.

Layer 2 (it compiles the scene's track specs, checked by `scene.animation`, into curves):
pure, vectorised curve maths; no bodies, no model. Used by the scene graph stage and by anyone who needs a keyframed path (the observer).

    track = compile_track({"times": [0, 1, 3], "values": [[0, 0, 0], [1, 0, 0], [1, 2, 0]],
                           "interpolation": "catmull-rom", "extrapolation": "loop"})
    value, rate = evaluate(track, t)      # t: float or (n,) array of s

`value` has shape (d,) (or (n, d)); scalar tracks give () (or (n,)). `rate` is dC/dt in
value units per second; for orientation tracks `value` is a unit quaternion [w, x, y, z]
and `rate` the angular velocity (rad/s) in the frame the keys are given in, for colour
tracks `value` is RGBA and `rate` d(RGBA)/dt.

Interpolation (all hit every key exactly, as the slide demands):
- step: C(t) = P_i on [t_i, t_{i+1}).
- linear: the slide's C(t) = (1 - s) P_i + s P_{i+1}, s = (t - t_i) / (t_{i+1} - t_i).
  Constant velocity per segment; the velocity jumps at keys.
- catmull-rom: cubic Hermite with tangent (P_{i+1} - P_{i-1}) / (t_{i+1} - t_{i-1}) (per second),
  i.e. Kochanek-Bartels with tension = continuity = bias = 0. C1 in time, also for
  unevenly spaced keys.
- kochanek-bartels: tangents (Kochanek & Bartels 1984, eq. 8-9) with the paper's timing
  adjustment, written per unit time (T, C, B: one number per track or one per key); with
  a = P_i - P_{i-1}, b = P_{i+1} - P_i,
    out_i = (1-T) [(1+B)(1+C) a + (1-B)(1-C) b] / (t_{i+1} - t_{i-1})
    in_i  = (1-T) [(1+B)(1-C) a + (1-B)(1+C) b] / (t_{i+1} - t_{i-1}).
  Missing neighbours at the ends are mirrored (P_{-1} = 2 P_0 - P_1), so the end tangent
  is the first chord's slope. With `loop` extrapolation and P_0 == P_last the curve is
  closed: the ends use the wrapped neighbours and the seam is C1 too.
- hermite: glTF 2.0 CUBICSPLINE. Per key an in-tangent a_k, value v_k, out-tangent b_k
  (value per second); on [t_k, t_{k+1}] with td = t_{k+1} - t_k:
    p(s) = (2s^3 - 3s^2 + 1) v_k + td (s^3 - 2s^2 + s) b_k + (-2s^3 + 3s^2) v_{k+1}
           + td (s^3 - s^2) a_{k+1}.
- orientations: step; slerp (shortest arc: consecutive keys are put in one hemisphere);
  `linear` means slerp (as in glTF); squad (Shoemake 1987) with
  a_i = q_i exp(-(log(q_i^-1 q_{i+1}) + log(q_i^-1 q_{i-1})) / 4), a_0 = q_0, a_last = q_last.
  slerp's angular velocity is exact and constant per segment; squad's is a central
  difference in the segment parameter (step 1e-5: relative error about 1e-10).

Colours interpolate as RGBA, or with `space: hsv` as (h, s, v, a) like X3D's
ColorInterpolator; the hue takes the shorter way round the colour wheel (ties go towards
decreasing hue) and grey keys (s = 0, no hue) borrow the next coloured key's hue (the
last one's after it). Results are clipped to [0, 1].

Extrapolation outside [t_0, t_last] (`extrapolation: X` or `{before: X, after: Y}`):
clamp (hold the end value, rate 0), loop (repeat with period t_last - t_0; t_0 + kT for
k >= 1 gives the last key), ping-pong (forwards, then backwards, period 2T).

Ease (`ease: in | out | in-out`) warps each segment's parameter s by s^2, s(2 - s) or
3s^2 - 2s^3: keys are still hit at their times, and the velocity is zero at the eased end
of every segment (Blender's per-key ease). `arc_length: true` (paths with two or more
numbers per key) moves along the same curve at constant speed S / (t_last - t_0) between
the first and the last key, S being the curve's length; the curve still passes through
every key, but interior keys are reached when their share of the length is covered, not
at their key times. Ease then warps the covered share of the length (a smooth start and
stop on a constant-speed path). Arc length is integrated with 5-point Gauss-Legendre on
32 pieces per segment and inverted with Newton's method (position error below 1e-11 m
in the tests).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import matmul, dot
from vrsim_cli.maths import trig
from vrsim_cli.maths.trig import sin_cos, sin_over_x

from vrsim_cli.maths.spatial import (quat_from_euler_deg, quat_left_matrix, quat_multiply,
                               quat_to_matrix, unit)
from vrsim_cli.scene.animation import COLOR, DEFAULT_MODE, KB_KEYS, ROTATION, VECTOR, track_issues

ARC_PIECES = 32  # sub-intervals per segment for the arc-length table
NEWTON_STEPS = 3  # guess off by <= 2e-4 m in tests; Newton: 4e-7, 3e-12, then round-off
SQUAD_H = 1e-5  # central-difference step in the segment parameter for squad's rate
# 5-point Gauss-Legendre nodes and weights on [0, 1]: exact for polynomials of degree 9.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


class TrackError(ValueError):
    """A track spec is invalid. `issues`: [(key path relative to the track, message, hint)]."""

    def __init__(self, issues):
        self.issues = list(issues)
        super().__init__("; ".join(f"{'.'.join(map(str, p)) or 'track'}: {m}"
                                   for p, m, _ in self.issues))


@dataclass(frozen=True, eq=False)
class Track:
    """A compiled track. n keys, n - 1 segments, values of width d.

    times: (n,) s; values: (n, d) keys (aligned quaternions; colours as RGBA or HSVA with
    unwrapped hue); coeffs: (n - 1, 4, d) cubic a + b s + c s^2 + d s^3 per segment (cubic
    modes); omega: (n - 1, 3) rad per unit s (slerp); ctrl: (n, 4) squad control points;
    half: (n - 1, 3) log(q_i^-1 q_{i+1}), left: (n - 1, 4, 4) L(q_i) (rotations).
    """

    kind: str
    mode: str
    times: np.ndarray
    values: np.ndarray
    before: str = "clamp"
    after: str = "clamp"
    ease: str = "none"
    scalar: bool = False
    hsv: bool = False
    coeffs: np.ndarray | None = None
    omega: np.ndarray | None = None
    ctrl: np.ndarray | None = None
    half: np.ndarray | None = None
    left: np.ndarray | None = None
    arc: tuple | None = None  # knot_seg, knot_s, knot_len (m + 1,); speed0, speed1 (m,)

    @property
    def start(self) -> float:
        return float(self.times[0])

    @property
    def end(self) -> float:
        return float(self.times[-1])


# ----------------------------------------------------------------------------- compile


def compile_track(spec: dict, kind: str = VECTOR) -> Track:
    """Track spec (the scene format's mapping) -> Track. Raises TrackError on bad specs.

    kind: 'vector' (numbers or lists of numbers), 'rotation' (`values` quaternions
    [w, x, y, z] or `euler_deg` [x, y, z] degrees, see spatial.quat_from_euler_deg) or
    'color' ([r, g, b] or [r, g, b, a] in [0, 1]).
    """
    issues = list(track_issues(spec, kind))
    if issues:
        raise TrackError(issues)
    mode = spec.get("interpolation", DEFAULT_MODE[kind])
    times = np.array(spec["times"], dtype=float)
    extrap = spec.get("extrapolation", "clamp")
    before, after = (extrap, extrap) if isinstance(extrap, str) else \
        (extrap.get("before", "clamp"), extrap.get("after", "clamp"))
    common = dict(kind=kind, times=times, before=before, after=after,
                  ease=spec.get("ease", "none"))
    if kind == ROTATION:
        if "euler_deg" in spec:
            quats = np.array([quat_from_euler_deg(e) for e in spec["euler_deg"]])
        else:
            # scaled first: [1e-200, 0, 0, 0] is a rotation too (its plain norm is 0)
            quats = unit(np.array(spec["values"], dtype=float))
        return _compile_rotation(quats, "slerp" if mode == "linear" else mode, common)
    raw = spec["values"]
    scalar = not isinstance(raw[0], list)
    values = np.array(raw, dtype=float).reshape(len(times), -1)
    hsv = kind == COLOR and spec.get("space", "rgb") == "hsv"
    if kind == COLOR:
        values = np.hstack([values, np.ones((len(times), 4 - values.shape[1]))])
        if hsv:
            values = _unwrap_hue(rgb_to_hsv(values))
    closed = "loop" in (before, after) and len(times) > 2 and np.array_equal(values[0],
                                                                              values[-1])
    coeffs = None
    if mode in ("catmull-rom", "kochanek-bartels"):
        v_in, v_out = kb_tangents(times, values, *(spec.get(key, 0.0) for key in KB_KEYS),
                                  closed=closed)
        coeffs = _hermite_coeffs(times, values, v_in, v_out)
    elif mode == "hermite":  # colours: tangents in the interpolation space (RGB or HSV)
        v_in, v_out = (_padded(spec[key], values.shape) for key in ("in_tangents",
                                                                    "out_tangents"))
        coeffs = _hermite_coeffs(times, values, v_in, v_out)
    track = Track(mode=mode, values=values, scalar=scalar, hsv=hsv, coeffs=coeffs, **common)
    if spec.get("arc_length") and len(times) > 1:
        track = _with_arc_table(track)
    return track


def _padded(tangents, shape) -> np.ndarray:
    """Tangents as an array of `shape`; missing trailing columns (a colour's alpha) are 0."""
    given = np.array(tangents, dtype=float).reshape(shape[0], -1)
    return np.hstack([given, np.zeros((shape[0], shape[1] - given.shape[1]))])


def kb_tangents(times, values, tension=0.0, continuity=0.0, bias=0.0, closed=False):
    """Kochanek-Bartels in- and out-tangents per unit time, (n, d) each (see module doc).

    tension, continuity, bias: one number for every key, or one per key (n,).
    """
    n = len(times)
    if n == 1:
        zero = np.zeros_like(values)
        return zero, zero
    prev_p = np.vstack([values[:1] * 2 - values[1:2], values[:-1]])
    next_p = np.vstack([values[1:], values[-1:] * 2 - values[-2:-1]])
    gaps = np.diff(times)
    prev_gap = np.concatenate([gaps[:1], gaps])
    next_gap = np.concatenate([gaps, gaps[-1:]])
    if closed:  # P_last == P_0: the neighbours wrap around the seam
        prev_p[0], prev_gap[0] = values[-2], gaps[-1]
        next_p[-1], next_gap[-1] = values[1], gaps[0]
    a = values - prev_p
    b = next_p - values
    t, c, bb = (np.asarray(x, dtype=float).reshape(-1, 1) for x in (tension, continuity,
                                                                     bias))
    span = (prev_gap + next_gap)[:, None]
    v_out = (1 - t) * ((1 + bb) * (1 + c) * a + (1 - bb) * (1 - c) * b) / span
    v_in = (1 - t) * ((1 + bb) * (1 - c) * a + (1 - bb) * (1 + c) * b) / span
    return v_in, v_out


def _hermite_coeffs(times, values, v_in, v_out) -> np.ndarray:
    """(n - 1, 4, d) power-basis coefficients of the cubic Hermite segments in s."""
    gap = np.diff(times)[:, None]
    p0, p1 = values[:-1], values[1:]
    m0, m1 = v_out[:-1] * gap, v_in[1:] * gap
    return np.stack([p0, m0, 3 * (p1 - p0) - 2 * m0 - m1, 2 * (p0 - p1) + m0 + m1], axis=1)


def _compile_rotation(quats, mode, common) -> Track:
    quats = quats.copy()
    for i in range(1, len(quats)):  # shortest arc: each key in the previous key's hemisphere
        if dot(quats[i], quats[i - 1]) < 0:
            quats[i] = -quats[i]
    omega = ctrl = None
    half = left = None
    if len(quats) > 1:
        rel = quat_multiply(_conj(quats[:-1]), quats[1:])  # q_i^-1 q_{i+1}
        half = _quat_log(rel)
        left = quat_left_matrix(quats[:-1])
        omega = np.einsum("nij,nj->ni", quat_to_matrix(quats[:-1]), 2 * half)
        if mode == "squad":
            closed = "loop" in (common["before"], common["after"]) and len(quats) > 2 and \
                abs(abs(dot(quats[0], quats[-1])) - 1) < 1e-15
            ctrl = _squad_controls(quats, closed)
    return Track(mode=mode, values=quats, omega=omega, ctrl=ctrl, half=half, left=left,
                 **common)


def _squad_controls(q, closed) -> np.ndarray:
    nxt = np.vstack([q[1:], q[1:2] if closed else q[-1:]])
    prv = np.vstack([q[-2:-1] if closed else q[:1], q[:-1]])
    if closed:  # the seam keys may differ in sign; put the wrapped neighbours alongside
        nxt[-1] *= -1.0 if dot(nxt[-1], q[-1]) < 0 else 1.0
        prv[0] *= -1.0 if dot(prv[0], q[0]) < 0 else 1.0
    inv = _conj(q)
    log_sum = _quat_log(quat_multiply(inv, nxt)) + _quat_log(quat_multiply(inv, prv))
    ctrl = quat_multiply(q, _quat_exp(-0.25 * log_sum))
    if not closed:
        ctrl[0], ctrl[-1] = q[0], q[-1]
    return ctrl


# ----------------------------------------------------------------------------- evaluate


def evaluate(track: Track, t):
    """(value, rate) of `track` at time(s) t (s). See the module docstring for shapes."""
    scalar_t = np.ndim(t) == 0
    t = np.atleast_1d(np.asarray(t, dtype=float))
    u, dudt = _wrap(track, t)
    if track.kind == ROTATION:
        value, rate = _eval_rotation(track, u, dudt)
    else:
        value, rate = _eval_vector(track, u, dudt)
        if track.kind == COLOR:
            value, rate = _finish_color(track, value, rate)
    if track.scalar:
        value, rate = value[:, 0], rate[:, 0]
    return (value[0], rate[0]) if scalar_t else (value, rate)


def _wrap(track: Track, t):
    """Map t to the key range [t_0, t_last]: (u, du/dt) per extrapolation mode."""
    t0, t1 = track.start, track.end
    period = t1 - t0
    u = t.copy()
    dudt = np.ones_like(t)
    for side, outside in (("before", t < t0), ("after", t > t1)):
        if not outside.any():
            continue
        mode = getattr(track, side)
        x = t[outside] - t0
        if mode == "clamp" or period == 0.0:
            u[outside] = t0 if side == "before" else t1
            dudt[outside] = 0.0
        elif mode == "loop":
            r = np.mod(x, period)
            # t_0 + kT ends a cycle after the keys (the last key), starts one before them
            end = (r == 0.0) if side == "after" else np.zeros_like(r, dtype=bool)
            u[outside] = np.where(end, t1, t0 + r)
        else:  # ping-pong: forwards on [0, T], backwards on (T, 2T)
            r = np.mod(x, 2.0 * period)
            back = r > period
            u[outside] = np.where(back, t0 + 2.0 * period - r, t0 + r)
            dudt[outside] = np.where(back, -1.0, 1.0)
    return u, dudt


def _segment(track: Track, u):
    """(segment index, s in [0, 1], segment duration) for u in [t_0, t_last]."""
    times = track.times
    i = np.clip(np.searchsorted(times, u, side="right") - 1, 0, len(times) - 2)
    gap = times[i + 1] - times[i]
    return i, (u - times[i]) / gap, gap


EASE = {  # s -> (warped s, d warped / ds); each maps 0 -> 0 and 1 -> 1 exactly
    "none": lambda s: (s, np.ones_like(s)),
    "in": lambda s: (s * s, 2.0 * s),
    "out": lambda s: (s * (2.0 - s), 2.0 * (1.0 - s)),
    "in-out": lambda s: (s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s)),
}


def _poly(coeffs, i, s):
    """Value and d/ds of the cubic segments i at s: (m, d) each."""
    a, b, c, d = (coeffs[i, k] for k in range(4))
    s = s[:, None]
    return a + s * (b + s * (c + s * d)), b + s * (2.0 * c + s * (3.0 * d))


def _eval_vector(track: Track, u, dudt):
    values = track.values
    n = len(values)
    if n == 1:
        return np.repeat(values, len(u), axis=0), np.zeros((len(u), values.shape[1]))
    if track.arc is not None:
        return _eval_arc(track, u, dudt)
    i, s, gap = _segment(track, u)
    s, warp = EASE[track.ease](s)
    speed = (warp * dudt / gap)[:, None]  # ds/dt
    if track.mode == "step":
        value, rate = values[i], np.zeros((len(u), values.shape[1]))
    elif track.mode == "linear":  # the slide's form, literally
        s2 = s[:, None]
        value = (1.0 - s2) * values[i] + s2 * values[i + 1]
        rate = (values[i + 1] - values[i]) * speed
    else:
        value, deriv = _poly(track.coeffs, i, s)
        rate = deriv * speed
    last = u >= track.end  # the last key exactly (a cubic's a+b+c+d may round off)
    if last.any():
        value[last] = values[-1]
    return value, rate


def _curve(track: Track, i, s):
    """The un-reparametrised curve and d/ds on segment i at s (for the arc-length table)."""
    if track.mode == "linear":
        p0, p1 = track.values[i], track.values[i + 1]
        return (1.0 - s[:, None]) * p0 + s[:, None] * p1, p1 - p0
    return _poly(track.coeffs, i, s)


def _with_arc_table(track: Track) -> Track:
    """The track with its arc-length table: knots at ARC_PIECES pieces per segment, the
    length covered at each knot and the curve's speed |dC/ds| at each piece's ends."""
    n_seg = len(track.times) - 1
    knots_s = np.linspace(0.0, 1.0, ARC_PIECES + 1)
    seg = np.repeat(np.arange(n_seg), ARC_PIECES)
    a, b = np.tile(knots_s[:-1], n_seg), np.tile(knots_s[1:], n_seg)
    knot_len = np.concatenate([[0.0], np.cumsum(_arc_pieces(track, seg, a, b))])
    knot_seg = np.append(seg, n_seg - 1)
    knot_s = np.append(a, 1.0)
    # |dC/ds| at both ends of every piece, each from the piece's own segment (the speed
    # per unit s jumps where segments of different durations meet)
    speeds = [np.linalg.norm(_curve(track, seg, x)[1], axis=1) for x in (a, b)]
    return dataclasses.replace(track, arc=(knot_seg, knot_s, knot_len, *speeds))


def _arc_pieces(track, seg, a, b):
    """Arc length of segments `seg` between s = a and s = b (arrays), Gauss-Legendre."""
    x = a[:, None] + (b - a)[:, None] * _GL_X[None, :]
    _, d = _curve(track, np.repeat(seg, len(_GL_X)), x.ravel())
    speed = np.linalg.norm(d, axis=1).reshape(x.shape)
    # A plain sum in a fixed order (not a BLAS matmul) gives the same bits for one time as
    # for many, so a run's samples equal evaluate(track, t) exactly.
    total = speed[:, 0] * _GL_W[0]
    for j in range(1, len(_GL_W)):
        total = total + speed[:, j] * _GL_W[j]
    return (b - a) * total


def _eval_arc(track: Track, u, dudt):
    """Constant speed along the curve: find s with length(0 -> s) = target.

    First guess: cubic Hermite interpolation of s(length) on the piece, whose end slopes
    are ds/dlength = 1 / |dC/ds| at the piece's ends; then NEWTON_STEPS Newton steps on
    length(s) - target with Gauss-Legendre lengths, which converge quadratically.
    """
    knot_seg, knot_s, knot_len, speed0, speed1 = track.arc
    values = track.values
    span = track.end - track.start
    frac, warp = EASE[track.ease]((u - track.start) / span)
    total = knot_len[-1]
    target = frac * total  # m of path covered
    dldt = total * warp * dudt / span
    k = np.clip(np.searchsorted(knot_len, target, side="right") - 1, 0, len(knot_len) - 2)
    seg = knot_seg[k]
    s0 = knot_s[k]
    s1 = np.where(knot_seg[k + 1] == seg, knot_s[k + 1], 1.0)
    piece = knot_len[k + 1] - knot_len[k]
    ok = (piece > 0) & (speed0[k] > 0) & (speed1[k] > 0)
    x = np.where(ok, (target - knot_len[k]) / np.where(ok, piece, 1.0), 0.0)
    ds = s1 - s0
    m0 = piece / np.where(ok, speed0[k], 1.0) / ds  # slopes in units of the piece
    m1 = piece / np.where(ok, speed1[k], 1.0) / ds
    x2, x3 = x * x, x * x * x
    y = np.where(ok, (x3 - 2 * x2 + x) * m0 + (3 * x2 - 2 * x3) + (x3 - x2) * m1, x)
    s = np.clip(s0 + ds * y, s0, s1)
    for _ in range(NEWTON_STEPS):
        _, d = _curve(track, seg, s)
        speed = np.linalg.norm(d, axis=1)
        err = knot_len[k] + _arc_pieces(track, seg, s0, s) - target
        s = np.clip(s - err / np.where(speed > 0, speed, np.inf), s0, s1)
    value, d = _curve(track, seg, s)
    speed = np.linalg.norm(d, axis=1)
    rate = d / np.where(speed > 0, speed, np.inf)[:, None] * dldt[:, None]
    value[target <= 0.0] = values[0]
    value[target >= total] = values[-1]
    return value, rate


# ----------------------------------------------------------------------------- rotations


def _conj(q):
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _quat_log(q):
    """(..., 4) unit quaternion -> (..., 3) rotation vector / 2 (angle in [0, 2 pi])."""
    v = q[..., 1:]
    sin_half = np.linalg.norm(v, axis=-1, keepdims=True)
    half = trig.atan2(sin_half, q[..., :1])  # not libm: the same bits on every CPU
    scale = np.where(sin_half > 1e-300, half / np.where(sin_half > 1e-300, sin_half, 1.0),
                     1.0)
    return v * scale


def _quat_exp(r):
    """(..., 3) half rotation vector -> (..., 4) unit quaternion."""
    half = np.linalg.norm(r, axis=-1, keepdims=True)
    # cos and sin(x)/x from maths.trig (1 at x = 0), not libm: the same bits on every CPU
    return np.concatenate([sin_cos(half)[1], r * sin_over_x(half)], axis=-1)


def slerp(p, q, h):
    """p (q/p)^h for (m, 4) quaternions and (m,) h, without flipping q's sign."""
    return quat_multiply(p, _quat_exp(h[:, None] * _quat_log(quat_multiply(_conj(p), q))))


def _eval_rotation(track: Track, u, dudt):
    q = track.values
    if len(q) == 1:
        return np.repeat(q, len(u), axis=0), np.zeros((len(u), 3))
    i, s, gap = _segment(track, u)
    s, warp = EASE[track.ease](s)
    sdot = warp * dudt / gap  # ds/dt
    if track.mode == "step":
        value, rate = q[i], np.zeros((len(u), 3))
    elif track.mode == "slerp":
        # q_i exp(s log r), r = q_i^-1 q_{i+1} = (cos(a/2), sin(a/2) n): with L(q_i) and
        # the half-angle vector (a/2) n precomputed per segment, one matmul per time
        half = track.half[i] * s[:, None]
        angle = np.linalg.norm(half, axis=1, keepdims=True)
        turn = np.concatenate([sin_cos(angle)[1], half * sin_over_x(angle)], axis=1)
        value = matmul(track.left[i], turn[:, :, None])[:, :, 0]
        # d/dt [q_i exp(s log r)] q^-1 = q_i (log r) q_i^-1 ds/dt: constant per segment
        rate = track.omega[i] * sdot[:, None]
    else:
        value = _squad(track, i, s)
        h = SQUAD_H
        dq = (_squad(track, i, s + h) - _squad(track, i, s - h)) / (2.0 * h)
        rate = 2.0 * quat_multiply(dq, _conj(value))[:, 1:] * sdot[:, None]
    last = u >= track.end
    if last.any():
        value[last] = q[-1]
    return value, rate


def _squad(track, i, s):
    q, a = track.values, track.ctrl
    return slerp(slerp(q[i], q[i + 1], s), slerp(a[i], a[i + 1], s), 2.0 * s * (1.0 - s))


# ----------------------------------------------------------------------------- colours


def rgb_to_hsv(rgba):
    """(n, 4) RGBA -> (n, 4) HSVA, hue in [0, 1)."""
    r, g, b, alpha = rgba.T
    hi = np.max(rgba[:, :3], axis=1)
    lo = np.min(rgba[:, :3], axis=1)
    span = hi - lo
    safe = np.where(span > 0, span, 1.0)
    hue = np.where(hi == r, np.mod((g - b) / safe, 6.0),
                   np.where(hi == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0)) / 6.0
    hue = np.where(span > 0, hue, 0.0)
    sat = np.where(hi > 0, span / np.where(hi > 0, hi, 1.0), 0.0)
    return np.stack([hue, sat, hi, alpha], axis=1)


def hsv_to_rgb(hsva, rate=None):
    """(n, 4) HSVA (any hue, taken mod 1) -> RGBA; with `rate` (n, 4) also d(RGBA)/dt.

    Channel c = v (1 - s m_c(h)) with m_c = clip(min(k, 4 - k), 0, 1), k = (n_c + 6h) mod 6,
    n = 5, 3, 1 for r, g, b (the closed form behind the usual six-sector table).
    """
    h, s, v, alpha = hsva.T
    n = np.array([5.0, 3.0, 1.0])
    k = np.mod(n[None, :] + 6.0 * h[:, None], 6.0)
    m = np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
    rgb = v[:, None] * (1.0 - s[:, None] * m)
    out = np.hstack([rgb, alpha[:, None]])
    if rate is None:
        return out
    dh, ds, dv, da = rate.T
    inner = np.minimum(k, 4.0 - k)
    dm_dk = np.where((inner > 0) & (inner < 1), np.where(k < 4.0 - k, 1.0, -1.0), 0.0)
    dm = dm_dk * 6.0 * dh[:, None]
    drgb = dv[:, None] * (1.0 - s[:, None] * m) - v[:, None] * (ds[:, None] * m
                                                                 + s[:, None] * dm)
    return out, np.hstack([drgb, da[:, None]])


def _unwrap_hue(hsva):
    """Hues of consecutive keys at most half a turn apart; greys borrow a neighbour's hue."""
    hsva = hsva.copy()
    coloured = np.flatnonzero(hsva[:, 1] > 0)
    if len(coloured):
        idx = np.arange(len(hsva))
        nearest = coloured[np.clip(np.searchsorted(coloured, idx), 0, len(coloured) - 1)]
        hsva[:, 0] = hsva[nearest, 0]
    step = np.mod(np.diff(hsva[:, 0]) + 0.5, 1.0) - 0.5
    hsva[1:, 0] = hsva[0, 0] + np.cumsum(step)
    return hsva


def _finish_color(track: Track, value, rate):
    if track.hsv:
        value, rate = hsv_to_rgb(value, rate)
    clipped = (value < 0.0) | (value > 1.0)
    return np.clip(value, 0.0, 1.0), np.where(clipped, 0.0, rate)
