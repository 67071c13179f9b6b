"""Texture filtering in plain PyTorch (``grid_sample`` + autograd): the yardstick that
:func:`glraster.torch.texture` is timed against (``glraster study texture-baseline``).

The same filters as :func:`glraster.torch.texture` for 2-D textures whose extents are
powers of two (the 2 x 2 box pyramid), written the way one would without a custom kernel:

* texel centres: ``grid_sample(align_corners=False)`` puts texel i of W at
  grid x = (2 i + 1)/W - 1, i.e. uv = (i + 0.5)/W with grid = 2 uv - 1, as glraster;
* boundaries: "clamp" is ``padding_mode="border"``, "zero" ``"zeros"``; "wrap" (which
  grid_sample lacks) pads the level by one texel circularly and samples
  ((s mod 1) W + 1)/(W + 2) of the padded level;
* the pyramid by ``avg_pool2d(2)``; the level from uv_da by the same formula in torch ops;
* linear-mipmap-linear "by hand": every level sampled at every pixel and blended with the
  hat weights max(0, 1 - |level - k|) (per-pixel levels differ, so grid_sample cannot pick
  one); linear-mipmap-nearest with the weight 1 on round(level).

Inputs are not validated (pass what glraster.torch.texture accepts, 2-D, power-of-two).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F


def _pyramid(tex: torch.Tensor, max_mip_level=None):
    """Levels of (B, C, H, W), base first, 2 x 2 box down to 1 x 1 (powers of two)."""
    levels = [tex]
    while levels[-1].shape[-1] > 1 or levels[-1].shape[-2] > 1:
        if max_mip_level is not None and len(levels) > max_mip_level:
            break
        lv = levels[-1]
        kh, kw = (2 if lv.shape[-2] > 1 else 1), (2 if lv.shape[-1] > 1 else 1)
        levels.append(F.avg_pool2d(lv, (kh, kw)))
    return levels


def _sample(level: torch.Tensor, uv: torch.Tensor, mode: str, boundary: str):
    """level (B, C, h, w), uv (B, H, W, 2) -> (B, C, H, W)."""
    if boundary == "wrap":
        h, w = level.shape[-2:]
        padded = F.pad(level, (1, 1, 1, 1), mode="circular")
        frac = torch.remainder(uv, 1.0)
        size = uv.new_tensor([w, h])
        grid = 2 * (frac * size + 1) / (size + 2) - 1
        return F.grid_sample(padded, grid, mode=mode, padding_mode="border",
                             align_corners=False)
    padding = "border" if boundary == "clamp" else "zeros"
    return F.grid_sample(level, 2 * uv - 1, mode=mode, padding_mode=padding,
                         align_corners=False)


def mip_level(uv_da: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Seed 003's level, 0.5 log2(lenMajorSqr), from uv_da (B, H, W, 4)."""
    a, b = uv_da[..., 0] * width, uv_da[..., 1] * width
    c, d = uv_da[..., 2] * height, uv_da[..., 3] * height
    A, B, C = a * a + c * c, b * b + d * d, a * b + c * d
    major = (A + B) / 2 + torch.sqrt(((A - B) / 2) ** 2 + C * C)
    return 0.5 * torch.log2(major)


def texture(tex, uv, uv_da=None, mip_level_bias=None, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None):
    """glraster.torch.texture's filters in plain PyTorch (2-D, power-of-two extents).
    tex (B or 1, H, W, C), uv (B, H', W', 2) -> (B, H', W', C)."""
    if filter_mode == "auto":
        filter_mode = "linear-mipmap-linear" if (uv_da is not None or mip_level_bias is not None) \
            else "linear"
    base = tex.permute(0, 3, 1, 2)
    if base.shape[0] != uv.shape[0]:
        base = base.expand(uv.shape[0], -1, -1, -1)
    if filter_mode in ("nearest", "linear"):
        mode = "nearest" if filter_mode == "nearest" else "bilinear"
        return _sample(base, uv, mode, boundary_mode).permute(0, 2, 3, 1)
    levels = _pyramid(base, max_mip_level)
    level = uv.new_zeros(uv.shape[:3])
    if uv_da is not None:
        level = mip_level(uv_da, tex.shape[1], tex.shape[2])
    if mip_level_bias is not None:
        level = level + mip_level_bias
    level = level.clamp(0, len(levels) - 1)
    out = 0
    for k, lv in enumerate(levels):
        if filter_mode == "linear-mipmap-nearest":
            weight = (torch.floor(level.detach() + 0.5) == k).to(uv.dtype)
        else:
            weight = (1 - (level - k).abs()).clamp(min=0)
        out = out + _sample(lv, uv, "bilinear", boundary_mode) * weight[:, None]
    return out.permute(0, 2, 3, 1)


# cube faces +x, -x, +y, -y, +z, -z (GL table 8.19): (axis, sign) of s_c, t_c and of m
_CUBE_FACES = (((2, -1), (1, -1), (0, 1)), ((2, 1), (1, -1), (0, -1)),
               ((0, 1), (2, 1), (1, 1)), ((0, 1), (2, -1), (1, -1)),
               ((0, 1), (1, -1), (2, 1)), ((0, -1), (1, -1), (2, -1)))


def cube_texture(tex, direction):
    """A cube map looked up with linear filtering in plain PyTorch, the way one would
    without a custom kernel: each pixel's major face by GL's rule (ties to x, then y), its
    face coordinates 2 s - 1 = s_c / m (GL table 8.19), and per face one ``grid_sample``
    of that face's pixels (border padding: a tap past a face edge clamps to the face
    instead of reading the neighbouring face, so this differs from glraster within a
    texel of the edges). tex (1, 6, N, N, C), direction (B, H, W, 3) -> (B, H, W, C)."""
    a = direction.detach().abs()
    x_major = (a[..., 0] >= a[..., 1]) & (a[..., 0] >= a[..., 2])
    y_major = ~x_major & (a[..., 1] >= a[..., 2])
    axis = torch.where(x_major, 0, torch.where(y_major, 1, 2))
    positive = torch.gather(direction.detach(), -1, axis[..., None])[..., 0] >= 0
    face = 2 * axis + (~positive).long()
    flat = direction.reshape(-1, 3)
    faces = face.reshape(-1)
    out = flat.new_zeros(flat.shape[0], tex.shape[-1])
    for f, ((sa, ss), (ta, ts), (ma, ms)) in enumerate(_CUBE_FACES):
        rows = torch.nonzero(faces == f)[:, 0]
        if rows.numel() == 0:
            continue
        d = flat[rows]
        m = ms * d[:, ma]
        grid = torch.stack([ss * d[:, sa] / m, ts * d[:, ta] / m], dim=-1)
        sample = F.grid_sample(tex[:, f].permute(0, 3, 1, 2), grid[None, None], mode="bilinear",
                               padding_mode="border", align_corners=False)
        out = out.index_put((rows,), sample[0, :, 0].t())
    return out.reshape(*direction.shape[:3], tex.shape[-1])


# --------------------------------------------------------------------------- benchmark


def perspective_inputs(size: int, channels: int = 4, seed: int = 0):
    """A size x size image of a size x size texture seen in perspective (levels ~0 .. 3):
    tex (1, size, size, channels) uniform in [0, 1), uv (1, size, size, 2) and its screen
    derivatives uv_da (1, size, size, 4), float32."""
    g = torch.Generator().manual_seed(seed)
    tex = torch.rand(1, size, size, channels, generator=g)
    ys, xs = torch.meshgrid(torch.arange(size) + 0.5, torch.arange(size) + 0.5, indexing="ij")
    depth = 1.0 + 3.0 * ys / size                       # farther up the image
    s = (xs - size / 2) / size * 2.0 / depth + 0.5
    t = 1.0 / depth
    uv = torch.stack([s, t], dim=-1)[None].contiguous()
    ds_dx = 2.0 / size / depth
    ds_dy = -(xs - size / 2) / size * 2.0 * (3.0 / size) / depth ** 2
    dt_dy = -(3.0 / size) / depth ** 2
    uv_da = torch.stack([ds_dx, ds_dy, torch.zeros_like(ds_dx), dt_dy], dim=-1)[None]
    return tex, uv, uv_da.contiguous()


def cube_inputs(size: int, channels: int = 4, seed: int = 0):
    """A size x size view (90 degrees across) toward a corner of a cube map of six
    n x n faces, n = max(1, size // 2) (1.5 size² texels, about the 2-D cells' size²; at
    1024² six 1024² faces would need 192 MiB of deterministic sums, more than llvmpipe's
    128 MiB storage block), so that three faces and their shared corner are seen:
    tex (1, 6, n, n, channels) uniform in [0, 1), directions (1, size, size, 3), float32."""
    g = torch.Generator().manual_seed(seed)
    n = max(1, size // 2)
    tex = torch.rand(1, 6, n, n, channels, generator=g)
    forward = torch.tensor([1.0, 0.8, 0.6])
    forward = forward / forward.norm()
    right = torch.linalg.cross(forward, torch.tensor([0.0, 1.0, 0.0]))
    right = right / right.norm()
    up = torch.linalg.cross(right, forward)
    ys, xs = torch.meshgrid((torch.arange(size) + 0.5) / size * 2 - 1,
                            (torch.arange(size) + 0.5) / size * 2 - 1, indexing="ij")
    d = forward + xs[..., None] * right + ys[..., None] * up
    return tex, d[None].contiguous().float()


MODES = ("nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear", "cube")


def _cell(size: int, mode: str, boundary_mode: str):
    """(inputs tex, uv, uv_da; the texture call's keyword arguments; the yardstick) of one
    bench cell; "cube" is linear filtering of a cube map (:func:`cube_inputs`)."""
    if mode == "cube":
        tex, d = cube_inputs(size)
        return (tex, d, None), dict(filter_mode="linear", boundary_mode="cube"), \
            lambda t, u, _d, _b, **_: cube_texture(t, u)
    tex, uv, uv_da = perspective_inputs(size)
    da = uv_da if mode.startswith("linear-mipmap") else None
    return (tex, uv, da), dict(filter_mode=mode, boundary_mode=boundary_mode), texture


def benchmark(sizes=(512, 1024), repeat: int = 5, boundary_mode: str = "wrap", modes=MODES,
              clock=None):
    """Rows (size, mode, glraster ms, plain PyTorch ms, glraster / PyTorch median, its
    lowest and highest round, max |difference|, p99.9 |difference|) of forward + backward
    (gradients to tex and uv, and uv_da in the mipmapped modes): ``repeat`` rounds after a
    warm-up one, each timing one glraster call and one PyTorch call (which goes first
    alternates), medians over the rounds, so both sides see the same load. ``clock``: wall
    time by default; ``time.process_time`` counts the process's CPU time (PyTorch's and
    llvmpipe's threads included), which swings less than wall time on shared cores."""
    import statistics
    import time

    import glraster.torch as dr

    clock = clock or time.perf_counter
    rows = []
    for size in sizes:
        for mode in modes:
            (tex, uv, da), params, yardstick = _cell(size, mode, boundary_mode)
            results = {}

            def run(impl, key):
                t = tex.clone().requires_grad_()
                u = uv.clone().requires_grad_()
                d = None if da is None else da.clone().requires_grad_()
                out = impl(t, u, d, None, **params)
                out.backward(torch.ones_like(out))
                results[key] = out.detach()

            sides = {"gl": lambda: run(dr.texture, "gl"), "pt": lambda: run(yardstick, "pt")}
            times = {"gl": [], "pt": []}
            for k in range(repeat + 1):              # round 0 warms up
                for key in (("gl", "pt") if k % 2 else ("pt", "gl")):
                    start = clock()
                    sides[key]()
                    times[key].append(clock() - start)
            ratios = [a / b for a, b in zip(times["gl"][1:], times["pt"][1:])]
            diff = (results["gl"] - results["pt"]).abs()
            rows.append((size, mode, 1e3 * statistics.median(times["gl"][1:]),
                         1e3 * statistics.median(times["pt"][1:]), statistics.median(ratios),
                         min(ratios), max(ratios), float(diff.max()),
                         float(diff.flatten().kthvalue(max(1, math.ceil(0.999 * diff.numel())))
                               .values)))
    return rows


def core_benchmark(sizes=(512, 1024), repeat: int = 5, boundary_mode: str = "wrap",
                   modes=MODES, clock=None):
    """Rows (size, mode, forward ms, backward ms atomic, backward ms deterministic,
    deterministic / atomic median over rounds, its lowest and highest round) of the GPU
    core alone (:mod:`glraster.diff.texture`, NumPy in and out), on the inputs of
    :func:`benchmark`; each round times the three calls in turn, medians over rounds.
    ``clock``: wall time by default; ``time.process_time`` counts the process's CPU time,
    llvmpipe's threads included (steadier than wall time on shared cores)."""
    import statistics
    import time

    from glraster.diff import texture as gpu

    clock = clock or time.perf_counter
    rows = []
    for size in sizes:
        for mode in modes:
            (tex, uv, da), params, _ = _cell(size, mode, boundary_mode)
            tex, uv = tex.numpy(), uv.numpy()
            da = None if da is None else da.numpy()
            g = np.ones(uv.shape[:3] + (tex.shape[-1],), np.float32)
            (_,), saved = gpu.forward(tex, uv, da, None, **params)
            calls = {"forward": lambda: gpu.forward(tex, uv, da, None, **params),
                     "atomic": lambda: gpu.backward(saved, g),
                     "deterministic": lambda: gpu.backward(saved, g, deterministic=True)}
            times = {name: [] for name in calls}
            for _ in range(repeat + 1):           # the first round warms up
                for name, call in calls.items():
                    start = clock()
                    call()
                    times[name].append(clock() - start)
            ratios = [d / a for d, a in zip(times["deterministic"][1:], times["atomic"][1:])]
            rows.append((size, mode, *(1e3 * statistics.median(t[1:]) for t in times.values()),
                         statistics.median(ratios), min(ratios), max(ratios)))
    return rows


def clear_benchmark(sizes=(512, 1024), repeat: int = 5, clock=None):
    """Rows (size, MiB, ms) of the driver's clear of the backward's texel-gradient buffer
    of a size x size RGBA texture without mips (one ``glClearNamedBufferSubData`` call, as
    :mod:`glraster.diff.texture` does, waited for), for float sums and for the
    deterministic 64-bit ones; medians of ``repeat`` calls after one."""
    import statistics
    import time

    from glraster.diff import texture as gpu
    from glraster.gpu.context import default_context

    clock = clock or time.perf_counter
    ctx = default_context()
    rows = []
    with ctx:
        for size in sizes:
            for nbytes in (size * size * 16, size * size * 32):
                times = []
                for _ in range(repeat + 1):
                    start = clock()
                    gpu._cleared(ctx, "texture.grad_tex", nbytes)
                    ctx.mgl.finish()
                    times.append(clock() - start)
                rows.append((size, nbytes / 2**20, 1e3 * statistics.median(times[1:])))
    return rows


def build_parser():
    from glraster.studies.registry import argument_parser

    parser = argument_parser(
        "texture-baseline",
        "Time glraster.torch.texture against the same filters in plain PyTorch "
        "(grid_sample + autograd): forward + backward for every filter mode, one square "
        "image and texture per size, 4 channels. Prints a Markdown table "
        "(docs/differentiable.md, 'Speed').")
    parser.add_argument("--sizes", type=int, nargs="+", default=[512, 1024], metavar="N",
                        help="image and texture sizes, powers of two (default: 512 1024)")
    parser.add_argument("--repeat", type=int, default=5, metavar="K",
                        help="timed calls per cell, the median is shown (default 5)")
    parser.add_argument("--boundary", default="wrap", choices=("wrap", "clamp", "zero"),
                        help="boundary_mode (default wrap)")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES,
                        metavar="MODE", help="filter modes, and cube (linear filtering of a "
                        "cube map seen toward a corner) (default: all five)")
    parser.add_argument("--cores", action="store_true",
                        help="instead: the GPU core's forward and its backward (atomic and "
                        "deterministic) alone, NumPy in and out")
    parser.add_argument("--cpu-time", action="store_true",
                        help="time the process's CPU time (PyTorch's and llvmpipe's threads "
                        "included) instead of wall time, steadier on shared cores")
    return parser


def main(argv=None) -> int:  # pragma: no cover - a measurement, not a test
    import time

    parser = build_parser()
    args = parser.parse_args(argv)
    for size in args.sizes:
        if size < 2 or size & (size - 1):
            parser.error(f"--sizes must be powers of two >= 2, got {size}")
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    torch.set_num_threads(max(1, torch.get_num_threads()))
    clock = time.process_time if args.cpu_time else time.perf_counter
    what = "CPU time of the process" if args.cpu_time else "wall time"
    if args.cores:
        print(f"glraster.diff.texture alone, {what}, median of {args.repeat} rounds, texture = "
              f"image size, 4 channels, {args.boundary} (cube: linear, six (N/2)² faces)")
        print("| image and texture | mode | forward ms | backward atomic ms | "
              "backward deterministic ms | deterministic / atomic [rounds] |")
        print("|---|---|---|---|---|---|")
        for size, mode, fwd, atomic, det, ratio, low, high in core_benchmark(
                tuple(args.sizes), args.repeat, args.boundary, args.modes, clock):
            print(f"| {size}² | {mode} | {fwd:.1f} | {atomic:.1f} | {det:.1f} | "
                  f"{ratio:.2f} [{low:.2f} .. {high:.2f}] |")
        print("clearing the texel-gradient buffer (one driver call, no mips): " + ", ".join(
            f"{size}² {mib:.0f} MiB {ms:.2f} ms" for size, mib, ms in
            clear_benchmark(tuple(args.sizes), args.repeat, clock)))
        return 0
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; forward + backward, "
          f"{what}, median of {args.repeat} interleaved rounds, texture = image size, 4 channels, "
          f"{args.boundary} (cube: linear, six (N/2)² faces)")
    print("| image and texture | mode | glraster.torch (GL) ms | plain PyTorch ms | "
          "glraster / PyTorch [rounds] | max / p99.9 |out difference| |")
    print("|---|---|---|---|---|---|")
    for size, mode, gl, pt, ratio, low, high, dmax, d999 in benchmark(
            tuple(args.sizes), args.repeat, args.boundary, args.modes, clock):
        print(f"| {size}² | {mode} | {gl:.1f} | {pt:.1f} | {ratio:.2f} [{low:.2f} .. "
              f"{high:.2f}] | {dmax:.1e} / {d999:.1e} |")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
