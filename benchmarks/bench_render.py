"""Frames per second of the OSMesa renderer: 100 bodies at 640x480 (not a test).

    python benchmarks/bench_render.py [--bodies 100] [--width 640] [--height 480]
                                      [--frames 60] [--batches 5] [--csv out.csv]

Builds a scene of `--bodies` moving bodies (spheres, boxes, capsules, cylinders in turn,
on a 10 x 10 grid, half translucent is not used: all opaque) over a ground plane, warms
up, then times batches of `--frames` frames, each from the same saved state, for:
render (draw + read back + overlay), encode (PNG, Pillow), and both plus an atomic file
write (FramesWriter.close, which draws the frames a run kept, camera path included).
Reports the mean and the standard deviation over the batches.
"""

from __future__ import annotations

import argparse
import csv
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.render import open_renderer, time_label
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.writers.frames import FramesWriter
from vrsim_cli.writers.frames import encode_png

SHAPES = ("{type: sphere, radius: 0.2}", "{type: box, size: [0.3, 0.3, 0.3]}",
          "{type: capsule, radius: 0.12, length: 0.25}",
          "{type: cylinder, radius: 0.15, length: 0.3}")


def scene_text(n_bodies: int) -> str:
    lines = ["vrsim: 1", "name: bench-render", "duration: 10", "frame_rate: 60", "bodies:",
             "  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}"]
    side = max(1, round(n_bodies ** 0.5))
    for i in range(n_bodies):
        x, z = (i % side - side / 2) * 0.7, (i // side - side / 2) * 0.7
        lines.append(f"  - {{name: b{i}, mass: 1, shape: {SHAPES[i % 4]}, "
                     f"position: [{x:.2f}, {1 + 0.1 * (i % 7):.2f}, {z:.2f}], "
                     f"velocity: [0.1, 2, 0]}}")
    return "\n".join(lines) + "\n"


def time_batches(fn, frames: int, batches: int) -> list[float]:
    """Frames per second of `fn(k)` per batch."""
    rates = []
    for _ in range(batches):
        start = time.perf_counter()
        for k in range(frames):
            fn(k)
        rates.append(frames / (time.perf_counter() - start))
    return rates


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=100)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--batches", type=int, default=5)
    parser.add_argument("--csv", type=Path)
    args = parser.parse_args(argv)

    model = compile_model(parse_scene(scene_text(args.bodies)))
    state = make_state(model)  # every batch starts from this saved state
    renderer = open_renderer(model, args.width, args.height)
    for _ in range(5):  # warm-up: display lists, llvmpipe's shader compilation
        image = renderer.render(state, time_label(state.t))

    def render(k):
        renderer.render(state, time_label(k / 60))

    def encode(_k):
        encode_png(image)

    rows = [("render", time_batches(render, args.frames, args.batches)),
            ("encode", time_batches(encode, args.frames, args.batches))]
    with tempfile.TemporaryDirectory() as folder:
        from vrsim_cli.model.frames import FramesSpec

        spec = FramesSpec(Path(folder), 1, args.width, args.height)
        step = model.steps_per_frame

        class Keep:  # the renderer stays open across batches; FramesWriter closes it
            def render(self, *a, **k):
                return renderer.render(*a, **k)

            def close(self):
                pass

        # FramesWriter keeps the states during the run and draws them all on close()
        # (with the action camera, which needs the whole run): time a batch's close.
        rates = []
        for _ in range(args.batches):
            writer = FramesWriter(model, spec, Keep(), label=time_label)
            for k in range(args.frames):
                writer(state.replace(step=k * step, t=k * step * model.dt))
            start = time.perf_counter()
            writer.close()
            rates.append(args.frames / (time.perf_counter() - start))
        rows.append(("render+png+write", rates))

    machine = f"{platform.processor() or platform.machine()}, {platform.system()} " \
              f"{platform.release()}, Python {platform.python_version()}"
    print(f"{args.bodies} bodies ({model.n_body} with the ground), {args.width}x{args.height},"
          f" {args.batches} batches of {args.frames} frames; {machine}")
    print(f"{'stage':<18} {'frames/s':>9} {'+-':>6} {'ms/frame':>9}")
    for stage, rates in rows:
        mean, sd = statistics.mean(rates), statistics.stdev(rates) if len(rates) > 1 else 0.0
        print(f"{stage:<18} {mean:>9.1f} {sd:>6.1f} {1e3 / mean:>9.2f}")
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["stage", "bodies", "width", "height", "batch", "frames_per_s"])
            for stage, rates in rows:
                for batch, rate in enumerate(rates):
                    out.writerow([stage, args.bodies, args.width, args.height, batch, rate])


if __name__ == "__main__":
    sys.exit(main())
