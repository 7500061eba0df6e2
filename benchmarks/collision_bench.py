"""Benchmark: broad phase + narrow phase for 100 ... 10 000 spheres (not a test).

Spheres of radius 0.1-0.3 m at a constant density of 8 per m^3 (about one touching pair
per sphere) in a cube whose side grows as n^(1/3), as in a heap or a particle cloud. Per n and
method: the median of `repeats` timed calls after one warm-up call, positions fixed (the
work per call is what a physics step pays). Methods:
  grid, sap, brute  vrsim's broad phases (numpy) followed by the vectorised
                    sphere-sphere narrow phase, i.e. `collision.detect` minus bookkeeping
  fcl-tree          python-fcl's DynamicAABBTreeCollisionManager (update + collide with
                    contacts), with the objects moved by setTranslation each call
Run:  python benchmarks/collision_bench.py [--max-n 10000] [--csv out.csv]
Writes CSV (n, method, broad_ms, narrow_ms, total_ms, pairs, contacts) to stdout or a file.
"""

from __future__ import annotations

import argparse
import csv
import platform
import statistics
import sys
import time

import numpy as np

from vrsim_cli.model.collision import analytic_geom, table
from vrsim_cli.stages.collision.broadphase import candidate_pairs
from vrsim_cli.stages.collision.detect import narrow_phase
from vrsim_cli.stages.collision.shapes import aabbs, place

DENSITY = 8.0  # spheres per m^3


def scene(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    side = (n / DENSITY) ** (1.0 / 3.0)
    radius = rng.uniform(0.1, 0.3, n)
    cm = table([analytic_geom(i, {"type": "sphere", "radius": float(r)})
                for i, r in enumerate(radius)])
    pos = rng.uniform(0.0, side, (n, 3))
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return cm, pos, quat


def vrsim_method(method: str):
    def call(cm, pos, quat):
        t0 = time.perf_counter()
        world = place(cm, pos, quat)
        lo, hi = aabbs(cm, world)
        ia, ib = candidate_pairs(lo, hi, method)
        t1 = time.perf_counter()
        pair, *_ = narrow_phase(cm, world, ia, ib, 0.0)
        t2 = time.perf_counter()
        return t1 - t0, t2 - t1, len(ia), len(pair)
    return call


def fcl_tree():
    import fcl

    state = {}

    def call(cm, pos, quat):
        key = id(cm)
        if state.get("key") != key:  # build once per scene (not timed again)
            objects = [fcl.CollisionObject(fcl.Sphere(float(r)), fcl.Transform(p))
                       for r, p in zip(cm.geom_radius, pos)]
            manager = fcl.DynamicAABBTreeCollisionManager()
            manager.registerObjects(objects)
            manager.setup()
            state.update(key=key, objects=objects, manager=manager)
        objects, manager = state["objects"], state["manager"]
        t0 = time.perf_counter()
        for obj, p in zip(objects, pos):
            obj.setTranslation(p)
        manager.update()
        # fcl's callback stops once num_max_contacts are found: allow them all.
        request = fcl.CollisionRequest(num_max_contacts=10 * len(objects), enable_contact=True)
        data = fcl.CollisionData(request=request)
        manager.collide(data, fcl.defaultCollisionCallback)
        t1 = time.perf_counter()
        return t1 - t0, 0.0, -1, len(data.result.contacts)
    return call


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-n", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--csv", help="write the CSV here instead of stdout")
    args = parser.parse_args()
    sizes = [n for n in (100, 300, 1000, 3000, 10_000, 30_000) if n <= args.max_n]
    methods = {"grid": vrsim_method("grid"), "sap": vrsim_method("sap"),
               "brute": vrsim_method("brute"), "fcl-tree": fcl_tree()}
    out = open(args.csv, "w", newline="") if args.csv else sys.stdout
    writer = csv.writer(out)
    print(f"# {platform.processor() or platform.machine()}, {platform.python_version()}, "
          f"numpy {np.__version__}", file=sys.stderr)
    writer.writerow(["n", "method", "broad_ms", "narrow_ms", "total_ms", "pairs", "contacts"])
    for n in sizes:
        cm, pos, quat = scene(n)
        for name, call in methods.items():
            if name == "brute" and n > 3000:
                continue  # n^2 = 10^8 pairs: minutes and gigabytes
            call(cm, pos, quat)  # warm-up (and fcl's tree build)
            runs = [call(cm, pos, quat) for _ in range(args.repeats)]
            broad = statistics.median(r[0] for r in runs) * 1e3
            narrow = statistics.median(r[1] for r in runs) * 1e3
            writer.writerow([n, name, f"{broad:.3f}", f"{narrow:.3f}", f"{broad + narrow:.3f}",
                             runs[0][2], runs[0][3]])
            out.flush()


if __name__ == "__main__":
    main()
