"""Cost of writing one output sample, per format, for N bodies (not a test).

    python benchmarks/output_cost.py [--bodies 1000] [--samples 200] [--repeats 3]
                                     [--formats mcap,csv,tum]

Builds a scene of `--bodies` spheres (every one a named entity with a shape), makes
`--samples` states with fresh random positions, orientations and velocities (random
numbers compress worst), and times the writer alone, in ms: `write(state)` per sample
after the first (the steady cost of a long run), the first sample (MCAP publishes every
body's shape then), `close()` (summary, flush to disk, atomic rename), and everything
divided by the samples. Of `--repeats` runs the one with the lowest per-sample cost is
reported. The budget of issue 17: MCAP <= 1 ms per sample at 1000 bodies.
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from vrsim_cli.maths.spatial import quat_normalize
from vrsim_cli.model.model import MAX_TUM_ENTITIES, compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.writers import open_writer


def scene_text(n_bodies: int) -> str:
    lines = ["vrsim: 1", "name: output-cost", "duration: 10", "frame_rate: 50", "bodies:"]
    lines += [f"  - {{name: body{i:04d}, mass: 1, shape: {{type: sphere, radius: 0.05}}, "
              f"position: [{i % 32}, 1, {i // 32}]}}" for i in range(n_bodies)]
    return "\n".join(lines) + "\n"


def states(model, samples: int, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    base = make_state(model)
    n = model.n_body
    return [base.replace(step=k * 10, t=k * 10 * model.dt,
                         body_pos=rng.normal(size=(n, 3)), body_vel=rng.normal(size=(n, 3)),
                         body_quat=quat_normalize(rng.normal(size=(n, 4))),
                         body_angvel=rng.normal(size=(n, 3)))
            for k in range(samples)]


def time_format(model, samples: list, fmt: str, folder: Path) -> tuple:
    """Seconds: (first sample, each further sample, close) for writing `samples` in
    `fmt`. The first sample of MCAP also publishes every body's shape on /scene; close
    writes the summary, flushes to disk and renames the file into place."""
    target = folder / {"mcap": "out.mcap", "csv": "out.csv", "tum": "tum"}[fmt]
    writer = open_writer(model, target, fmt)
    clock = time.perf_counter
    t0 = clock()
    writer.write(samples[0])
    t1 = clock()
    for state in samples[1:]:
        writer.write(state)
    t2 = clock()
    writer.close()
    t3 = clock()
    return t1 - t0, (t2 - t1) / (len(samples) - 1), t3 - t2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=1000)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--formats", default="mcap,csv,tum")
    args = parser.parse_args(argv)
    if args.samples < 2 or args.bodies < 1 or args.repeats < 1:
        parser.error("--samples must be >= 2 (the first is timed apart), --bodies and "
                     "--repeats >= 1")
    model = compile_model(parse_scene(scene_text(args.bodies), "<output-cost>"))
    samples = states(model, args.samples)
    print(f"{args.bodies} bodies, {args.samples} samples, best of {args.repeats}; "
          f"Python {platform.python_version()} on {platform.machine()}")
    print(f"{'format':<7}{'per sample':>12}{'first':>10}{'close':>10}{'all / samples':>15}  (ms)")
    for fmt in args.formats.split(","):
        if fmt == "tum" and args.bodies > MAX_TUM_ENTITIES:  # one open file per entity
            print(f"{fmt:<7}skipped: TUM writes one file per entity, at most "
                  f"{MAX_TUM_ENTITIES} (--bodies {args.bodies})")
            continue
        runs = []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as folder:
                runs.append(time_format(model, samples, fmt, Path(folder)))
        first, each, close = min(runs, key=lambda r: r[1])
        total = (first + each * (len(samples) - 1) + close) / len(samples)
        print(f"{fmt:<7}{1e3 * each:12.3f}{1e3 * first:10.2f}{1e3 * close:10.2f}"
              f"{1e3 * total:15.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
