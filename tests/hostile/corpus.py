"""A hostile-input corpus for vrsim, run as real processes (issue 19, "Hostile inputs").

    python tests/hostile/corpus.py [--jobs 2] [--timeout 60] [--only CATEGORY ...]
                                   [--limit N] [--report report.json] [--list] [--warm]

Builds >= 2500 cases in the categories of the issue, each a folder with a scene (and
meshes, sensor files, FIFOs, links, ...) and the `vrsim` invocations a user would type:

- types:    every key of a scene that touches the whole format, with a value of each wrong
            type (null, bool, string, number, list, mapping, nested list)
- numbers:  every number of that scene at the ends of the float range and beyond
            (1e308, -1e308, 5e-324, 1e-300, 0, -0.0, 2**63, 10**400, ...)
- meshes:   degenerate meshes (a line, a point, a flat hull, a vertex at 1e308, NaN, no
            triangles, zero-area triangles, huge and tiny scales, 300k-1M triangles, junk
            bytes) under every collision geometry, as static and as dynamic bodies
- yaml:     alias and merge bombs, deep bracket and block nesting, a 2M-number flow list,
            huge strings and keys, control characters, tags, binary junk
- chains:   parent chains from 10 to 5000 long, cycles, wide trees
- files:    the scene, input files, meshes and outputs as FIFOs, devices, folders, links,
            loops, empty files, long and odd names, NUL bytes
- limits:   solver iterations, frame sizes, emitter and body counts at and past the limits
- outputs:  issue 53's classes: frames folders holding what vrsim did not write (user
            frames, notes, FIFOs and links named like frames, subfolders, the folder itself
            a link, file or FIFO, unwritable), video targets of every kind, with and without
            -o; standard streams closed (0, 1, 2 and together) for every command; a full
            disk (RLIMIT_FSIZE at 0 B to 100 kB) for every writer; the kernel cache damaged
            (truncated, empty, random entries), a file, unwritable or full

Every invocation is checked for: an exit code in the allowed set (validate: 0, 2; run: 0,
1, 2; info/compare: 0, 1, 2), no traceback, no hang (--timeout), its peak memory (the
process's maximum resident set), nothing half-written (no `.partial` left, nothing outside
the case's folder), and for runs that exit 0, no NaN or infinity in the trajectory (a
silent failure). Cases of `outputs` also check that no file the case made before the
command changed or went, except the targets it names (`touched`), that nothing appeared
beside them (`stray`), and that stderr stays under 20 lines (`spam`). A summary per category is printed; --report writes every result.

Not run by the test suite in full (it takes ~20 min on 2 cores); tests/test_hostile_schema.py
runs the schema-driven generator in CI.
"""

from __future__ import annotations

import argparse
import base64
import copy
import json
import math
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
MB = 1024 * 1024

# ----------------------------------------------------------------------------- bases


def cube_stl(scale: float = 0.5) -> bytes:
    """A closed cube of half-size `scale`, ASCII STL."""
    v = [(x, y, z) for x in (-scale, scale) for y in (-scale, scale) for z in (-scale, scale)]
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return stl_ascii([[v[a], v[b], v[c]] for a, b, c in faces])


def stl_ascii(triangles) -> bytes:
    out = ["solid m"]
    for tri in triangles:
        out.append(" facet normal 0 0 0\n  outer loop")
        out += [f"   vertex {x!r} {y!r} {z!r}" for x, y, z in tri]
        out.append("  endloop\n endfacet")
    out.append("endsolid m\n")
    return "\n".join(out).encode()


def stl_binary(triangles, count: int | None = None) -> bytes:
    head = b"\0" * 80 + struct.pack("<I", len(triangles) if count is None else count)
    body = b"".join(struct.pack("<12fH", 0, 0, 0, *[c for v in tri for c in v], 0)
                    for tri in triangles)
    return head + body


BASE = {
    "vrsim": 1, "name": "hostile", "description": "corpus base", "dimension": 3,
    "duration": 0.05, "frame_rate": 100, "dt": 0.01, "integrator": "rk4",
    "gravity": [0, -9.81, 0],
    "bodies": [
        {"name": "ball", "mass": 0.2, "shape": {"type": "sphere", "radius": 0.05},
         "position": [0, 1, 0], "velocity": [1, 2, 0], "color": [1, 0, 0],
         "forces": [{"force": [0, 5, 0], "start": 0.01, "end": 0.03}],
         "material": {"restitution": 0.5, "friction": 0.3}},
        # apart from the ball (since start overlaps are an input error, a crate around
        # the ball made every case stop at validation)
        {"name": "crate", "mass": 2, "shape": {"type": "box", "size": [1, 2, 3]},
         "position": [0, 1.5, 6], "euler_deg": [0, 90, 0], "angular_velocity": [0, 1, 0],
         "damping": {"linear": 0.1, "angular": 0.1},
         "torques": [{"torque": [0, 1, 0], "start": 0, "end": 0.02}]},
        {"name": "top", "mass": 1, "orientation": [1, 0, 0, 0],
         "shape": {"type": "capsule", "radius": 0.1, "length": 1}, "position": [3, 1, 0]},
        {"name": "can", "density": 500, "shape": {"type": "cylinder", "radius": 0.2,
                                                    "length": 0.5}, "position": [-3, 1, 0]},
        {"name": "cube", "particles": {"grid": {"n": 2, "size": 0.5, "mass": 1}},
         "position": [0, 3, 3]},
        {"name": "floor", "type": "static", "shape": {"type": "plane", "normal": [0, 1, 0],
                                                       "offset": -1}},
        {"name": "rock", "type": "static", "position": [0, -0.5, -4],
         "shape": {"type": "mesh", "file": "mesh.stl", "scale": 1.5},
         "collision": {"geometry": "hull"}},
        {"name": "cart", "type": "kinematic", "velocity": [0, 0, 1],
         "keyframes": {"color": {"times": [0, 0.05], "values": [[1, 0, 0], [0, 0, 1]]}}},
        {"name": "arm", "type": "kinematic", "parent": "cart", "position": [0, 1, 0],
         "keyframes": {"orientation": {"times": [0, 0.05], "values": [[1, 0, 0, 0],
                                                                       [0, 1, 0, 0]]},
                       "position": {"times": [0, 0.025, 0.05], "values": [[0, 1, 0],
                                                                           [0, 2, 0],
                                                                           [0, 1, 0]],
                                    "interpolation": "catmull-rom"}}},
        {"name": "car", "type": "kinematic", "drive": {"speed": 2, "heading_deg": 10,
                                                        "yaw_rate_deg": 30}},
    ],
    "springs": [{"body": "ball", "anchor": [0, 2, 0], "stiffness": 10, "damping": 0.5}],
    "emitters": [{"name": "drop", "position": [0, 0.5, 0], "direction": [0, 1, 0],
                  "speed": 6, "speed_jitter": 0.1, "spread_deg": 12, "count": 5, "rate": 100,
                  "mass": 0.001, "radius": 0.015, "color": [0.3, 0.6, 1.0, 0.9], "seed": 7}],
    "collision": {"tolerance": 0.001, "broad_phase": "grid", "iterations": 4,
                  "pairs": [{"bodies": ["ball", "crate"], "restitution": 0.9}]},
    "output": {"file": "out.csv", "rate": 50},
}
OBSERVER_BASE = {
    "vrsim": 1, "name": "walker", "duration": 0.05, "frame_rate": 100, "dt": 0.01,
    "observer": {"mode": "walk", "position": [0, 1.6, 0], "direction": [0, 0, -1],
                 "up": [0, 1, 0], "v_max": 1, "gamma_max": 90, "eye_height": 1.6,
                 "step_height": 0.3, "radius": 0.25, "fov_deg": 60},
    "input": {"mouse": [{"t": 0, "alpha": 0.5, "beta": 0.1}, {"t": 0.02, "alpha": 1,
                                                                "beta": -0.2}]},
    "bodies": [{"name": "ground", "type": "static",
                "shape": {"type": "box", "size": [20, 0.1, 20]}}],
    "output": {"file": "out.csv", "frames": {"every": 2, "width": 64, "height": 48}},
}
BASE_2D = {"vrsim": 1, "dimension": 2, "duration": 0.05, "frame_rate": 100, "dt": 0.01,
           "bodies": [{"name": "disc", "mass": 1, "angle_deg": 30, "position": [0, 1],
                       "velocity": [1, 0], "angular_velocity": 2,
                       "shape": {"type": "box", "size": [1, 1]}}],
           "output": {"file": "out.csv"}}
BASES = {"base": BASE, "observer": OBSERVER_BASE, "2d": BASE_2D}

WRONG_TYPES = [None, True, "text", 7, 2.5, [], {}, [[1, 2]], [None], {"k": 1}]
EXTREMES = [1e308, -1e308, 1.7976931348623157e308, 5e-324, -5e-324, 1e-300, 1e-200,
            1e-30, 0, -0.0, 1e16, 2 ** 63, -(2 ** 63), 10 ** 400, 1e300, -1]


def junk_bytes(n: int) -> bytes:
    """n random bytes, the same on every run (seeded by n), so that two runs of the corpus
    (spawn and fork mode, before and after a fix) feed vrsim the same junk."""
    import random

    return random.Random(f"junk-{n}").randbytes(n)


def leaves(node, prefix=()):
    """(path, value) of every node of a JSON-like document (containers too)."""
    yield prefix, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from leaves(value, prefix + (key,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from leaves(value, prefix + (i,))


def set_at(doc, path, value):
    doc = copy.deepcopy(doc)
    node = doc
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value
    return doc


def dump(doc) -> bytes:
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, width=10 ** 9).encode()


# ----------------------------------------------------------------------------- cases


@dataclass
class Case:
    category: str
    name: str
    files: dict  # name -> bytes | ("fifo",) | ("link", target) | ("dir",) | ("chmod0", bytes)
    commands: list  # argument lists (after `vrsim`); "{d}" is the case folder
    allowed: tuple = ()  # per command, the exit codes allowed (default by command)
    results: list = field(default_factory=list)
    complete: bool = False  # every command ran (not cut short by SIGINT/SIGTERM)
    key: str = ""  # unique in the corpus (see case_keys)
    close: tuple = ()  # standard descriptors closed before the interpreter starts
    fsize: int = -1  # RLIMIT_FSIZE in bytes (writes past it fail like a full disk)
    env: dict = field(default_factory=dict)  # extra variables; "{d}" is the case folder
    targets: tuple | None = None  # names a command may change; None: no touched check


RUN = ["run", "scene.yaml", "-q"]
VALIDATE_RUN = [["validate", "scene.yaml"], RUN]


def with_mesh(files: dict) -> dict:
    return {"mesh.stl": cube_stl(), **files}


def types_cases() -> list[Case]:
    cases = []
    for base_name, base in BASES.items():
        for path, value in leaves(base):
            if not path:
                continue
            for wrong in WRONG_TYPES:
                if type(wrong) is type(value) and wrong == value:
                    continue
                doc = set_at(base, path, wrong)
                cases.append(Case("types", f"{base_name}:{'.'.join(map(str, path))}="
                                  f"{json.dumps(wrong)}", with_mesh({"scene.yaml": dump(doc)}),
                                  VALIDATE_RUN))
    return cases


def numbers_cases() -> list[Case]:
    cases = []
    for base_name, base in BASES.items():
        for path, value in leaves(base):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            for extreme in EXTREMES:
                doc = set_at(base, path, extreme)
                text = dump(doc)
                if extreme == 10 ** 400:  # beyond float: safe_dump writes it as an integer
                    text = text.replace(str(10 ** 400).encode(), b"1" + b"0" * 400)
                cases.append(Case("numbers", f"{base_name}:{'.'.join(map(str, path))}="
                                  f"{extreme if extreme != 10 ** 400 else '1e400 (int)'}",
                                  with_mesh({"scene.yaml": text}), VALIDATE_RUN))
    # The issue's named silent failures and overflows, as whole scenes
    named = {
        "force-end-1e308": "bodies: [{name: a, mass: 1, forces: [{force: [1, 0, 0], "
                           "end: 1.0e308}]}]",
        "mass-1e308": "bodies: [{name: a, mass: 1.0e308, shape: {type: sphere, radius: 1}}]",
        "size-1e308": "bodies: [{name: a, mass: 1, shape: {type: box, size: [1.0e308, 1, 1]}}]",
        "radius-tiny": "bodies: [{name: a, mass: 1, shape: {type: sphere, radius: 1.0e-300}}]",
        "radius-tiny-static": "bodies: [{name: a, type: static, shape: {type: sphere, "
                              "radius: 1.0e-300}}]\ncollision: {}",
        "observer-direction-tiny": "observer: {mode: fly, direction: [1.0e-300, 0, 0]}",
        "observer-up-tiny": "observer: {mode: walk, up: [0, 1.0e-300, 0]}",
        "observer-look-at-self": "observer: {mode: examine, position: [0, 1, 0], "
                                 "look_at: [0, 1, 0]}",
        "key-quat-tiny": "bodies: [{name: a, type: kinematic, keyframes: {orientation: "
                         "{times: [0, 1], values: [[1.0e-200, 0, 0, 0], [1, 0, 0, 0]]}}}]",
        "key-times-subnormal": "bodies: [{name: a, type: kinematic, keyframes: {position: "
                               "{times: [0, 5.0e-324], values: [[0, 0, 0], [1, 0, 0]]}}}]",
        "key-times-close": "bodies: [{name: a, type: kinematic, keyframes: {orientation: "
                           "{times: [0, 1.0e-300], values: [[1, 0, 0, 0], [0, 1, 0, 0]], "
                           "interpolation: squad}}}]",
        "orientation-tiny": "bodies: [{name: a, mass: 1, shape: {type: sphere, radius: 1}, "
                            "orientation: [1.0e-200, 0, 0, 0]}]",
        "plane-normal-tiny": "bodies: [{name: p, type: static, shape: {type: plane, "
                             "normal: [0, 1.0e-320, 0]}}]",
        "emitter-direction-tiny": "emitters: [{name: e, count: 2, rate: 10, speed: 1, "
                                  "mass: 1, direction: [5.0e-324, 0, 0]}]",
        "spin-1e300": "bodies: [{name: a, mass: 1, shape: {type: box, size: [1, 2, 3]}, "
                      "angular_velocity: [1.0e300, 0, 0]}]",
        "inertia-tiny": "bodies: [{name: a, mass: 1, inertia: [1.0e-300, 1.0e-300, 1.0e-300]}]",
        "inertia-huge": "bodies: [{name: a, mass: 1, inertia: [1.0e300, 1.0e300, 1.0e300]}]",
        "spring-stiff": "bodies: [{name: a, mass: 1}]\nsprings: [{body: a, anchor: [0, 1, 0], "
                        "stiffness: 1.0e300}]",
        "drive-yaw-huge": "bodies: [{name: c, type: kinematic, drive: {speed: 1, "
                          "yaw_rate_deg: 1.0e308}}]",
        "camera-far": "bodies: [{name: a, mass: 1}]\noutput: {frames: {camera: {position: "
                      "[1.0e308, 0, 0], look_at: [0, 0, 0]}}}",
        "density-tiny": "bodies: [{name: a, density: 5.0e-324, shape: {type: sphere, "
                        "radius: 1}}]",
        "gravity-huge": "gravity: [0, -1.0e308, 0]\nbodies: [{name: a, mass: 1}]",
    }
    for name, body in named.items():
        text = f"vrsim: 1\nduration: 0.1\ndt: 0.01\nframe_rate: 100\n{body}\n"
        cases.append(Case("numbers", f"named:{name}", {"scene.yaml": text.encode()},
                          [["validate", "scene.yaml"], ["run", "scene.yaml", "-q", "-o",
                                                        "out.csv"]]))
    return cases


def mesh_files() -> dict:
    line = [[(0, 0, 0), (1, 1, 1), (2, 2, 2)], [(0, 0, 0), (3, 3, 3), (1, 1, 1)]]
    point = [[(1, 1, 1)] * 3] * 4
    flat = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(1, 0, 0), (1, 1, 0), (0, 1, 0)]]
    tri = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 0, 0), (0, 1, 0), (0, 0, 1)],
           [(0, 0, 0), (0, 0, 1), (1, 0, 0)], [(1, 0, 0), (0, 0, 1), (0, 1, 0)]]
    far = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 0, 0), (0, 1, 0), (0, 0, 1e308)],
           [(0, 0, 0), (0, 0, 1e308), (1, 0, 0)], [(1, 0, 0), (0, 0, 1e308), (0, 1, 0)]]
    nan = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 0, 0), (0, 1, 0), (float("nan"), 0, 1)]]
    inf = [[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 0, 0), (0, 1, 0), (float("inf"), 0, 1)]]
    tiny = [[(x * 1e-300, y * 1e-300, z * 1e-300) for x, y, z in t] for t in tri]
    huge = [[(x * 1e300, y * 1e300, z * 1e300) for x, y, z in t] for t in tri]
    subnormal = [[(x * 5e-324, y * 5e-324, z * 5e-324) for x, y, z in t] for t in tri]
    out = {
        "cube.stl": cube_stl(), "line.stl": stl_ascii(line), "point.stl": stl_ascii(point),
        "flat.stl": stl_ascii(flat), "tetra.stl": stl_ascii(tri), "far.stl": stl_ascii(far),
        "nan.stl": stl_ascii(nan), "inf.stl": stl_ascii(inf), "tiny.stl": stl_ascii(tiny),
        "huge.stl": stl_ascii(huge), "subnormal.stl": stl_ascii(subnormal),
        "empty.stl": b"", "notri.stl": b"solid m\nendsolid m\n",
        "junk.stl": bytes(range(256)) * 20, "badcount.stl": stl_binary(tri, count=10 ** 9),
        "binline.stl": stl_binary(line), "zero-area.stl": stl_ascii([[(0, 0, 0)] * 3] * 3),
        "point.obj": b"v 0 0 0\nf 1 1 1\n", "badidx.obj": b"v 0 0 0\nv 1 0 0\nf 1 2 99\n",
        "flat.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n",
        "nan.obj": b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "neg.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3\n",
        "empty.obj": b"", "text.obj": b"hello world\n" * 100,
        "junk.ply": b"ply\nformat ascii 1.0\nelement vertex 999999999\nend_header\n",
        "junk.glb": b"glTF" + b"\xff" * 100, "junk.gltf": b"{\"asset\": 1}",
        "unknown.xyz": cube_stl(), "noext": cube_stl(),
    }
    return out


def big_mesh(n_tri: int) -> bytes:
    """A closed-ish sphere-like mesh of about n_tri triangles, binary STL."""
    import numpy as np

    k = max(2, int(math.sqrt(n_tri / 2)))
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, k + 1), np.linspace(0, np.pi, k + 1))
    pts = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
    a, b, c, d = pts[:-1, :-1], pts[1:, :-1], pts[1:, 1:], pts[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3),
                           np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    rec = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tris
    return b"\0" * 80 + struct.pack("<I", len(tris)) + rec.tobytes()


def meshes_cases() -> list[Case]:
    cases = []
    meshes = mesh_files()
    for file, data in meshes.items():
        for geometry in ("exact", "sphere", "aabb", "obb", "hull", "mesh"):
            for kind in ("static", "dynamic"):
                for collide in (True, False):
                    body = {"name": "m", "shape": {"type": "mesh", "file": file},
                            "position": [0, 0, 0]}
                    if kind == "dynamic":
                        body["density"] = 1000
                    else:
                        body["type"] = "static"
                    doc = {"vrsim": 1, "duration": 0.03, "frame_rate": 100, "dt": 0.01,
                           "bodies": [body, {"name": "ball", "mass": 1, "shape": {
                               "type": "sphere", "radius": 0.1}, "position": [0, 2, 0]}]}
                    if collide:
                        body["collision"] = {"geometry": geometry}
                        doc["collision"] = {}
                    elif geometry != "exact":
                        continue
                    cases.append(Case("meshes", f"{file}:{geometry}:{kind}:"
                                      f"{'collide' if collide else 'none'}",
                                      {"scene.yaml": dump(doc), file: data},
                                      [["validate", "scene.yaml"],
                                       ["run", "scene.yaml", "-q", "-o", "out.mcap"],
                                       ["mass-properties", "scene.yaml"],
                                       ["collision-proxies", "scene.yaml", "--samples",
                                        "50"]]))
    for scale in (1e308, 1e154, 1e100, 1e-100, 1e-154, 1e-300, 5e-324):
        for geometry in ("exact", "hull", "obb", "sphere"):
            doc = {"vrsim": 1, "duration": 0.03, "frame_rate": 100, "dt": 0.01,
                   "collision": {}, "bodies": [
                       {"name": "m", "density": 1, "shape": {"type": "mesh", "file":
                                                             "cube.stl", "scale": scale},
                        "collision": {"geometry": geometry}},
                       {"name": "s", "type": "static", "position": [0, -2, 0],
                        "shape": {"type": "sphere", "radius": 1}}]}
            cases.append(Case("meshes", f"scale={scale}:{geometry}",
                              {"scene.yaml": dump(doc), "cube.stl": cube_stl()},
                              [["validate", "scene.yaml"],
                               ["run", "scene.yaml", "-q", "-o", "out.mcap"],
                               ["mass-properties", "scene.yaml"]]))
    for n_tri in (100_000, 300_000, 1_000_000):
        for collide in (True, False):
            doc = {"vrsim": 1, "duration": 0.03, "frame_rate": 100, "dt": 0.01,
                   "bodies": [{"name": "m", "type": "static", "shape": {
                       "type": "mesh", "file": "big.stl"}},
                       {"name": "ball", "mass": 1, "position": [0, 2, 0],
                        "shape": {"type": "sphere", "radius": 0.1}}]}
            if collide:
                doc["collision"] = {}
            cases.append(Case("meshes", f"big-{n_tri}:{'collide' if collide else 'none'}",
                              {"scene.yaml": dump(doc), "big.stl": ("bigmesh", n_tri)},
                              [["validate", "scene.yaml"],
                               ["run", "scene.yaml", "-q", "-o", "out.mcap"]]))
    return cases


def yaml_cases() -> list[Case]:
    head = "vrsim: 1\nduration: 0.05\n"
    texts = {}
    for width in (2, 5, 10, 30):
        for depth in (3, 6, 9, 12, 20):
            lines = ["x0: &x0 [1, 1]"] + [f"x{i}: &x{i} [{', '.join([f'*x{i - 1}'] * width)}]"
                                         for i in range(1, depth)]
            for where in ("gravity", "bodies", "zz"):
                texts[f"laughs-{width}x{depth}-{where}"] = head + "\n".join(lines) + \
                    f"\n{where}: *x{depth - 1}\n"
    for depth in (10, 20, 40):
        lines = ["m0: &m0 {a: 1, b: 2}"] + [f"m{i}: &m{i} {{<<: [*m{i - 1}, *m{i - 1}], "
                                            f"k{i}: {i}}}" for i in range(1, depth)]
        texts[f"merge-{depth}"] = head + "\n".join(lines) + "\n"
    for text in ("x: &x [*x]", "x: &x {a: *x}", "bodies: &b [{name: a, mass: 1, forces: *b}]",
                 "output: &o {file: *o}", "bodies: [&b {name: a, mass: 1, <<: *b}]"):
        texts[f"recursive-{len(texts)}"] = head + text + "\n"
    for depth in (64, 65, 100, 3000, 100_000):
        texts[f"brackets-{depth}"] = head + "gravity: " + "[" * depth + "]" * depth + "\n"
        texts[f"braces-{depth}"] = head + "gravity: " + "{a: " * depth + "1" + "}" * depth + "\n"
    for depth in (50, 65, 600, 3000):
        texts[f"block-{depth}"] = head + "".join(" " * i + f"k{i}:\n" for i in range(depth))
        texts[f"dashes-{depth}"] = head + "gravity:\n" + "".join(
            " " * (2 * i) + "-\n" for i in range(depth)) + " " * (2 * depth) + "- 1\n"
    for count in (10 ** 5, 10 ** 6, 2 * 10 ** 6):
        texts[f"flow-{count}"] = head + "input:\n  per_frame: [" + ", ".join(
            ["0"] * count) + "]\n"
        texts[f"block-list-{count}"] = head + "zz:\n" + "- 0\n" * count
    texts["per-frame-200k"] = "vrsim: 1\nduration: 1\nobserver: {}\ninput:\n  per_frame: [" \
        + ", ".join(["[0, 0]"] * 200_000) + "]\n"
    for size in (10 ** 5, 10 ** 6, 4 * 10 ** 6, 5 * 10 ** 6, 33 * 10 ** 6):
        texts[f"string-{size}"] = head + "description: " + "x" * size + "\n"
        texts[f"key-{size}"] = head + "y" * min(size, 10 ** 6) + ": 1\n"
    texts["many-keys"] = head + "".join(f"k{i}: {i}\n" for i in range(300_000))
    texts["many-bodies-100k"] = "vrsim: 1\nduration: 0.01\ndt: 0.01\nframe_rate: 100\n" \
        "bodies:\n" + "".join(f"  - {{name: b{i}, mass: 1}}\n" for i in range(100_000))
    for snippet in ["!!python/object/apply:os.system ['touch pwned']", "!!binary aGVsbG8=",
                    "!!float x", "!!int " + "9" * 5000, "!!set {a, b}", "!!omap [a: 1]",
                    "!!timestamp 2001-13-45", "!custom x", "\x00", "\x07", "\ufeff",
                    "\u2028", "\x1b[2J", "\r", "-.inf", ".nan", "1e400", "0x1F", "~"]:
        texts[f"snippet-{snippet.encode('unicode_escape').decode()[:20]}"] = \
            head + "name: " + snippet + "\n"
        texts[f"value-{snippet.encode('unicode_escape').decode()[:20]}"] = \
            head + "gravity: [0, " + snippet + ", 0]\n"
    texts["name-escape"] = head + "name: \"\\e]0;pwned\\a\\e[2J\\r\"\nbodies: [{name: a, mass: 1}]\n"
    texts["bom"] = "\ufeff" + head
    texts["crlf"] = head.replace("\n", "\r\n")
    texts["tabs"] = head + "gravity:\t[0, -1, 0]\n"
    texts["multi-doc"] = head + "---\n" + head
    texts["empty"] = ""
    texts["comment-only"] = "# nothing\n"
    texts["list-doc"] = "- 1\n- 2\n"
    texts["scalar-doc"] = "vrsim\n"
    cases = [Case("yaml", name, {"scene.yaml": text.encode("utf-8", "surrogatepass")},
                  VALIDATE_RUN) for name, text in texts.items()]
    junk = [bytes(range(256)), b"\xff\xfe" + "vrsim: 1".encode("utf-16-le"), b"\x00" * 1000,
            b"\xc3\x28", junk_bytes(4096), b"vrsim: 1\nduration: 1\nname: \xe9\n"]
    cases += [Case("yaml", f"binary-{i}", {"scene.yaml": data}, VALIDATE_RUN)
              for i, data in enumerate(junk)]
    return cases


def chains_cases() -> list[Case]:
    cases = []
    for n in (10, 63, 64, 65, 100, 500, 2000, 5000):
        bodies = [{"name": "b0", "type": "kinematic", "drive": {"speed": 1}}] + [
            {"name": f"b{i}", "type": "kinematic", "parent": f"b{i - 1}",
             "position": [0.1, 0, 0], "keyframes": {"orientation": {
                 "times": [0, 1], "euler_deg": [[0, 0, 0], [0, 90, 0]]}}} for i in range(1, n)]
        doc = {"vrsim": 1, "duration": 0.05, "frame_rate": 100, "dt": 0.01, "bodies": bodies}
        cases.append(Case("chains", f"chain-{n}", {"scene.yaml": dump(doc)},
                          VALIDATE_RUN + [["run", "scene.yaml", "-q", "-o", "out.mcap"]]))
        rev = {"vrsim": 1, "duration": 0.05, "frame_rate": 100, "dt": 0.01,
               "bodies": list(reversed(bodies))}
        cases.append(Case("chains", f"chain-reversed-{n}", {"scene.yaml": dump(rev)},
                          VALIDATE_RUN))
        cyc = copy.deepcopy(bodies)
        cyc[0]["parent"] = f"b{n - 1}"
        del cyc[0]["drive"]
        cases.append(Case("chains", f"cycle-{n}", {"scene.yaml": dump(
            {"vrsim": 1, "duration": 0.05, "bodies": cyc})}, VALIDATE_RUN))
    for n in (1000, 10_000, 50_000):
        bodies = [{"name": "root", "type": "kinematic", "drive": {"speed": 1, "yaw_rate_deg": 10}}] \
            + [{"name": f"c{i}", "type": "kinematic", "parent": "root", "position": [i, 0, 0]}
               for i in range(n)]
        cases.append(Case("chains", f"wide-{n}", {"scene.yaml": dump(
            {"vrsim": 1, "duration": 0.05, "frame_rate": 100, "dt": 0.01, "bodies": bodies})},
            VALIDATE_RUN))
    cases.append(Case("chains", "self-parent", {"scene.yaml": b"vrsim: 1\nduration: 1\n"
                      b"bodies: [{name: a, type: kinematic, parent: a}]\n"}, VALIDATE_RUN))
    cases.append(Case("chains", "parent-dynamic", {"scene.yaml": b"vrsim: 1\nduration: 1\n"
                      b"bodies: [{name: a, mass: 1}, {name: b, mass: 1, parent: a}]\n"},
                      VALIDATE_RUN))
    cases.append(Case("chains", "springs-chain-2000", {"scene.yaml": dump(
        {"vrsim": 1, "duration": 0.05, "frame_rate": 100, "dt": 0.01,
         "bodies": [{"name": f"p{i}", "mass": 1} for i in range(2000)],
         "springs": [{"body": f"p{i}", "to": f"p{i + 1}", "stiffness": 10}
                     for i in range(1999)]})}, VALIDATE_RUN))
    return cases


SIMPLE = b"vrsim: 1\nduration: 0.05\ndt: 0.01\nframe_rate: 100\nbodies: [{name: a, mass: 1}]\n"
OBSERVED = (b"vrsim: 1\nduration: 0.05\ndt: 0.01\nframe_rate: 100\nobserver: {}\n"
            b"input: {%s: %s}\n")


def files_cases() -> list[Case]:
    cases = []
    c = lambda name, files, commands, allowed=(): cases.append(  # noqa: E731
        Case("files", name, files, commands, allowed))
    # the scene itself
    c("scene-fifo", {"scene.yaml": ("fifo",)}, [["validate", "scene.yaml"], RUN])
    c("scene-dev-zero", {}, [["validate", "/dev/zero"], ["run", "/dev/zero", "-q"]])
    c("scene-dev-null", {}, [["validate", "/dev/null"], ["run", "/dev/null", "-q"]])
    c("scene-dev-urandom", {}, [["validate", "/dev/urandom"]])
    c("scene-dev-stdin", {}, [["validate", "/dev/stdin"]])
    c("scene-proc", {}, [["validate", "/proc/self/status"]])
    c("scene-dir", {"scene.yaml": ("dir",)}, [["validate", "scene.yaml"], RUN])
    c("scene-dot", {}, [["validate", "."], ["run", ".", "-q"]])
    c("scene-link-loop", {"scene.yaml": ("link", "scene.yaml")}, VALIDATE_RUN)
    c("scene-dangling", {"scene.yaml": ("link", "nowhere")}, VALIDATE_RUN)
    c("scene-link-fifo", {"f": ("fifo",), "scene.yaml": ("link", "f")}, VALIDATE_RUN)
    c("scene-missing", {}, VALIDATE_RUN)
    c("scene-empty", {"scene.yaml": b""}, VALIDATE_RUN)
    c("scene-nul-name", {}, [["validate", "a\udc80b.yaml"]])
    c("scene-long-name", {}, [["validate", "s" * 5000 + ".yaml"]])
    c("scene-unreadable", {"scene.yaml": ("chmod0", SIMPLE)}, VALIDATE_RUN)
    c("scene-huge", {"scene.yaml": ("sparse", 40 * MB)}, VALIDATE_RUN)
    # input files of the observer
    for key in ("file", "tracker", "replay"):
        for kind, files in (("fifo", {"in.x": ("fifo",)}), ("dir", {"in.x": ("dir",)}),
                            ("dev-zero", {"in.x": ("link", "/dev/zero")}),
                            ("dev-null", {"in.x": ("link", "/dev/null")}),
                            ("empty", {"in.x": b""}), ("junk", {"in.x": junk_bytes(2000)}),
                            ("missing", {}), ("loop", {"in.x": ("link", "in.x")}),
                            ("huge", {"in.x": ("sparse", 100 * MB)}),
                            ("header-only", {"in.x": b"t,alpha,beta\n"}),
                            ("nan", {"in.x": b"t,alpha,beta\n0,nan,0\n"}),
                            ("long-line", {"in.x": b"t,alpha,beta\n" + b"1" * 10 ** 6 + b"\n"})):
            mode = b"tracked" if key == "tracker" else b"walk"
            text = OBSERVED.replace(b"observer: {}", b"observer: {mode: %s}" % mode) % (
                key.encode(), b"in.x")
            c(f"input-{key}-{kind}", {"scene.yaml": text, **files}, VALIDATE_RUN)
    # mesh files of odd kinds
    for kind, files in (("fifo", {"m.stl": ("fifo",)}), ("dir", {"m.stl": ("dir",)}),
                        ("dev-zero", {"m.stl": ("link", "/dev/zero")}),
                        ("dev-urandom", {"m.stl": ("link", "/dev/urandom")}),
                        ("huge", {"m.stl": ("sparse", 200 * MB)}),
                        ("loop", {"m.stl": ("link", "m.stl")})):
        for collide in (b"", b"collision: {}\n"):
            text = (b"vrsim: 1\nduration: 0.05\ndt: 0.01\nframe_rate: 100\n" + collide +
                    b"bodies: [{name: m, density: 1, shape: {type: mesh, file: m.stl}}]\n")
            c(f"mesh-{kind}-{'collide' if collide else 'none'}", {"scene.yaml": text, **files},
              VALIDATE_RUN + [["mass-properties", "scene.yaml"],
                              ["collision-proxies", "scene.yaml"]])
    # outputs of odd kinds, from the scene and from -o
    outputs = {"fifo": ("fifo",), "dir": ("dir",), "link-file": ("link", "victim.csv"),
               "link-dev-null": ("link", "/dev/null"), "dangling": ("link", "nowhere.csv"),
               "link-loop": ("link", "out.csv")}
    for kind, entry in outputs.items():
        for fmt in ("csv", "mcap", "tum"):
            text = SIMPLE + f"output: {{file: out.csv, format: {fmt}}}\n".encode()
            c(f"output-scene-{kind}-{fmt}", {"scene.yaml": text, "out.csv": entry,
                                             "victim.csv": b"victim\n"}, VALIDATE_RUN)
            c(f"output-cli-{kind}-{fmt}", {"scene.yaml": SIMPLE, "out.csv": entry,
                                           "victim.csv": b"victim\n"},
              [["run", "scene.yaml", "-q", "-o", "out.csv", "--format", fmt]])
    for device in ("/dev/null", "/dev/full", "/dev/stdout", "/dev/zero", "/dev/tty",
                   "/proc/self/status", "/", "/tmp"):
        for fmt in ("csv", "mcap", "tum"):
            c(f"output-device-{device}-{fmt}", {"scene.yaml": SIMPLE},
              [["run", "scene.yaml", "-q", "-o", device, "--format", fmt]])
    names = ["a" * 300 + ".csv", "a" * 236 + ".csv", "a" * 250 + ".csv", "\x1b[2J.csv",
             "new\nline.csv", "-", "--", "-x.csv", " .csv", "~/x.csv", "nodir/x.csv",
             "x.csv/y.csv", "é.csv", "\udcff.csv", "...csv", ".csv", "x.CSV", "x.csv.gz",
             "x.mcap.csv", "x.tum", "x."]
    for name in names:
        c(f"output-name-{name.encode('unicode_escape', 'surrogateescape')[:30]!r}",
          {"scene.yaml": SIMPLE}, [["run", "scene.yaml", "-q", "-o", name]])
    scene_outputs = ["../x.csv", "/tmp/vrsim-corpus-outside.csv", ".", "..", "out/",
                     "a" * 300 + ".csv", "scene.yaml", "x\x1b.csv", "sub/../../x.csv",
                     "/dev/null", "/dev/stdout", "-"]
    for target in scene_outputs:
        for fmt in ("csv", "tum"):
            text = SIMPLE + f"output: {{file: {json.dumps(target)}, format: {fmt}}}\n".encode()
            c(f"scene-output-{target[:20]!r}-{fmt}", {"scene.yaml": text}, VALIDATE_RUN)
    for kind in ("fifo", "dir-with-files", "dev-null"):
        files = {"scene.yaml": SIMPLE + b"output: {file: out.csv, frames: {dir: f, "
                                        b"width: 16, height: 16}}\n"}
        files["f"] = {"fifo": ("fifo",), "dir-with-files": ("dir",),
                      "dev-null": ("link", "/dev/null")}[kind]
        c(f"frames-dir-{kind}", files, VALIDATE_RUN)
    # info and compare on odd files
    for kind, files in (("fifo", {"t.csv": ("fifo",)}), ("dev-zero", {"t.csv": ("link", "/dev/zero")}),
                        ("dir-empty", {"t.csv": ("dir",)}), ("junk-mcap", {"t.mcap": junk_bytes(5000)}),
                        ("junk-gz", {"t.csv.gz": junk_bytes(5000)}),
                        ("gz-bomb", {"t.csv.gz": ("gzbomb", 200 * MB)}),
                        ("huge-csv", {"t.csv": ("bigcsv", 2_000_000)}),
                        ("escape-names", {"t.csv": ("t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,"
                                                    "wy,wz\n0,\x1b]0;pwned\x07\x1b[2J\r,0,0,0,1,0,"
                                                    "0,0,0,0,0,0,0,0\n").encode()})):
        name = next(iter(files))
        c(f"tool-{kind}", files, [["info", name], ["compare", name, name]])
    return cases


def limits_cases() -> list[Case]:
    cases = []
    for it, pit in ((1000, 1000), (100, 100), (1000, 0), (0, 1000)):
        bodies = [{"name": f"b{i}", "mass": 1, "shape": {"type": "box", "size": [1, 1, 1]},
                   "position": [0, 1.01 * i + 0.5, 0]} for i in range(30)]
        bodies.append({"name": "floor", "type": "static", "shape": {"type": "plane",
                                                                    "normal": [0, 1, 0]}})
        for impacts in ("located", "stepped"):
            doc = {"vrsim": 1, "duration": 0.05, "frame_rate": 100, "dt": 0.01,
                   "collision": {"iterations": it, "position_iterations": pit,
                                 "impacts": impacts}, "bodies": bodies}
            cases.append(Case("limits", f"iterations-{it}-{pit}-{impacts}",
                              {"scene.yaml": dump(doc)},
                              VALIDATE_RUN + [["run", "scene.yaml", "-q", "-o", "out.mcap"]]))
    for w, h in ((8192, 8192), (8192, 16), (4096, 4096), (2048, 2048), (16, 8192), (8193, 16)):
        doc = {"vrsim": 1, "duration": 0.02, "frame_rate": 100, "dt": 0.01,
               "bodies": [{"name": "a", "mass": 1, "shape": {"type": "sphere", "radius": 1}}],
               "output": {"frames": {"dir": "f", "width": w, "height": h}}}
        cases.append(Case("limits", f"frames-{w}x{h}", {"scene.yaml": dump(doc)},
                          VALIDATE_RUN + [["run", "scene.yaml", "-q", "--frames", "g",
                                           "--video", "v.mp4"]]))
    for count in (10_000, 100_000):
        for n in (1, 2, 10):
            emitters = [{"name": f"e{k}", "count": count, "rate": 1000, "speed": 1, "mass": 1}
                        for k in range(n)]
            doc = {"vrsim": 1, "duration": 0.02, "frame_rate": 100, "dt": 0.01,
                   "emitters": emitters}
            for fmt in ("csv", "mcap"):
                cases.append(Case("limits", f"emitters-{n}x{count}-{fmt}",
                                  {"scene.yaml": dump(doc)},
                                  [["validate", "scene.yaml"],
                                   ["run", "scene.yaml", "-q", "-o", f"out.{fmt}"]]))
            doc_c = copy.deepcopy(doc)
            doc_c["collision"] = {}
            cases.append(Case("limits", f"emitters-{n}x{count}-collide",
                              {"scene.yaml": dump(doc_c)},
                              [["validate", "scene.yaml"], ["run", "scene.yaml", "-q"]]))
    for n in (1000, 10_000):
        bodies = [{"name": f"b{i}", "mass": 1, "shape": {"type": "sphere", "radius": 0.4},
                   "position": [i % 30, 1 + i // 900, (i // 30) % 30]} for i in range(n)]
        for impacts in ("located", "stepped"):
            doc = {"vrsim": 1, "duration": 0.02, "frame_rate": 100, "dt": 0.01,
                   "collision": {"impacts": impacts}, "bodies": bodies}
            cases.append(Case("limits", f"spheres-{n}-{impacts}", {"scene.yaml": dump(doc)},
                              [["validate", "scene.yaml"], ["run", "scene.yaml", "-q"]]))
    for steps in (10 ** 6, 10 ** 7):
        doc = {"vrsim": 1, "duration": steps * 1e-6, "dt": 1e-6, "frame_rate": 1000,
               "bodies": [{"name": "a", "mass": 1}]}
        cases.append(Case("limits", f"steps-{steps}", {"scene.yaml": dump(doc)},
                          [["validate", "scene.yaml"]]))
    for count in (1000, 10_000, 100_000):
        doc = {"vrsim": 1, "duration": 0.02, "frame_rate": 100, "dt": 0.01,
               "bodies": [{"name": "k", "type": "kinematic", "keyframes": {"position": {
                   "times": [i * 1e-3 for i in range(count)],
                   "values": [[i, 0, 0] for i in range(count)],
                   "interpolation": "catmull-rom", "arc_length": True}}}]}
        cases.append(Case("limits", f"keys-{count}", {"scene.yaml": dump(doc)}, VALIDATE_RUN))
    return cases


INTEGRATORS = ("euler", "symplectic-euler", "verlet", "rk4", "dopri5")


def warm_scenes() -> dict:
    """One scene of each kind whose kernels numba compiles on first use (--warm): the
    bases, the base with each integrator, located and stepped, and the limits' stepped
    stack and spheres. Run once before the cases so that a case's time is its own and not
    a first compile's (the snapshot is a new folder, so the kernel cache is cold for it)."""
    runnable = copy.deepcopy(BASE)
    scenes = {name: dump(base) for name, base in BASES.items()}
    for integ in INTEGRATORS:
        for impacts in ("located", "stepped"):
            doc = copy.deepcopy(runnable)
            doc["integrator"] = integ
            doc["collision"]["impacts"] = impacts
            scenes[f"base-{integ}-{impacts}"] = dump(doc)
    boxes = [{"name": f"b{i}", "mass": 1, "shape": {"type": "box", "size": [1, 1, 1]},
              "position": [0, 1.01 * i + 0.5, 0]} for i in range(30)]
    boxes.append({"name": "floor", "type": "static", "shape": {"type": "plane",
                                                               "normal": [0, 1, 0]}})
    spheres = [{"name": f"s{i}", "mass": 1, "shape": {"type": "sphere", "radius": 0.4},
                "position": [i % 10, 1 + i // 100, (i // 10) % 10]} for i in range(200)]
    for name, bodies in (("boxes-stepped", boxes), ("spheres-stepped", spheres)):
        scenes[name] = dump({"vrsim": 1, "duration": 0.02, "frame_rate": 100, "dt": 0.01,
                             "collision": {"impacts": "stepped"}, "bodies": bodies})
    return scenes


def warm(root: Path, timeout: float) -> list:
    """Run each warm scene once (spawned, one at a time): [{name, code, wall_s}]."""
    done = []
    for name, text in warm_scenes().items():
        if STOP.is_set():
            break
        folder = root / "warm" / name / "w"
        folder.mkdir(parents=True)
        materialise(folder, with_mesh({"scene.yaml": text}))
        result = spawn_invocation(folder, ["run", "scene.yaml", "-q"], timeout)
        done.append({"name": name, "code": result["code"], "wall_s": result["wall_s"]})
        print(f"warm {name}: code {result['code']}, {result['wall_s']:.1f} s", flush=True)
    return done


# ----------------------------------------------------------------------------- outputs


FRAMES_SCENE = (b"vrsim: 1\nduration: 0.5\nframe_rate: 20\nbodies:\n"
                b"  - {name: ball, type: static, shape: {type: sphere, radius: 0.3}, "
                b"position: [0, 1, 0]}\n"
                b"output:\n  frames: {every: 3, width: 64, height: 48}\n")
LONG = (b"vrsim: 1\nduration: 20\ndt: 0.01\nframe_rate: 50\n"
        b"bodies: [{name: a, mass: 1, velocity: [1, 2, 0]}, {name: b, mass: 2}]\n")
PNG_OF_THEIRS = b"\x89PNG\r\n\x1a\n" + b"their own image" * 20
TARGETS = ("out", "out.csv", "out.mcap", "renders", "video.mp4", "video.gif", "cache", "cache/")
WARM_CACHE = None  # the kernel cache this corpus's processes use (set by main)


def outputs_cases() -> list[Case]:
    cases = []

    def c(name, files, commands, allowed=(), targets=TARGETS, **kw):
        cases.append(Case("outputs", name, files, commands, allowed, targets=targets, **kw))

    # frames folders: what is in them, what else the run writes
    folders = {
        "missing": {}, "empty": {"renders": ("emptydir",)},
        "notes": {"renders/notes.txt": b"mine\n"},
        "their-frames": {"renders/frame_000003.png": PNG_OF_THEIRS,
                         "renders/frame_000099.png": PNG_OF_THEIRS},
        "their-frame-0": {"renders/frame_000000.png": PNG_OF_THEIRS},
        "frame-fifo": {"renders/frame_000001.png": ("fifo",)},
        "frame-link": {"elsewhere.png": PNG_OF_THEIRS,
                       "renders/frame_000002.png": ("link", "../elsewhere.png")},
        "frame-dangling": {"renders/frame_000002.png": ("link", "nowhere.png")},
        "frame-dir": {"renders/frame_000000.png": ("dir",)},
        "frame-dev-null": {"renders/frame_000000.png": ("link", "/dev/null")},
        "hidden": {"renders/.DS_Store": b"x"},
        "subfolder": {"renders/old": ("dir",)},
        "vrsim-partial": {"renders/.frame_000001.png.abcd1234.partial": b"half"},
        "folder-link": {"real": ("emptydir",), "renders": ("link", "real")},
        "folder-file": {"renders": b"a file\n"},
        "folder-fifo": {"renders": ("fifo",)},
        "folder-dev-null": {"renders": ("link", "/dev/null")},
        "scene-inside": {"renders/scene.yaml": FRAMES_SCENE},
    }
    for fname, files in folders.items():
        for vname, video in (("", []), ("mp4", ["--video", "video.mp4"]),
                             ("gif", ["--video", "video.gif"])):
            for oname, out in (("", []), ("csv", ["-o", "out.csv"])):
                c(f"frames-{fname}-{vname}-{oname}", {"scene.yaml": FRAMES_SCENE, **files},
                  [["run", "scene.yaml", "-q", "--frames", "renders", *video, *out]])
    for where in ("/sys/vrsim-frames", "/proc/self/vrsim", "a/b/c/renders", "r" * 300,
                  "renders\udc80"):
        c(f"frames-at-{where[:20]}", {"scene.yaml": FRAMES_SCENE},
          [["run", "scene.yaml", "-q", "--frames", where, "-o", "out.csv"]],
          targets=TARGETS + ("a", where))
    # the frames of an earlier run of the same scene are the run's to replace and remove
    c("frames-rerun", {"scene.yaml": FRAMES_SCENE},
      [["run", "scene.yaml", "-q", "--frames", "renders"]] * 2, targets=("renders", "renders/"))
    c("frames-rerun-shorter", {"scene.yaml": FRAMES_SCENE},
      [["run", "scene.yaml", "-q", "--frames", "renders", "--duration", "1"],
       ["run", "scene.yaml", "-q", "--frames", "renders"]], targets=("renders", "renders/"))
    # video targets
    kinds = {"absent": {}, "previous": b"the previous video", "fifo": ("fifo",),
             "dir": ("dir",), "link-file": ("link", "elsewhere.bin"),
             "link-dev-null": ("link", "/dev/null"), "dangling": ("link", "nowhere")}
    for suffix in ("mp4", "gif"):
        for kname, kind in kinds.items():
            files = {"scene.yaml": FRAMES_SCENE, "elsewhere.bin": b"theirs"}
            if kname != "absent":
                files[f"video.{suffix}"] = kind
            c(f"video-{kname}-{suffix}", files,
              [["run", "scene.yaml", "-q", "--frames", "renders", "--video",
                f"video.{suffix}", "-o", "out.csv"]])
        for where in ("/sys/v", "/dev/full", "missing/v", "v" * 300):
            c(f"video-at-{where[:12]}-{suffix}", {"scene.yaml": FRAMES_SCENE},
              [["run", "scene.yaml", "-q", "--frames", "renders", "--video",
                f"{where}.{suffix}"]])
    c("video-avi", {"scene.yaml": FRAMES_SCENE},
      [["run", "scene.yaml", "-q", "--frames", "renders", "--video", "video.avi"]])
    # standard streams closed before the interpreter starts
    commands = {"validate": ["validate", "scene.yaml"], "run-csv": ["run", "scene.yaml",
                "-o", "out.csv"], "run-stdout": ["run", "scene.yaml", "-o", "-"],
                "run-stdout-mcap": ["run", "scene.yaml", "-o", "-", "--format", "mcap"],
                "run-json": ["run", "scene.yaml", "--json", "-o", "out.csv"],
                "run-bare": ["run", "scene.yaml"], "schema": ["schema"],
                "run-frames": ["run", "frames.yaml", "--frames", "renders", "-o", "out.csv"],
                "info": ["info", "scene.yaml"], "cache": ["cache"]}
    for closed in ((0,), (1,), (2,), (1, 2), (0, 1, 2)):
        for cname, command in commands.items():
            c(f"closed-{''.join(map(str, closed))}-{cname}",
              {"scene.yaml": SIMPLE, "frames.yaml": FRAMES_SCENE}, [command],
              allowed=(0, 1, 2), close=closed)
    # a full disk for every writer (RLIMIT_FSIZE: EFBIG past the limit)
    writers = {"csv": ["-o", "out.csv"], "mcap": ["-o", "out.mcap"],
               "tum": ["-o", "out", "--format", "tum"], "stdout": ["-o", "-"],
               "frames": ["--frames", "renders", "--duration", "0.5"],
               "mp4": ["--frames", "renders", "--duration", "0.5", "--video", "video.mp4"],
               "gif": ["--frames", "renders", "--duration", "0.5", "--video", "video.gif"]}
    for wname, extra in writers.items():
        scene = FRAMES_SCENE if wname in ("frames", "mp4", "gif") else LONG
        for limit in (0, 1, 100, 1000, 5000, 20_000, 100_000):
            c(f"full-{wname}-{limit}", {"scene.yaml": scene, "out.csv": b"previous\n"},
              [["run", "scene.yaml", "-q", *extra]], fsize=limit)
    # the kernel cache: damaged, a file, unwritable, full (VRSIM_CACHE_DIR of the case)
    for how in ("truncated", "empty", "random"):
        for suffix in (".nbc", ".nbi"):
            c(f"cache-{how}{suffix}", {"scene.yaml": SIMPLE, "cache": ("cachecopy", how,
                                                                      suffix)},
              [["run", "scene.yaml", "-q", "-o", "out.csv"]] * 2,
              env={"VRSIM_CACHE_DIR": "{d}/cache"})
    c("cache-a-file", {"scene.yaml": SIMPLE, "cache": b"not a folder\n"},
      [["run", "scene.yaml", "-q", "-o", "out.csv"]], env={"VRSIM_CACHE_DIR": "{d}/cache"},
      targets=("out.csv",))  # the file named like the cache stays as it was
    c("cache-in-sys", {"scene.yaml": SIMPLE}, [["run", "scene.yaml", "-q", "-o", "out.csv"]],
      env={"VRSIM_CACHE_DIR": "/sys/vrsim-cache"})
    c("cache-full", {"scene.yaml": SIMPLE}, [["run", "scene.yaml", "-q", "-o", "out.csv"]],
      env={"VRSIM_CACHE_DIR": "{d}/cache"}, fsize=2000)
    c("cache-clear", {"scene.yaml": SIMPLE, "cache": ("cachecopy", "truncated", ".none"),
                      "cache/README": b"theirs\n"},
      [["cache", "--clear"], ["cache"]], env={"VRSIM_CACHE_DIR": "{d}/cache"},
      targets=TARGETS[:-1] + ("cache/src-",))
    return cases


CATEGORIES = {"types": types_cases, "numbers": numbers_cases, "meshes": meshes_cases,
              "yaml": yaml_cases, "chains": chains_cases, "files": files_cases,
              "limits": limits_cases, "outputs": outputs_cases}

# ----------------------------------------------------------------------------- running

ALLOWED = {"validate": (0, 2), "run": (0, 1, 2), "info": (0, 2), "compare": (0, 1, 2),
           "cache": (0,), "schema": (0,),
           "mass-properties": (0, 2), "collision-proxies": (0, 2)}


def materialise(folder: Path, files: dict) -> None:
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif content[0] == "fifo":
            os.mkfifo(path)
        elif content[0] == "dir":
            path.mkdir()
            (path / "inside.txt").write_text("not vrsim's\n")
        elif content[0] == "emptydir":
            path.mkdir(exist_ok=True)
        elif content[0] == "cachecopy":  # this corpus's warm kernel cache, then damaged
            shutil.copytree(WARM_CACHE, path, symlinks=True)
            for victim in sorted(path.rglob(f"*{content[2]}")):  # every entry
                data = victim.read_bytes()
                victim.write_bytes({"truncated": data[:len(data) // 2], "empty": b"",
                                    "random": os.urandom(max(64, len(data)))}[content[1]])
        elif content[0] == "link":
            path.symlink_to(content[1])
        elif content[0] == "chmod0":
            path.write_bytes(content[1])
            path.chmod(0)
        elif content[0] == "sparse":
            with open(path, "wb") as f:
                f.truncate(content[1])
        elif content[0] == "bigmesh":
            path.write_bytes(big_mesh(content[1]))
        elif content[0] == "gzbomb":
            import gzip
            with gzip.open(path, "wb") as f:
                header = b"t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n"
                f.write(header)
                row = b"0.0,a,0,0,0,1,0,0,0,0,0,0,0,0,0\n"
                chunk = row * (MB // len(row))
                for _ in range(content[1] // MB):
                    f.write(chunk)
        elif content[0] == "bigcsv":
            with open(path, "wb") as f:
                f.write(b"t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n")
                rows = b"".join(f"{i * 1e-3!r},e{i % 50},1.5,2.5,3.5,1,0,0,0,0.1,0.2,0.3,0,0,0\n"
                                .encode() for i in range(10_000))
                for _ in range(content[1] // 10_000):
                    f.write(rows)


SNAPSHOT: Path | None = None  # a copy of vrsim_cli taken at start (see main)
STOP = threading.Event()  # set on SIGINT/SIGTERM: no new invocation starts
RUNNING: dict = {}  # thread id -> process group of the invocation it waits for


def child_env() -> dict:
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    if SNAPSHOT is not None:  # the code as it was when the corpus started, edits or not
        env["PYTHONPATH"] = str(SNAPSHOT)
    return env


def _preexec(close: tuple, fsize: int):
    """In the child, before the interpreter starts: closed descriptors (as the shell's
    `2>&-`), a file-size limit (as a full disk: EFBIG instead of SIGXFSZ)."""
    def run():
        if fsize >= 0:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        for fd in close:
            os.close(fd)
    return run if close or fsize >= 0 else None


def spawn_invocation(folder: Path, args: list, timeout: float, opts=None) -> dict:
    """One `python -m vrsim_cli ARGS` in `folder` as a new process. `opts`: the case's
    close, fsize and env (see Case)."""
    opts = opts or {}
    start = time.perf_counter()
    # /usr/bin/time reports the child's own peak RSS; wait4 from this (large) process
    # would report at least this process's size (Linux carries it over through fork)
    fd, rss_name = tempfile.mkstemp(prefix="rss-", dir=folder.parent.parent)
    os.close(fd)  # (it leaked one descriptor per invocation)
    rss_file = Path(rss_name)
    timer = ["/usr/bin/time", "-f", "%M", "-o", str(rss_file)] \
        if os.path.exists("/usr/bin/time") else []
    if opts.get("close") or opts.get("fsize", -1) >= 0:
        timer = []  # time's own report would go through a closed or limited descriptor
    env = child_env()
    env.update({k: v.replace("{d}", str(folder)) for k, v in opts.get("env", {}).items()})
    proc = subprocess.Popen([*timer, sys.executable, "-m", "vrsim_cli", *args], cwd=folder,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=_preexec(tuple(opts.get("close", ())),
                                                opts.get("fsize", -1)))
    RUNNING[threading.get_ident()] = proc.pid
    hang = False
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        hang = True
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
    finally:
        RUNNING.pop(threading.get_ident(), None)
    wall = time.perf_counter() - start
    rss = None
    try:
        rss = round(int(rss_file.read_text().split()[-1]) / 1024, 1)  # KB -> MB
    except (OSError, ValueError, IndexError):
        pass
    code = proc.returncode
    if timer and not hang:  # time exits with the child's code; a signal shows as 128 + n
        text = rss_file.read_text() if rss_file.exists() else ""
        if "terminated by signal" in text:
            code = -int(text.split("terminated by signal")[1].split()[0].strip("\n"))
    rss_file.unlink(missing_ok=True)
    return {"code": code, "wall_s": round(wall, 3), "hang": hang, "err": err,
            "stdout_bytes": len(out), "rss_mb": rss}


class ForkServer:
    """A tests/hostile/forkserver.py process (one per worker thread): it has imported what
    an invocation imports and forks a child per invocation (see that file)."""

    def __init__(self, root: Path):
        self.root = root
        self.proc = None
        self.info = None

    def start(self) -> None:
        log = open(self.root / f"forkserver-{threading.get_ident()}.log", "ab")
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name(
            "forkserver.py"))], cwd=self.root, env=child_env(), stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=log, start_new_session=True)
        log.close()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the fork server did not start: see {log.name}")
        self.info = json.loads(line)

    def run(self, folder: Path, args: list, timeout: float) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        request = json.dumps({"cwd": str(folder), "args": args, "timeout": timeout})
        self.proc.stdin.write(request.encode() + b"\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()  # {"pid": the child's}, then the answer
        if line:
            RUNNING[threading.get_ident()] = json.loads(line)["pid"]
            line = self.proc.stdout.readline()
            RUNNING.pop(threading.get_ident(), None)
        if not line:  # the server died (it never runs vrsim code itself): say so, respawn
            self.proc.wait()
            raise RuntimeError(f"fork server died with {self.proc.returncode}")
        answer = json.loads(line)
        answer["err"] = base64.b64decode(answer.pop("stderr_b64"))
        return answer

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


SERVERS: dict = {}  # thread id -> ForkServer (fork mode)


def fork_invocation(folder: Path, args: list, timeout: float) -> dict:
    server = SERVERS.get(threading.get_ident())
    if server is None:
        server = SERVERS[threading.get_ident()] = ForkServer(folder.parent.parent.parent)
    try:
        return server.run(folder, args, timeout)
    except RuntimeError as exc:  # counted apart, then the invocation is run by spawn
        result = spawn_invocation(folder, args, timeout)
        result["fallback"] = str(exc)
        return result


def run_invocation(folder: Path, args: list, timeout: float, fork: bool = False,
                   opts=None) -> dict:
    """One `vrsim ARGS` in `folder`, spawned or forked (spawned whenever the case closes
    descriptors, limits file sizes or sets variables): exit code, time, peak RSS (MB),
    traceback, hang."""
    if opts:
        raw = spawn_invocation(folder, args, timeout, opts)
    else:
        raw = (fork_invocation if fork else spawn_invocation)(folder, args, timeout)
    err = raw.pop("err")
    return {"args": args, **raw, "traceback": b"Traceback (most recent call last)" in err,
            "stderr": err[-2000:].decode("utf-8", "replace")}


def _tree(folder: Path) -> dict:
    """relative name -> (kind, content or link target) of everything under `folder`."""
    import stat as st

    out = {}
    for path in folder.rglob("*"):
        name = path.relative_to(folder).as_posix()
        try:
            mode = os.lstat(path).st_mode
            if st.S_ISLNK(mode):
                out[name] = ("link", os.readlink(path))
            elif st.S_ISREG(mode):
                out[name] = ("file", path.read_bytes())
            else:
                out[name] = ("dir" if st.S_ISDIR(mode) else "special", None)
        except OSError:
            out[name] = ("gone", None)
    return out


def run_case(case: Case, root: Path, timeout: float, fork: bool = False) -> Case:
    if STOP.is_set():
        return case
    folder = Path(tempfile.mkdtemp(prefix="case-", dir=root / "cases"))
    work = folder / "w"
    work.mkdir()
    try:
        materialise(work, case.files)
        before = sorted(p.name for p in folder.iterdir())
        opts = {k: getattr(case, k) for k in ("close", "fsize", "env")
                if getattr(case, k) not in ((), -1, {})}
        for args in case.commands:
            if STOP.is_set():
                case.results = []  # a case is reported whole or not at all
                return case
            made = _tree(work) if case.targets is not None else None
            result = run_invocation(work, args, timeout, fork, opts)
            if STOP.is_set():  # killed by the corpus's own signal handler, not a finding
                case.results = []
                return case
            command = args[0]
            result["allowed"] = list(ALLOWED.get(command, (0, 1, 2)))
            result["wrong_code"] = not result["hang"] and result["code"] not in result["allowed"]
            partials = [str(p) for p in work.rglob("*.partial")
                        if made is None or p.relative_to(work).as_posix() not in made]
            result["half_written"] = partials  # (a case's own .partial files are not)
            result["outside"] = sorted(p.name for p in folder.iterdir()) != before
            result["touched"], result["stray"] = [], []
            if made is not None:
                now = _tree(work)
                # a target "x" may be replaced and new files may appear under it; one
                # ending in "/" or "-" may also change what was under it before (the
                # kernel cache); a user's file inside a frames folder is not the run's
                prefix = lambda n: any(t[-1] in "/-" and n.startswith(t)  # noqa: E731
                                       for t in case.targets)
                mine = lambda n: n in case.targets or prefix(n) or any(  # noqa: E731
                    n.startswith(t + "/") for t in case.targets)
                result["touched"] = sorted(n for n in made if n not in case.targets and
                                           not prefix(n) and now.get(n) != made[n])
                result["stray"] = sorted(n for n in now if n not in made and not mine(n))
            result["spam"] = len(result["stderr"].splitlines()) > 20 if \
                len(result["stderr"]) < 2000 else result["stderr"].count("\n") > 20
            result["nan_output"] = False
            if command == "run" and result["code"] == 0:
                for out in list(work.glob("out*.csv")):
                    try:
                        text = out.read_text(errors="replace").lower()
                        result["nan_output"] = "nan" in text or "inf" in text
                    except OSError:
                        pass
            case.results.append(result)
        case.complete = True
    finally:
        for p in folder.rglob("*"):
            try:
                if p.is_dir() and not p.is_symlink():
                    p.chmod(0o755)
                elif p.exists() and not p.is_symlink():
                    p.chmod(0o644)
            except OSError:
                pass
        shutil.rmtree(folder, ignore_errors=True)
    return case


SAMPLE = {"types": 1300, "numbers": 1300}  # of ~3200 and ~3000: every key is still hit


def build(only=None, full=False) -> list[Case]:
    """The cases; the two generated categories sampled (seeded) unless `full`."""
    import random

    cases = []
    for name, make in CATEGORIES.items():
        if only and name not in only:
            continue
        made = make()
        if not full and len(made) > SAMPLE.get(name, len(made)):
            keep = set(random.Random(19).sample(range(len(made)), SAMPLE[name]))
            made = [c for i, c in enumerate(made) if i in keep]
        cases += made
    return cases


def case_keys(cases) -> list[str]:
    """A key per case, unique (a name can repeat: the occurrence is counted)."""
    seen, keys = {}, []
    for c in cases:
        base = f"{c['category'] if isinstance(c, dict) else c.category}:" \
               f"{c['name'] if isinstance(c, dict) else c.name}"
        seen[base] = seen.get(base, 0) + 1
        keys.append(f"{base}#{seen[base]}")
    return keys


def sample(cases: list[Case], n: int, seed: int = 19) -> list[Case]:
    """About n cases, the same number from each category (all of a smaller one), seeded."""
    import random

    by = {}
    for c in cases:
        by.setdefault(c.category, []).append(c)
    per = math.ceil(n / max(1, len(by)))
    keep = set()
    for category, members in by.items():
        keep |= {id(c) for c in random.Random(f"{seed}-{category}").sample(
            members, min(per, len(members)))}
    return [c for c in cases if id(c) in keep]


def write_report(path: Path, done: list, meta: dict) -> dict:
    summary = summarise(done)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({**meta, "summary": summary, "cases": [
        {"category": c.category, "name": c.name, "key": c.key, "results": c.results}
        for c in done]}, indent=1, default=str))
    os.replace(tmp, path)  # a report is whole or the previous one
    return summary


def compare_reports(a: Path, b: Path) -> int:
    """Per invocation of the cases both reports ran: do exit code, traceback, hang,
    half-written and outside agree? Prints the disagreements and the RSS of both."""
    ra, rb = (json.loads(Path(p).read_text()) for p in (a, b))
    cases_b = {c["key"]: c for c in rb["cases"]}
    keys = ("code", "traceback", "hang", "half_written", "outside", "wrong_code", "nan_output")
    total = agree = 0
    rss = []
    for ca in ra["cases"]:
        cb = cases_b.get(ca["key"])
        if cb is None:
            continue
        for x, y in zip(ca["results"], cb["results"]):
            total += 1
            diff = {k: (x[k], y[k]) for k in keys if bool(x[k]) != bool(y[k]) or
                    (k == "code" and x[k] != y[k])}
            rss.append((x.get("rss_mb") or 0, y.get("rss_mb") or 0))
            if diff:
                print(f"DIFFER {ca['key']} | {' '.join(map(str, x['args']))}: {diff}\n"
                      f"  A: {x['stderr'].strip()[-300:]!r}\n  B: {y['stderr'].strip()[-300:]!r}")
            else:
                agree += 1
    print(f"{agree} of {total} invocations agree on exit code, traceback, hang, half-written, "
          f"outside, wrong code and NaN output")
    if rss:
        print(f"peak RSS (MB): A max {max(r[0] for r in rss)}, median "
              f"{sorted(r[0] for r in rss)[len(rss) // 2]}; B max {max(r[1] for r in rss)}, "
              f"median {sorted(r[1] for r in rss)[len(rss) // 2]}")
    return 0 if agree == total else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--only", nargs="*")
    parser.add_argument("--limit", type=int)
    parser.add_argument("--match", help="only cases whose name contains this")
    parser.add_argument("--sample", type=int, help="about N cases, as many from each category "
                        "(seeded)")
    parser.add_argument("--report", type=Path, help="written every 100 cases and at the end, "
                        "also after SIGINT/SIGTERM (with the cases done)")
    parser.add_argument("--resume", type=Path, help="an earlier report: its complete cases are "
                        "kept, not run again")
    parser.add_argument("--list", action="store_true")
    parser.add_argument("--full", action="store_true", help="every generated case, not a "
                        "sample of the types and numbers categories")
    parser.add_argument("--fork", action="store_true", help="fork each invocation from a "
                        "server that has imported vrsim (tests/hostile/forkserver.py) instead "
                        "of spawning `python -m vrsim_cli`: same checks, ~10x faster")
    parser.add_argument("--warm", action="store_true", help="first run one scene of each "
                        "kind (warm_scenes) so that kernels are compiled before the cases")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"),
                        help="compare two reports invocation by invocation, run nothing")
    args = parser.parse_args(argv)
    if args.compare:
        return compare_reports(*args.compare)
    meta = {}

    def on_signal(signum, _frame):
        # Stop: no new invocation, the running ones killed (those cases are dropped, not
        # counted), the report written with every case done so far.
        if not STOP.is_set():
            print(f"{signal.Signals(signum).name}: stopping, writing the cases done",
                  flush=True)
        STOP.set()
        meta["interrupted"] = signal.Signals(signum).name
        for pid in list(RUNNING.values()):
            for kill in (os.killpg, os.kill):
                try:
                    kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass

    global WARM_CACHE  # what the cache cases copy and damage: the cache children use
    WARM_CACHE = Path(os.environ.get("VRSIM_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
                      or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
                      / "vrsim" / "numba")
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    cases = build(args.only, args.full)
    for case, key in zip(cases, case_keys(cases)):
        case.key = key
    if args.match:
        cases = [c for c in cases if args.match in c.name]
    if args.sample:
        cases = sample(cases, args.sample)
    if args.limit:
        cases = cases[:args.limit]
    if args.list:
        counts = {}
        for c in cases:
            counts[c.category] = counts.get(c.category, 0) + 1
        print(json.dumps(counts, indent=2), "total", len(cases),
              "invocations", sum(len(c.commands) for c in cases))
        return 0
    done = []
    meta.update({"mode": "fork" if args.fork else "spawn", "timeout_s": args.timeout,
            "jobs": args.jobs, "argv": sys.argv[1:] if argv is None else argv})
    if args.resume:
        earlier = json.loads(args.resume.read_text())
        kept = {c["key"]: c for c in earlier["cases"]}
        for case in cases:
            if case.key in kept:
                case.results = kept[case.key]["results"]
                case.complete = True
                done.append(case)
        cases = [c for c in cases if not c.complete]
        meta["resumed"] = {"from": str(args.resume), "cases": len(done),
                           "commit": earlier.get("commit")}
    root = Path(tempfile.mkdtemp(prefix="vrsim-corpus-"))
    global SNAPSHOT
    SNAPSHOT = root / "snapshot"
    shutil.copytree(REPO / "vrsim_cli", SNAPSHOT / "vrsim_cli",
                    ignore=shutil.ignore_patterns("__pycache__"))
    (root / "cases").mkdir()
    commit = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"],
                            capture_output=True, text=True).stdout.strip()
    meta["commit"] = commit
    print(f"corpus of {len(cases)} cases against vrsim_cli at {commit}, {meta['mode']} mode"
          + (f" ({len(done)} kept from {args.resume})" if args.resume else ""), flush=True)

    start = time.perf_counter()
    try:
        if STOP.is_set():  # a signal while the cases were built: report what was kept
            cases = []
        if args.warm:
            meta["warm"] = warm(root, 900.0)
            start = time.perf_counter()
        with ThreadPoolExecutor(args.jobs) as pool:
            for i, case in enumerate(pool.map(lambda c: run_case(c, root, args.timeout,
                                                                 args.fork), cases), 1):
                if not case.complete:
                    continue
                done.append(case)
                bad = [r for r in case.results if r["traceback"] or r["hang"] or
                       r["wrong_code"] or r["half_written"] or r["outside"] or
                       r.get("touched") or r.get("stray") or r.get("spam")]
                if bad:
                    r = bad[0]
                    print(f"[{i}/{len(cases)}] {case.category} {case.name!r}: "
                          f"{' '.join(map(str, r['args']))} -> code {r['code']}"
                          f"{' HANG' if r['hang'] else ''}"
                          f"{' TRACEBACK' if r['traceback'] else ''}"
                          f"{' PARTIAL' if r['half_written'] else ''}"
                          f"{' OUTSIDE' if r['outside'] else ''}"
                          f"{' TOUCHED ' + str(r['touched']) if r.get('touched') else ''}"
                          f"{' STRAY ' + str(r['stray']) if r.get('stray') else ''}"
                          f"{' SPAM' if r.get('spam') else ''}: "
                          f"{r['stderr'].strip().splitlines()[-1] if r['stderr'].strip() else ''}"
                          [:400], flush=True)
                elif i % 100 == 0:
                    print(f"[{i}/{len(cases)}] {time.perf_counter() - start:.0f} s", flush=True)
                if i % 100 == 0 and args.report:
                    write_report(args.report, done, {**meta, "partial": True})
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for server in SERVERS.values():
            meta.setdefault("fork_servers", []).append(server.info)
            server.stop()
        shutil.rmtree(root, ignore_errors=True)
        meta["wall_s"] = round(time.perf_counter() - start, 1)
        summary = summarise(done)
        if args.report:
            write_report(args.report, done, meta)
    print(json.dumps(summary, indent=2))
    if STOP.is_set():
        print(f"interrupted: {len(done)} cases reported", flush=True)
        return 128 + {"SIGINT": 2, "SIGTERM": 15}[meta["interrupted"]]
    bad = summary["total"]
    return 1 if bad["tracebacks"] or bad["hangs"] or bad["wrong_exit_codes"] or \
        bad["half_written"] or bad["outside"] or bad.get("touched") or bad.get("stray") \
        or bad.get("spam") else 0


def summarise(cases: list[Case]) -> dict:
    out = {}
    for case in cases:
        for key in (case.category, "total"):
            s = out.setdefault(key, {"cases": 0, "invocations": 0, "tracebacks": 0, "hangs": 0,
                                     "wrong_exit_codes": 0, "half_written": 0, "outside": 0,
                                     "nan_outputs": 0, "exit_codes": {}, "peak_rss_mb": 0.0,
                                     "peak_rss_case": "", "max_wall_s": 0.0,
                                     "max_wall_case": ""})
            s["cases"] += 1
            for r in case.results:
                s["invocations"] += 1
                s["fallbacks"] = s.get("fallbacks", 0) + bool(r.get("fallback"))
                s["tracebacks"] += r["traceback"]
                s["hangs"] += r["hang"]
                s["wrong_exit_codes"] += r["wrong_code"]
                s["half_written"] += bool(r["half_written"])
                s["outside"] += r["outside"]
                s["nan_outputs"] += r["nan_output"]
                for k in ("touched", "stray", "spam"):
                    s[k] = s.get(k, 0) + bool(r.get(k))
                code = str(r["code"])
                s["exit_codes"][code] = s["exit_codes"].get(code, 0) + 1
                if (r["rss_mb"] or 0) > s["peak_rss_mb"]:
                    s["peak_rss_mb"] = r["rss_mb"]
                    s["peak_rss_case"] = f"{case.name} | {' '.join(map(str, r['args']))}"[:200]
                if r["wall_s"] > s["max_wall_s"]:
                    s["max_wall_s"] = r["wall_s"]
                    s["max_wall_case"] = f"{case.name} | {' '.join(map(str, r['args']))}"[:200]
    return out


if __name__ == "__main__":
    sys.exit(main())
