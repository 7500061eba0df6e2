"""The memory a run will take, estimated when the model is compiled, and its limit.

Layer 2 helper of `model.compile_model`. A run's memory grows with what it holds at once:
bodies (state arrays, per-sample output rows: an MCAP sample is JSON for every entity),
rendered frames (RGBA buffer, PNG encoding) and mesh triangles (trimesh, proxies, fcl);
not with its duration (outputs are streamed). Each term below is an upper bound measured
on x86-64 Linux (peak RSS of `vrsim run`, Python 3.11, numpy 2.4; see
tests/test_memory.py, which runs the largest scenes this accepts and checks the peak):

- 100000 emitted particles, collision on: 262 MB with CSV output, 585 MB with MCAP;
- frames of 4096 x 4096 px: 529 MB (577 MB with a video);
- two mesh bodies of 199000 triangles each, collision and mass properties: 277 MB; five
  with hull proxies: 552 MB;
- contact pairs: 1000 particles leaving one nozzle at once (499500 overlapping pairs):
  1043 MB, 500: 304 MB, 700: 540 MB (~2 KB a pair); written to MCAP, where every contact
  is drawn, 805 of them took 1309 MB (~4 KB a pair). Only pairs that overlap from the
  start are counted here (bodies at one point, emitters releasing many particles at one
  step): a pile is a few contacts per body, and bodies that collide respond.

A scene whose estimate passes MAX_RUN_MB is refused at validation (exit 2) with the
estimate and what drives it, instead of being killed for memory later.
"""

from __future__ import annotations

MAX_RUN_MB = 900  # the estimate's limit; with the terms' margins the peak stays < 1 GB
BASE_MB = 100  # Python, numpy, the scene: a small run's peak
BODY_KB = {"mcap": 6.0, "csv": 2.5, "tum": 2.5, None: 2.5}  # per body or particle
PIXEL_B = 44  # per pixel of a frame (RGBA buffer, the flipped copy, PNG rows, labels);
# measured 41 B with an MP4 (tests/test_memory.py: 8192 x 2959 px peaked at 1108 MB)
VIDEO_MB = 60  # the encoder
TRIANGLE_B = 700  # per triangle of every mesh body
PAIR_KB = {"mcap": 5.0, None: 2.5}  # per pair of colliding bodies starting at one point


def estimate_mb(n_body: int, output_format: str | None, pixels: int, video: bool,
                triangles: int, pairs: int = 0) -> dict:
    """{term: MB} of the run's memory, with 'total'."""
    terms = {
        "base": BASE_MB,
        "bodies": n_body * BODY_KB.get(output_format, BODY_KB[None]) / 1024,
        "frames": pixels * PIXEL_B / 2 ** 20 + (VIDEO_MB if video and pixels else 0),
        "meshes": triangles * TRIANGLE_B / 2 ** 20,
        "overlaps": pairs * PAIR_KB.get(output_format, PAIR_KB[None]) / 1024,
    }
    terms["total"] = sum(terms.values())
    return terms


def gif_mb(images: int, pixels: int) -> float:
    """MB a GIF video holds until the run ends: every RGB image (imageio/Pillow write a
    GIF at once). An MP4 is streamed and costs VIDEO_MB whatever its length."""
    return images * pixels * 3 / 2 ** 20


def budget_problem(terms: dict) -> tuple[str, str] | None:
    """(message, the term that drives it) when the estimate passes MAX_RUN_MB, or None."""
    if terms["total"] <= MAX_RUN_MB:
        return None
    kinds = ("bodies", "frames", "meshes", "overlaps")
    main = max(kinds, key=lambda k: terms[k])
    parts = ", ".join(f"{k} {terms[k]:.0f} MB" for k in kinds if terms[k] >= 1)
    return (f"this run would take about {terms['total']:.0f} MB of memory ({parts}); "
            f"vrsim runs scenes up to {MAX_RUN_MB} MB", main)


def coincident_pairs(keys, movable) -> int:
    """Pairs of colliding bodies that start at the same point at the same time: `keys`
    (n,) (position, release step) pairs; `movable` (n,) bool (two static bodies never make
    a contact). Pairs with a movable body are counted per release step; the largest step's
    count is returned (particles released at different steps have moved apart)."""
    groups: dict = {}
    for key, moves in zip(keys, movable):
        count = groups.setdefault(key, [0, 0])
        count[0 if moves else 1] += 1
    per_step: dict = {}
    for (_position, step), (m, s) in groups.items():
        per_step[step] = per_step.get(step, 0) + m * (m - 1) // 2 + m * s
    return max(per_step.values(), default=0)
