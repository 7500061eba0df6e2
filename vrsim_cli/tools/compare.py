"""Compare two trajectories entity by entity: the numbers behind `vrsim compare A B`.

Layer 7. B is the reference (for CI: the golden file), as in `numpy.isclose(a, b)`.

Per entity, on the sample times both files hold:
- position error      e_p(t) = |p_A(t) - p_B(t)|               (m, Euclidean norm)
- orientation angle   theta(t), the angle of the rotation q_B^-1 q_A (rad, in [0, pi])
- velocity error      e_v(t) = |v_A(t) - v_B(t)|               (m/s)
- angular velocity    e_w(t) = |w_A(t) - w_B(t)|               (rad/s)
A sample exceeds the tolerance when e_p > atol + rtol |p_B|, e_v > atol + rtol |v_B|,
e_w > atol + rtol |w_B| or theta > angle_tol (atol is read in each quantity's SI unit).
NaN in either file always exceeds.

Times are matched, not interpolated: a sample of A and one of B are the same instant when
their times differ by at most TIME_EPS_S. Interpolating would add an error of its own that
could not be told apart from a change in the physics. Files written at different rates are
therefore compared on the times their grids share (a 100 Hz run against a 25 Hz golden: on
the 25 Hz samples), and the report says how many samples each side has that the other
lacks. Both files must cover the same span: a different first or last time (a run cut
short) fails the comparison, whatever the errors on the shared times.

Formats without velocities (TUM) are compared on position and orientation only; the report
names the entities whose velocities were skipped.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field

import numpy as np

from vrsim_cli.errors import InputError, Problem, printable
from vrsim_cli.text import plural, table
from vrsim_cli.tools.trajectory import Track, Trajectory

TIME_EPS_S = 1e-9  # s: two sample times within this are the same instant (MCAP stores ns)


@dataclass(frozen=True)
class Tolerance:
    atol: float = 1e-9  # in the quantity's SI unit (m, m/s, rad/s)
    rtol: float = 0.0  # relative to the reference (B) value's norm
    angle_tol: float = 1e-9  # rad


@dataclass(frozen=True)
class TolerancePlan:
    """The default tolerance and per-entity overrides: (fnmatch pattern, Tolerance); the last
    matching override wins."""

    default: Tolerance = Tolerance()
    overrides: tuple = ()

    def for_entity(self, name: str) -> Tolerance:
        chosen = self.default
        for pattern, tol in self.overrides:
            if fnmatch.fnmatchcase(name, pattern):
                chosen = tol
        return chosen


@dataclass
class EntityResult:
    name: str
    tolerance: Tolerance
    compared: int = 0  # sample times present in both files
    only_a: int = 0  # samples of A at times B lacks
    only_b: int = 0
    span_mismatch: str | None = None  # why the time spans differ, or None
    pos_err: float = 0.0  # m, max over the compared times
    angle_err: float = 0.0  # rad
    vel_err: float | None = 0.0  # m/s; None: a side has no velocities
    angvel_err: float | None = 0.0  # rad/s; None: a side has no angular velocities
    worst_t: float | None = None  # s, time of the largest position error
    first_exceed_t: float | None = None  # s, first compared time outside tolerance
    first_exceed_what: str | None = None  # which quantity exceeded first

    @property
    def ok(self) -> bool:
        return self.first_exceed_t is None and self.span_mismatch is None and self.compared > 0

    def as_dict(self) -> dict:
        return {"entity": self.name, "ok": self.ok, "compared_samples": self.compared,
                "samples_only_in_a": self.only_a, "samples_only_in_b": self.only_b,
                "span_mismatch": self.span_mismatch,
                "max_position_error_m": _json_float(self.pos_err),
                "max_orientation_error_rad": _json_float(self.angle_err),
                "max_velocity_error_m_s": _json_float(self.vel_err),
                "max_angular_velocity_error_rad_s": _json_float(self.angvel_err),
                "time_of_max_position_error_s": self.worst_t,
                "first_exceedance_s": self.first_exceed_t,
                "first_exceedance_quantity": self.first_exceed_what,
                "tolerance": {"atol": self.tolerance.atol, "rtol": self.tolerance.rtol,
                              "angle_tol_rad": self.tolerance.angle_tol}}


@dataclass
class Report:
    a: Trajectory
    b: Trajectory
    entities: list = field(default_factory=list)  # EntityResult of the shared ones, B's order
    only_in_a: list = field(default_factory=list)  # entity names
    only_in_b: list = field(default_factory=list)
    allow_missing_entities: bool = False

    @property
    def ok(self) -> bool:
        missing = (self.only_in_a or self.only_in_b) and not self.allow_missing_entities
        return all(e.ok for e in self.entities) and not missing and bool(self.entities)

    @property
    def first_exceedance(self) -> tuple[float, str] | None:
        hits = [(e.first_exceed_t, e.name) for e in self.entities
                if e.first_exceed_t is not None]
        return min(hits) if hits else None

    @property
    def velocity_skipped(self) -> list:
        return [e.name for e in self.entities if e.vel_err is None]

    def as_dict(self) -> dict:
        first = self.first_exceedance
        return {
            "ok": self.ok,
            "a": {"file": self.a.source, "format": self.a.format,
                  "entities": len(self.a.tracks)},
            "b": {"file": self.b.source, "format": self.b.format,
                  "entities": len(self.b.tracks)},
            "reference": "b",
            "time_matching": {"method": "exact", "epsilon_s": TIME_EPS_S,
                              "interpolation": False},
            "entities_only_in_a": self.only_in_a,
            "entities_only_in_b": self.only_in_b,
            "allow_missing_entities": self.allow_missing_entities,
            "velocity_not_compared": self.velocity_skipped,
            "first_exceedance": {"t_s": first[0], "entity": first[1]} if first else None,
            "entities": [e.as_dict() for e in self.entities],
        }


def _json_float(x: float | None):
    """JSON has no NaN or infinity: report them as strings."""
    if x is None or math.isfinite(x):
        return x
    return str(x)


def compare(a: Trajectory, b: Trajectory, plan: TolerancePlan = TolerancePlan(), *,
            allow_missing_entities: bool = False) -> Report:
    """Compare trajectory `a` with the reference `b`. Raises InputError when a track's
    times are not increasing (two samples of one entity at the same time)."""
    for traj in (a, b):
        if not traj.tracks and traj.format == "mcap":
            raise InputError([Problem(traj.source, 0, 0, (), "holds no trajectory",
                                      "vrsim reads /vrsim/state or, from files of other "
                                      "tools, foxglove.FrameTransforms channels")])
    report = Report(a, b, allow_missing_entities=allow_missing_entities)
    report.only_in_a = [n for n in a.tracks if n not in b.tracks]
    report.only_in_b = [n for n in b.tracks if n not in a.tracks]
    for name in b.tracks:
        if name in a.tracks:
            ta = _ordered(a.tracks[name], a.source, name)
            tb = _ordered(b.tracks[name], b.source, name)
            report.entities.append(compare_tracks(name, ta, tb, plan.for_entity(name)))
    return report


def _ordered(track: Track, source: str, name: str) -> Track:
    """The track sorted by time. Non-finite or repeated times are input errors."""
    if not np.all(np.isfinite(track.t)):
        raise InputError([Problem(source, 0, 0, (), f"entity '{name}' has a sample time "
                                                    f"that is not a finite number")])
    order = np.argsort(track.t, kind="stable")
    t = track.t[order]
    dup = np.flatnonzero(np.diff(t) <= TIME_EPS_S)
    if len(dup):
        raise InputError([Problem(source, 0, 0, (), f"entity '{name}' has two samples "
                                                    f"at t = {t[dup[0]]:.9g} s")])
    return Track(t, track.pos[order], track.quat[order], track.vel[order],
                 track.angvel[order])


def match_times(ta: np.ndarray, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of the samples at the same instant (|ta - tb| <= TIME_EPS_S).
    Both inputs are strictly increasing with steps larger than TIME_EPS_S, so each sample
    has at most one partner."""
    if len(ta) == 0 or len(tb) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    j = np.clip(np.searchsorted(tb, ta), 1, len(tb) - 1) if len(tb) > 1 else \
        np.zeros(len(ta), dtype=np.int64)
    # the nearest of tb[j - 1] and tb[j]
    if len(tb) > 1:
        left = np.abs(ta - tb[j - 1]) <= np.abs(ta - tb[j])
        j = np.where(left, j - 1, j)
    hit = np.abs(ta - tb[j]) <= TIME_EPS_S
    return np.flatnonzero(hit), j[hit]


def quat_angle(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) between orientations qa and qb, (n, 4) each.

    q and -q are the same rotation, so qb is flipped to the side of qa (sign of the dot
    product). With phi the angle between the two unit 4-vectors, the rotation angle is
    2 phi, and phi = 2 atan2(|qa - qb|, |qa + qb|): unlike 2 acos(|qa . qb|), this keeps
    full precision for small angles (acos near 1 resolves only ~3e-8 rad).
    """
    qa = qa / np.linalg.norm(qa, axis=1, keepdims=True)
    qb = qb / np.linalg.norm(qb, axis=1, keepdims=True)
    sign = np.where(np.einsum("ij,ij->i", qa, qb) < 0.0, -1.0, 1.0)[:, None]
    qb = sign * qb
    return 4.0 * np.arctan2(np.linalg.norm(qa - qb, axis=1), np.linalg.norm(qa + qb, axis=1))


def _norm(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x, axis=1)


def _has(x: np.ndarray) -> bool:
    """A column group is present when it is not all NaN (readers fill absent ones with NaN)."""
    return x.size > 0 and not np.all(np.isnan(x))


def compare_tracks(name: str, a: Track, b: Track, tol: Tolerance) -> EntityResult:
    """Compare one entity's samples; `b` is the reference."""
    res = EntityResult(name, tol)
    ia, ib = match_times(a.t, b.t)
    res.compared = len(ia)
    res.only_a = len(a.t) - len(ia)
    res.only_b = len(b.t) - len(ib)
    if res.compared == 0:
        res.span_mismatch = "no sample times in common"
        return res
    if abs(a.t[0] - b.t[0]) > TIME_EPS_S or abs(a.t[-1] - b.t[-1]) > TIME_EPS_S:
        res.span_mismatch = (f"A covers {a.t[0]:.6g} .. {a.t[-1]:.6g} s, "
                             f"B covers {b.t[0]:.6g} .. {b.t[-1]:.6g} s")
    t = b.t[ib]
    with np.errstate(invalid="ignore", over="ignore"):
        checks = []  # (quantity, error per sample, bound per sample)
        e_p = _norm(a.pos[ia] - b.pos[ib])
        checks.append(("position", e_p, tol.atol + tol.rtol * _norm(b.pos[ib])))
        theta = quat_angle(a.quat[ia], b.quat[ib])
        checks.append(("orientation", theta, np.full(len(t), tol.angle_tol)))
        for attr, label in (("vel", "velocity"), ("angvel", "angular velocity")):
            if _has(getattr(a, attr)) and _has(getattr(b, attr)):
                vb = getattr(b, attr)[ib]
                e = _norm(getattr(a, attr)[ia] - vb)
                checks.append((label, e, tol.atol + tol.rtol * _norm(vb)))
                setattr(res, f"{attr}_err", _max(e))
            else:
                setattr(res, f"{attr}_err", None)
        res.pos_err, res.angle_err = _max(e_p), _max(theta)
        res.worst_t = float(t[_argmax(e_p)])
        for label, err, bound in checks:
            bad = np.flatnonzero(~(err <= bound))  # NaN never passes
            if len(bad) and (res.first_exceed_t is None or t[bad[0]] < res.first_exceed_t):
                res.first_exceed_t, res.first_exceed_what = float(t[bad[0]]), label
    return res


def _max(x: np.ndarray) -> float:
    return float("nan") if np.isnan(x).any() else float(x.max())


def _argmax(x: np.ndarray) -> int:
    nan = np.flatnonzero(np.isnan(x))
    return int(nan[0]) if len(nan) else int(np.argmax(x))


# ----------------------------------------------------------------------------- text report


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.3g}"


def format_report(report: Report, *, show_all: bool = False, max_rows: int = 20) -> list[str]:
    """The report as lines of a readable table. Failing entities are always listed;
    passing ones too when there are few (or `show_all`). Names from the files are printed
    with control characters escaped."""
    return [printable(line) for line in _report_lines(report, show_all, max_rows)]


def _report_lines(report: Report, show_all: bool, max_rows: int) -> list[str]:
    a, b = report.a, report.b
    lines = [f"A: {a.source} ({a.format}, {plural(len(a.tracks), 'entity')})",
             f"B: {b.source} ({b.format}, {plural(len(b.tracks), 'entity')}) - the reference",
             f"times: compared on the sample times both files hold (|tA - tB| <= "
             f"{TIME_EPS_S:g} s), no interpolation"]
    rows = report.entities
    failing = [e for e in rows if not e.ok]
    shown = rows if show_all or len(rows) <= max_rows else failing
    cells = []
    for e in shown:
        first = "-" if e.first_exceed_t is None else f"{e.first_exceed_t:.6g}"
        verdict = "ok" if e.ok else (f"FAIL {e.first_exceed_what}" if e.first_exceed_what
                                     else f"FAIL {e.span_mismatch}")
        if not e.ok and e.first_exceed_what and e.span_mismatch:
            verdict += f"; {e.span_mismatch}"
        cells.append([e.name, e.compared, e.only_a, e.only_b, _fmt(e.pos_err),
                      _fmt(e.angle_err), _fmt(e.vel_err), _fmt(e.angvel_err), first, verdict])
    if shown:  # columns as wide as their longest cell: long entity names stay in line
        lines += table(["entity", "samples", "onlyA", "onlyB", "pos m", "angle rad",
                        "vel m/s", "angvel", "first over", "result"], cells,
                       right=set(range(1, 9)))
    if len(shown) < len(rows):
        more = "more " if shown else ""
        lines.append(f"... {plural(len(rows) - len(shown), more + 'entity', more + 'entities')}"
                     f" within tolerance (--all lists them)")
    if any(e.only_a or e.only_b for e in rows):
        lines.append("note: the files have different sample times; errors are over the "
                     "shared times only")
    if report.velocity_skipped:
        names = report.velocity_skipped
        lines.append(f"note: velocities not compared for {plural(len(names), 'entity')} "
                     f"({', '.join(names[:5])}{', ...' if len(names) > 5 else ''}): "
                     f"a file has none (TUM holds poses only)")
    for side, names in (("A", report.only_in_a), ("B", report.only_in_b)):
        if names:
            shown_names = ", ".join(names[:10]) + (", ..." if len(names) > 10 else "")
            lines.append(f"entities only in {side} ({len(names)}): {shown_names}")
    if rows:
        worst = max(rows, key=lambda e: (math.isnan(e.pos_err), e.pos_err))
        lines.append(f"largest position error: {_fmt(worst.pos_err)} m ({worst.name}"
                     f"{'' if worst.worst_t is None else f' at t = {worst.worst_t:.6g} s'})")
    first = report.first_exceedance
    if report.ok:
        lines.append(f"OK: {plural(len(rows), 'entity')} within tolerance")
    else:
        why = []
        if first:
            why.append(f"first exceedance at t = {first[0]:.6g} s ({first[1]})")
        if failing and not first:
            why.append(f"{plural(len(failing), 'entity')} with mismatched samples")
        elif any(e.span_mismatch for e in failing):
            why.append("sample spans differ")
        if (report.only_in_a or report.only_in_b) and not report.allow_missing_entities:
            why.append("entity sets differ (--allow-missing-entities to compare the shared "
                       "ones only)")
        if not rows:
            why.append("no entity in common")
        lines.append("FAIL: " + "; ".join(why))
    return lines
