"""pytest-benchmark timings of the differentiable ops (not run by `make test`: pyproject's
addopts has --benchmark-skip). Run with `pytest benchmarks/test_bench_diff.py
--benchmark-enable` (or `--benchmark-only`). `glraster bench-diff` measures the same calls
in interleaved rounds and reports the ratios against their goals (docs/differentiable.md,
"Speed"); these track regressions with pytest-benchmark's own statistics and comparison
tools. The scene is the benchmark terrain at 1024x1024 with 20k triangles."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

import glraster as gr  # noqa: E402
import glraster.torch as dr  # noqa: E402
from glraster.diff import interpolate as core_interpolate  # noqa: E402
from glraster.diff import rasterize as core_rasterize  # noqa: E402
from glraster.diff.ops import INTERPOLATE, RASTERIZE  # noqa: E402
from glraster.studies.bench import make_bench_scene  # noqa: E402
from glraster.studies import torch_interpolate_baseline as baseline  # noqa: E402

RESOLUTION = (1024, 1024)
ATTRIBUTES = 4


@pytest.fixture(scope="module")
def inputs(ctx):
    scene = make_bench_scene("terrain", 20000)
    (pos,), params = RASTERIZE.check(scene.pos, tri=scene.faces, resolution=RESOLUTION,
                                     ctx=ctx)
    (rast, rast_db), saved = core_rasterize.forward(pos, **params)
    rng = np.random.default_rng(0)
    normal = lambda *shape: rng.standard_normal(shape).astype(np.float32)  # noqa: E731
    return {"pos": pos, "params": params, "saved": saved, "tri": params["tri"],
            "rast": rast, "rast_db": rast_db,
            "grad_rast": normal(*rast.shape), "grad_db": normal(*rast.shape),
            "attr": normal(len(scene.pos), ATTRIBUTES),
            "grad_out": normal(*rast.shape[:3], ATTRIBUTES),
            "grad_out_da": normal(*rast.shape[:3], 2 * ATTRIBUTES)}


@pytest.mark.parametrize("grad_db", [False, True], ids=["rast", "rast+db"])
def test_rasterize_forward(benchmark, ctx, inputs, grad_db):
    benchmark(core_rasterize.forward, inputs["pos"], **dict(inputs["params"], grad_db=grad_db))


@pytest.mark.parametrize("deterministic", [False, True], ids=["atomic", "deterministic"])
def test_rasterize_backward(benchmark, ctx, inputs, deterministic):
    benchmark(core_rasterize.backward, inputs["saved"], inputs["grad_rast"], inputs["grad_db"],
              deterministic=deterministic)


@pytest.mark.parametrize("deterministic", [False, True], ids=["atomic", "deterministic"])
def test_interpolate_backward(benchmark, ctx, inputs, deterministic):
    _, saved = INTERPOLATE.forward(inputs["attr"], inputs["rast"], inputs["rast_db"],
                                   tri=inputs["tri"], diff_attrs="all", ctx=ctx)
    benchmark(core_interpolate.backward, saved, inputs["grad_out"], inputs["grad_out_da"],
              deterministic=deterministic)


@pytest.mark.parametrize("impl", ["glraster", "baseline"])
def test_interpolate_forward_backward_torch(benchmark, ctx, inputs, impl):
    """glraster.torch.interpolate against the same math in plain PyTorch (gather +
    autograd), forward + backward with A = 4 and diff_attrs="all"."""
    run = baseline.ForwardBackward(inputs["attr"], inputs["rast"], inputs["tri"],
                                   inputs["rast_db"], inputs["grad_out"],
                                   inputs["grad_out_da"], diff_attrs="all",
                                   glctx=dr.RasterizeGLContext(context=ctx))
    benchmark(run, impl)
