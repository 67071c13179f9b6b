"""pytest-benchmark timings (not run by `make test`: pyproject's addopts has
--benchmark-skip). Run with `pytest benchmarks --benchmark-enable` or
`pytest benchmarks --benchmark-only`. The `glraster bench` command measures the same things
with interleaved A/B pairs against the fill limit and the reference; these are for
tracking regressions with pytest-benchmark's own statistics and comparison tools."""

from __future__ import annotations

import pytest

import glraster as gr
from glraster import reference
from glraster.studies.bench import make_bench_scene
from glraster.studies.fill_limit import FillLimit
from glraster.gpu.rasterize import METHODS


@pytest.fixture(scope="module")
def terrain():
    return make_bench_scene("terrain", 20000)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_method_1024_20k(benchmark, ctx, terrain, method):
    benchmark(gr.rasterize, terrain.pos, terrain.faces, (1024, 1024), ctx=ctx, method=method)


def test_fill_limit_1024_20k(benchmark, ctx, terrain):
    fill = FillLimit(ctx, terrain.pos, terrain.faces, (1024, 1024))
    benchmark(fill.run)
    fill.release()


@pytest.mark.parametrize("method", sorted(METHODS))
def test_overhead_64x64_one_triangle(benchmark, ctx, method):
    one = make_bench_scene("terrain", 1)
    benchmark(gr.rasterize, one.pos, one.faces, (64, 64), ctx=ctx, method=method)


def test_reference_1024_20k(benchmark, terrain):
    benchmark.pedantic(reference.rasterize, (terrain.pos, terrain.faces, (1024, 1024)),
                       rounds=3, iterations=1)
