"""`glraster demo`: rasterize built-in scenes on the GPU and the reference and compare.

Rasterize 500 random triangles and a shared-edge grid on the GPU and with the float64
reference, print the comparison, then run the conformance check (HTML report) and write
the distortion figure.
"""

from __future__ import annotations

import time
from pathlib import Path

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFolder, unwritable_reason


def register(subparsers) -> None:
    p = add_command(subparsers, "demo", __doc__)
    add_backend_argument(p)
    p.add_argument("--out", action=OutputFolder, default=None,
                   help="folder for reports and figures (default: out)")
    p.add_argument("--quick", action="store_true",
                   help="only the GPU-vs-reference comparison, no check or figure")
    p.set_defaults(func=run)


def compare_builtin(ctx) -> bool:
    """Print the GPU-vs-reference comparison of the built-in scenes; True when all pass."""
    from glraster import rasterize, reference
    from glraster.geometry import synthetic
    from glraster.verify.compare import compare
    from glraster.verify.tolerance import ErrorModel

    scenes = {
        "500 random triangles, w in [0.2, 20]": synthetic.random_soup(500, seed=1),
        "20x20 grid, shared edges, w in [0.5, 5]": synthetic.grid(20, 20, w_range=(0.5, 5)),
    }
    ok = True
    for name, (pos, tri) in scenes.items():
        start = time.perf_counter()
        gpu = rasterize(pos, tri, (256, 256), ctx=ctx)
        gpu_ms = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        ref = reference.rasterize(pos, tri, (256, 256),
                                  fill_rule="llvmpipe" if ctx.is_llvmpipe else None)
        ref_ms = (time.perf_counter() - start) * 1e3
        report = compare(gpu, ref, ErrorModel.for_context(ctx))
        print(f"\n== {name}  (GPU {gpu_ms:.1f} ms, reference {ref_ms:.1f} ms)")
        print(report.summary())
        ok &= report.ok()
    return ok


def run(args) -> int:
    from glraster.cli import main
    from glraster.gpu.context import Context

    out = Path(args.out or "out")
    reason = None if args.quick else unwritable_reason(out, folder=True)
    if reason is not None:   # (the default is judged here: --quick writes nothing)
        raise ArgumentError("--out", f"cannot write {out} ({reason})")
    ctx = Context(backend=args.backend)
    print(f"glraster demo on {ctx.backend}: {ctx.renderer}, {ctx.gl_version}")
    ok = compare_builtin(ctx)
    if args.quick:
        return exit_codes.OK if ok else exit_codes.FAIL
    backend = ["--backend", ctx.backend]
    print(f"\n== conformance check -> {out / 'report' / 'index.html'}")
    ok &= main(["check", *backend, "--html", str(out / "report")]) == 0
    print(f"\n== distortion figure -> {out / 'distortion'}")
    ok &= main(["distortion", *backend, "--out", str(out / "distortion")]) == 0
    return exit_codes.OK if ok else exit_codes.FAIL
