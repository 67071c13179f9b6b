"""How long the exact area coverage (glraster.reference.area_coverage) takes.

    glraster study area-coverage [--size 256] [--rounds 5]

Scenes at --size x --size: the antialias study's three (fan, thin slivers, near-clipped
floor), a 32 x 32 grid mesh (2048 triangles sharing edges), 300 small random overlapping
triangles and 300 large random ones that intersect each other (the worst case: dozens of
triangles per pixel, split by their lines of equal depth). Prints the median over
--rounds runs after a warm-up (numba compiles once). Timings on a shared machine are
noisy.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from glraster.geometry.window import window_to_clip
from glraster.reference.area import area_coverage
from glraster.studies.antialias import builtin_scenes
from glraster.studies.registry import argument_parser


def _random(n, size, side, seed):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(0, size, (n, 1, 2))
    xy = (centre + rng.uniform(-side, side, (n, 3, 2))).reshape(-1, 2)
    pos = window_to_clip(xy, (size, size), z_ndc=rng.uniform(-0.9, 0.9, len(xy)))
    return pos, np.arange(len(xy)).reshape(-1, 3)


def _grid(n, size):
    g = np.linspace(0.3, size - 0.7, n + 1)
    gx, gy = np.meshgrid(g, g)
    pos = window_to_clip(np.c_[gx.ravel(), gy.ravel()], (size, size))
    tri = []
    for r in range(n):
        for c in range(n):
            a, b = r * (n + 1) + c, r * (n + 1) + c + 1
            tri += [(a, b, b + n + 1), (a, b + n + 1, a + n + 1)]
    return pos, np.array(tri)


def main(argv=None) -> int:
    parser = argument_parser("area-coverage", __doc__)
    parser.add_argument("--size", type=int, default=256, help="image height and width (px)")
    parser.add_argument("--rounds", type=int, default=5, help="timed runs per scene")
    args = parser.parse_args(argv)
    if args.size < 16:
        parser.error(f"--size must be at least 16, got {args.size}")
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    size = args.size
    scenes = {s.name: (s.pos, s.tri) for s in builtin_scenes((size, size))}
    scenes["grid 32x32"] = _grid(32, size)
    scenes["300 small random"] = _random(300, size, 0.05 * size, 1)
    scenes["300 large intersecting"] = _random(300, size, 0.5 * size, 2)
    area_coverage(*scenes["fan"], (16, 16))
    for name, (pos, tri) in scenes.items():
        times = []
        for _ in range(args.rounds):
            t0 = time.perf_counter()
            area = area_coverage(pos, tri, (size, size))
            times.append(time.perf_counter() - t0)
        print(f"{name:<24} {len(tri):5d} triangles  {size}x{size}  "
              f"{1e3 * statistics.median(times):8.1f} ms  (covered {area.sum():.0f} px)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
