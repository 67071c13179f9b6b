"""The differentiable pipeline's speed goals, every figure from one run, each with met or
missed.

    glraster study speed-goals --before-commit ada30fd --json out/speed-goals.json

Four parts, run one after the other in this process (the A/B in two worker
interpreters), each a study of its own reused here:

``floors`` (:mod:`glraster.studies.diff_floors`)
    one iteration of each fit (cube 4x4 and 16x16, pose 256², texture, envmap) against
    the sum of its op calls' floors (their GL work replayed bare) plus its optimizer
    step, medians of ``--rounds`` interleaved rounds of ``--fit-iterations``.
    Goal: iteration / (floors + step) <= 1.5 for every fit.
``ab`` (:mod:`glraster.studies.fit_iterations_ab`)
    iterations per second of the cube fit at 4x4 and 16x16, the pose fit and the
    environment-map workload in nvdiffrast's calls, this tree (``--after``) against the
    older one (``--before`` PATH, or ``--before-commit`` COMMIT: a temporary git
    worktree; ada30fd when neither is given), ``--rounds`` interleaved rounds; the
    figure is the median of the rounds' after / before. Goals: >= 2 for the cube and
    pose fits, >= 4 for envmap.
``bench`` (:mod:`glraster.studies.diff_bench`, ``glraster bench-diff --full``'s cells)
    per (resolution, triangles) cell: the rasterize backward, deterministic and atomic,
    against the forward with rast_db, and the deterministic / atomic backward of
    rasterize and interpolate (medians of per-round ratios). Goals: every ratio <= 2.
``texture`` (:mod:`glraster.studies.torch_texture_baseline`)
    forward + backward of ``glraster.torch.texture`` against the same filters in plain
    PyTorch (``grid_sample``), every filter mode and size, and the core's deterministic /
    atomic backward. Goals: glraster / PyTorch < 1, deterministic / atomic <= 2.

Prints each part's Markdown table (the tables of docs/performance.md), then the goals
with met / missed and how long each part took. ``--parts`` and the size options make a
short form (tests/studies/test_speed_goals.py runs one in well under a minute); the
figures of a short form are no statement about the goals. Timings on a shared machine
are noisy: read the ratios, and rerun a missed goal before trusting it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from glraster.io.destinations import OutputFile
from glraster.studies import diff_floors, fit_iterations_ab
from glraster.studies.registry import argument_parser

PARTS = ("floors", "ab", "bench", "texture")
AB_CASES = ("cube 4x4", "cube 16x16", "pose", "envmap")
# goal comparisons: the figure must be (op) the target
FIT_GOAL = ("<=", 1.5)
AB_GOALS = {"cube 4x4": (">=", 2.0), "cube 16x16": (">=", 2.0), "pose": (">=", 2.0),
            "envmap": (">=", 4.0)}
BENCH_GOALS = {  # diff_bench ratio name -> (figure name, goal)
    "backward_deterministic_over_forward": ("rasterize det. backward / forward", ("<=", 2.0)),
    "backward_atomic_over_forward": ("rasterize atomic backward / forward", ("<=", 2.0)),
    "rasterize_deterministic_over_atomic": ("rasterize det. / atomic backward", ("<=", 2.0)),
    "interpolate_deterministic_over_atomic": ("interpolate det. / atomic backward",
                                              ("<=", 2.0)),
}
TEXTURE_GOAL = ("<", 1.0)
TEXTURE_DETERMINISTIC_GOAL = ("<=", 2.0)


def _goal(part: str, figure: str, value: float, goal: tuple) -> dict:
    op, target = goal
    met = {"<=": value <= target, ">=": value >= target, "<": value < target}[op]
    return {"part": part, "figure": figure, "value": float(value), "goal": f"{op} {target:g}",
            "met": bool(met)}


# --------------------------------------------------------------------------- the parts


def floors(glctx, fits, rounds: int, iterations: int, profile_iterations: int):
    """(diff_floors.measure_fits result, goals)."""
    result = diff_floors.measure_fits(glctx, fits, rounds, iterations, profile_iterations)
    goals = [_goal("floors", f"{name}: iteration / (floors + step)",
                   diff_floors.fit_ratio(fit), FIT_GOAL)
             for name, fit in result.items()]
    return result, goals


def ab(before, after, *, rounds: int, iterations: int, size: int, cases=AB_CASES,
       envmap_resolution: int = 256, envmap_mesh=(128, 120), envmap_env_size: int = 512):
    """(fit_iterations_ab.compare rows, goals)."""
    rows = fit_iterations_ab.compare(before, after, rounds=rounds, iterations=iterations,
                                     size=size, names=cases,
                                     envmap_resolution=envmap_resolution,
                                     envmap_mesh=envmap_mesh, envmap_env_size=envmap_env_size)
    goals = [_goal("ab", f"{row['label']}: iterations/s after / before", row["paired"],
                   AB_GOALS[row["case"]]) for row in rows]
    return rows, goals


def bench(backend, *, resolutions, counts, repeats: int):
    """(diff_bench.run result, goals) of the ``full`` preset's cells (or the given)."""
    from glraster.studies import diff_bench

    result = diff_bench.run("full", backend=backend, resolutions=tuple(resolutions),
                            counts=tuple(counts), repeats=repeats, profile=None)
    goals = []
    for cell in result["cells"]:
        where = f"{cell['resolution'][0]}², {cell['triangles']} triangles"
        for name, (figure, goal) in BENCH_GOALS.items():
            goals.append(_goal("bench", f"{where}: {figure}",
                               cell["ratios"][name]["median"], goal))
    return result, goals


def texture(*, sizes, repeat: int, modes):
    """(rows {size, mode, glraster_ms, pytorch_ms, ratio, deterministic_over_atomic},
    goals): the whole op against plain PyTorch (``ratio``: median of the rounds'
    glraster / PyTorch) and the GPU core's deterministic / atomic backward (median of
    the rounds' ratios), every mode and size."""
    from glraster.studies import torch_texture_baseline as baseline

    sizes, modes = tuple(sizes), tuple(modes)
    cores = {(size, mode): det_over_atomic for size, mode, _, _, _, det_over_atomic, _, _
             in baseline.core_benchmark(sizes, repeat, "wrap", modes)}
    rows = [{"size": size, "mode": mode, "glraster_ms": gl, "pytorch_ms": pt,
             "ratio": ratio, "deterministic_over_atomic": cores[size, mode]}
            for size, mode, gl, pt, ratio, *_ in baseline.benchmark(sizes, repeat, "wrap",
                                                                    modes)]
    goals = []
    for r in rows:
        where = f"{r['size']}² {r['mode']}"
        goals.append(_goal("texture", f"{where}: glraster / PyTorch", r["ratio"],
                           TEXTURE_GOAL))
        goals.append(_goal("texture", f"{where}: det. / atomic backward",
                           r["deterministic_over_atomic"], TEXTURE_DETERMINISTIC_GOAL))
    return rows, goals


# --------------------------------------------------------------------------- tables


def texture_table(rows: list) -> str:
    lines = ["| image and texture | filter_mode | glraster.torch ms | plain PyTorch ms | "
             "glraster / PyTorch | det. / atomic backward |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['size']}² | {r['mode']} | {r['glraster_ms']:.1f} | "
              f"{r['pytorch_ms']:.1f} | {r['ratio']:.2f} | "
              f"{r['deterministic_over_atomic']:.2f} |" for r in rows]
    return "\n".join(lines)


def goals_table(goals: list) -> str:
    lines = ["| part | figure | value | goal | |", "|---|---|---|---|---|"]
    lines += [f"| {g['part']} | {g['figure']} | {g['value']:.2f} | {g['goal']} | "
              f"{'met' if g['met'] else '**missed**'} |" for g in goals]
    return "\n".join(lines)


# --------------------------------------------------------------------------- main


def build_parser():
    parser = argument_parser("speed-goals", __doc__)
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    parser.add_argument("--rounds", type=int, default=5,
                        help="interleaved rounds of the floors and the A/B (default 5)")
    parser.add_argument("--backend", default=None, help="OpenGL backend (egl, osmesa)")
    parser.add_argument("--json", action=OutputFile,
                        default=None, metavar="FILE", help="also write every "
                        "figure and goal here")
    floors_ = parser.add_argument_group("floors")
    floors_.add_argument("--fits", nargs="+", choices=diff_floors.FITS,
                         default=list(diff_floors.FITS))
    floors_.add_argument("--fit-iterations", type=int, default=10,
                         help="timed iterations per fit and round (default 10)")
    floors_.add_argument("--profile-iterations", type=int, default=2,
                         help="iterations per fit under cProfile (default 2)")
    ab_ = parser.add_argument_group("ab")
    ab_.add_argument("--before", type=Path, help="a checkout of the older tree")
    ab_.add_argument("--before-commit", help=f"or: a commit to check out as the older tree "
                     f"(default {fit_iterations_ab.DEFAULT_BEFORE} when neither is given)")
    ab_.add_argument("--after", type=Path, default=fit_iterations_ab.HERE.parents[2])
    ab_.add_argument("--ab-cases", nargs="+", choices=AB_CASES, default=list(AB_CASES))
    ab_.add_argument("--ab-iterations", type=int, default=200,
                     help="cube iterations per round (pose: a fifth; envmap: a fiftieth, "
                          "at least 2; default 200)")
    ab_.add_argument("--ab-size", type=int, default=256, help="the pose fit's image size")
    ab_.add_argument("--envmap-resolution", type=int, default=256)
    ab_.add_argument("--envmap-mesh", type=int, nargs=2, default=[128, 120],
                     metavar=("NU", "NV"))
    ab_.add_argument("--envmap-env-size", type=int, default=512)
    bench_ = parser.add_argument_group("bench")
    bench_.add_argument("--bench-resolutions", type=int, nargs="+",
                        default=[256, 512, 1024])
    bench_.add_argument("--bench-counts", type=int, nargs="+", default=[1000, 20000, 100000])
    bench_.add_argument("--bench-repeats", type=int, default=15,
                        help="rounds per cell (default 15, as bench-diff --full)")
    texture_ = parser.add_argument_group("texture")
    texture_.add_argument("--texture-sizes", type=int, nargs="+", default=[256, 512, 1024])
    texture_.add_argument("--texture-repeat", type=int, default=5)
    texture_.add_argument("--texture-modes", nargs="+", default=None,
                          help="filter modes (default: all of texture-baseline's)")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for option in ("rounds", "fit_iterations", "profile_iterations", "ab_iterations",
                   "ab_size", "envmap_resolution", "envmap_env_size", "bench_repeats",
                   "texture_repeat"):
        if getattr(args, option) < 1:
            parser.error(f"--{option.replace('_', '-')} must be at least 1")
    if args.before is not None and args.before_commit is not None:
        parser.error("give at most one of --before PATH or --before-commit COMMIT")
    for size in args.texture_sizes:
        if size < 2 or size & (size - 1):
            parser.error(f"--texture-sizes must be powers of two >= 2, got {size}")
    figures, goals, seconds = {}, [], {}

    def part(name, title, run, table):
        start = time.perf_counter()
        result, part_goals = run()
        seconds[name] = time.perf_counter() - start
        figures[name] = result
        goals.extend(part_goals)
        print(f"\n## {title}\n\n{table(result)}", flush=True)

    if "floors" in args.parts:
        from glraster.torch.fitting.common import session

        with session(backend=args.backend) as glctx:
            print(f"# speed-goals on {glctx.context.renderer} ({glctx.context.backend})")
            part("floors", "Fit iterations against their floors (diff-floors)",
                 lambda: floors(glctx, args.fits, args.rounds, args.fit_iterations,
                                args.profile_iterations),
                 diff_floors.fits_tables)
    if "ab" in args.parts:
        commit = args.before_commit
        if args.before is None and commit is None:
            commit = fit_iterations_ab.DEFAULT_BEFORE
        with fit_iterations_ab.BeforeTree(args.before, commit, args.after) as before:
            part("ab", f"Iterations per second against {args.before or commit} "
                 f"(fit-iterations-ab, {args.rounds} rounds)",
                 lambda: ab(before, args.after, rounds=args.rounds,
                            iterations=args.ab_iterations, size=args.ab_size,
                            cases=args.ab_cases, envmap_resolution=args.envmap_resolution,
                            envmap_mesh=tuple(args.envmap_mesh),
                            envmap_env_size=args.envmap_env_size),
                 fit_iterations_ab.table)
    if "bench" in args.parts:
        from glraster.studies import diff_bench

        part("bench", "Backward against forward, deterministic against atomic (bench-diff "
             "cells)", lambda: bench(args.backend, resolutions=args.bench_resolutions,
                                     counts=args.bench_counts, repeats=args.bench_repeats),
             diff_bench.table)
    if "texture" in args.parts:
        from glraster.studies import torch_texture_baseline as baseline

        part("texture", "Texture against plain PyTorch (texture-baseline)",
             lambda: texture(sizes=args.texture_sizes, repeat=args.texture_repeat,
                             modes=args.texture_modes or baseline.MODES),
             texture_table)
    met = sum(g["met"] for g in goals)
    print(f"\n## Goals: {met} of {len(goals)} met\n\n{goals_table(goals)}")
    print("\nseconds per part: " + ", ".join(f"{k} {v:.0f}" for k, v in seconds.items())
          + f"; total {sum(seconds.values()):.0f}")
    if args.json:
        from glraster.io.atomic import write_text

        write_text(args.json, json.dumps({"figures": figures, "goals": goals,
                                          "seconds": seconds}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
