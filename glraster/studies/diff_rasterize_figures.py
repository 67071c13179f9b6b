"""Figures for docs/differentiable.md ("GPU"): the differentiable rasterize's forward
(the float32 core of glraster.diff.ops.RASTERIZE) against float64 on catalog scenes, and its
speed with and without rast_db.

    glraster study diff-rasterize-figures [--accuracy] [--timing] [--batches]

``--accuracy`` judges the GPU against the per-pixel error bounds of the test suite
(tests/diff/test_rasterize_gpu.py: ``float64_forward`` and ``compare``), so it runs in a
source checkout of glraster only.
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

import numpy as np

import glraster as gr
from glraster.conformance.scenes import list_scenes, load_scene
from glraster.diff.ops import RASTERIZE
from glraster.studies.bench import make_bench_scene
from glraster.studies.registry import argument_parser
from glraster.studies.timing import median_seconds

# the source tree this module is in: glraster/studies/ -> the checkout's root
TREE = Path(__file__).resolve().parents[2]


def gpu_forward(pos, tri, resolution, ctx, grad_db=True):
    """A call of the float32 (GPU) rasterize core on inputs checked once: ``call()`` ->
    (rast, rast_db), each (B, H, W, 4) float32 (rast_db (B, H, W, 0) without ``grad_db``).
    The call runs the core only, which is what the timings measure."""
    inputs, params = RASTERIZE.check(np.asarray(pos, np.float32), tri=tri,
                                     resolution=resolution, grad_db=grad_db, ctx=ctx)
    core = RASTERIZE.core(np.float32)
    return lambda: core.forward(*inputs, **params)[0]


def _test_bounds():
    """``(float64_forward, compare)`` of the test suite's rasterize checks (the per-pixel
    error bounds live with the tests), importable from a source checkout only."""
    if not (TREE / "tests" / "diff" / "test_rasterize_gpu.py").is_file():
        raise FileNotFoundError(f"--accuracy needs a glraster source checkout (its tests/diff "
                                f"error bounds); none at {TREE}")
    if str(TREE) not in sys.path:
        sys.path.insert(0, str(TREE))
    module = importlib.import_module("tests.diff.test_rasterize_gpu")
    return module.float64_forward, module.compare


def accuracy(ctx, names):
    float64_forward, compare = _test_bounds()
    total = {"uv": [], "z": [], "db": [], "db_rel": []}
    worst = {"ratio": 0.0, "ratio_db": 0.0}
    mism = amb = pixels = 0
    print(f"{'scene':28s} {'px':>8s} {'idDiff':>6s} {'uv max':>9s} {'z max':>9s} "
          f"{'db max':>9s} {'dbrel p99.9':>11s} {'ratio':>6s} {'ratio_db':>8s}")
    for name in names:
        s = load_scene(name)
        t0 = time.perf_counter()
        rast, db = gpu_forward(s.pos, s.tri, s.resolution, ctx)()
        got = compare(rast[0], db[0], float64_forward(s.pos, s.tri, s.resolution, ctx=ctx))
        for k in total:
            total[k].append(got[k])
        for k in worst:
            worst[k] = max(worst[k], got[k])
        mism += got["id_mismatch"]
        amb += got["id_mismatch_unambiguous"]
        pixels += got["pixels"]
        mx = lambda a: a.max() if a.size else 0.0
        p = lambda a: np.quantile(a, 0.999) if a.size else 0.0
        print(f"{name:28s} {got['pixels']:8d} {got['id_mismatch']:6d} {mx(got['uv']):9.2e} "
              f"{mx(got['z']):9.2e} {mx(got['db']):9.2e} {p(got['db_rel']):11.2e} "
              f"{got['ratio']:6.3f} {got['ratio_db']:8.3f}   ({time.perf_counter() - t0:.1f} s)")
    print(f"\nall: {pixels} pixels compared, {mism} with other ids ({amb} outside the "
          "ambiguous pixels)")
    for k, a in total.items():
        a = np.concatenate(a)
        print(f"  {k:7s} max {a.max():.2e}  p99.9 {np.quantile(a, 0.999):.2e}  "
              f"mean {a.mean():.2e}")
    print(f"  worst error / bound: rast {worst['ratio']:.3f}, rast_db {worst['ratio_db']:.3f}")


def timing(ctx, repeat):
    print(f"\n{'size':>6s} {'tris':>6s} {'no db ms':>9s} {'db ms':>9s} {'ratio':>6s} "
          f"{'cpu no db':>9s} {'cpu db':>9s} {'ratio':>6s} {'gr.rasterize hw ms':>18s}")
    for tris in (1000, 20000):
        for size in (256, 512, 1024):
            scene = make_bench_scene("terrain", tris, seed=0)
            pos, tri, res = scene.pos, scene.faces, (size, size)
            # interleaved A/B: minima of alternating runs
            # process CPU time includes llvmpipe's rasterizer threads and is less disturbed
            # by other processes on shared cores than wall time
            a, b, ca, cb = [], [], [], []
            nodb = gpu_forward(pos, tri, res, ctx, grad_db=False)
            db = gpu_forward(pos, tri, res, ctx)
            for _ in range(repeat):
                a.append(median_seconds(nodb, 1, warmup=1))
                b.append(median_seconds(db, 1, warmup=1))
                ca.append(median_seconds(nodb, 1, warmup=1, clock=time.process_time))
                cb.append(median_seconds(db, 1, warmup=1, clock=time.process_time))
            hw = min(median_seconds(lambda: gr.rasterize(pos, tri, res, ctx=ctx,
                                                         outputs=("persp", "depth", "tri_id")),
                                    1, warmup=1)
                     for _ in range(repeat))
            ta, tb = np.min(a), np.min(b)  # minima: the machine's cores are shared
            tca, tcb = np.median(ca), np.median(cb)
            print(f"{size:6d} {len(tri):6d} {1e3 * ta:9.2f} {1e3 * tb:9.2f} {tb / ta:6.2f} "
                  f"{1e3 * tca:9.2f} {1e3 * tcb:9.2f} {tcb / tca:6.2f} {1e3 * hw:18.2f}")


def _atlas(batch, tri, height):
    """The B items of ``batch`` (B, V, 4) stacked as tiles of a (B H, W) image: item b's
    window y moves up by b H. One draw, one clear and one readback for the whole batch,
    as a layered array-texture render would have (a proxy for its cost, not its values)."""
    B, V, _ = batch.shape
    pos = batch.astype(np.float64).copy()
    w = pos[..., 3]
    for b in range(B):
        yw = (pos[b, :, 1] / w[b] + 1) / 2 * height + b * height
        pos[b, :, 1] = (yw / (B * height) * 2 - 1) * w[b]
    tris = np.concatenate([tri + b * V for b in range(B)])
    return pos.reshape(-1, 4).astype(np.float32), tris


def batches(ctx, repeat):
    """Instanced batches drawn one item after the other into the same framebuffer (what
    forward does) against the cost of one draw into a B-times-taller image (see _atlas)."""
    print(f"\n{'size':>6s} {'tris':>6s} {'B':>3s} {'per item ms':>11s} {'one draw ms':>11s} "
          f"{'per item / one draw':>19s}")
    for tris, size in ((1000, 256), (1000, 512), (20000, 256), (20000, 512)):
        scene = make_bench_scene("terrain", tris, seed=0)
        pos, tri = scene.pos, scene.faces
        for B in (4, 16):
            rng = np.random.default_rng(B)
            jitter = rng.normal(0, 0.01, (B, 1, 4)) * [1, 1, 0, 0]
            batch = (pos[None] + jitter).astype(np.float32)
            apos, atri = _atlas(batch, tri, size)
            per_item = gpu_forward(batch, tri, (size, size), ctx)
            one_draw = gpu_forward(apos, atri, (B * size, size), ctx)
            a, b = [], []
            for _ in range(repeat):
                a.append(median_seconds(per_item, 1, warmup=1))
                b.append(median_seconds(one_draw, 1, warmup=1))
            ta, tb = np.min(a), np.min(b)  # minima: the machine's cores are shared
            print(f"{size:6d} {len(tri):6d} {B:3d} {1e3 * ta:11.1f} {1e3 * tb:11.1f} "
                  f"{ta / tb:19.2f}")


def main(argv=None) -> int:
    ap = argument_parser("diff-rasterize-figures", __doc__)
    ap.add_argument("--accuracy", action="store_true", help="float64 comparison on the catalog")
    ap.add_argument("--timing", action="store_true", help="forward with and without rast_db")
    ap.add_argument("--batches", action="store_true", help="instanced batches against one draw")
    ap.add_argument("--scenes", default=None, help="fnmatch pattern(s), default all")
    ap.add_argument("--repeat", type=int, default=7, help="timed rounds (minima shown)")
    ap.add_argument("--backend", default="egl", choices=("egl", "osmesa"))
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error(f"--repeat must be at least 1, got {args.repeat}")
    everything = not (args.accuracy or args.timing or args.batches)
    ctx = gr.Context(backend=args.backend)
    print(ctx.backend, ctx.renderer)
    if args.accuracy or everything:
        accuracy(ctx, list_scenes(args.scenes))
    if args.timing or everything:
        timing(ctx, args.repeat)
    if args.batches or everything:
        batches(ctx, args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
