"""glraster.interpolate is an adapter over the differentiable interpolate: the same numbers
as the weighted sum it replaced, on GPU and reference rasters, in both spaces."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
import glraster.reference
from glraster.diff import ops
from glraster.geometry import synthetic
from glraster.interpolate import interpolate


def _weighted_sum(attr, raster, tri, space, normalize):
    """The definition, in float64: sum_k b_k attr[tri[t, k]] (divided by sum_k b_k)."""
    bary, tri_id = getattr(raster, space).astype(np.float64), raster.tri_id
    out = np.zeros(tri_id.shape + (attr.shape[1],))
    covered = tri_id >= 0
    b = bary[covered]
    vals = np.einsum("nk,nkc->nc", b, attr[tri[tri_id[covered]]])
    out[covered] = vals / b.sum(1, keepdims=True) if normalize else vals
    return out


@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("normalize", [True, False])
def test_adapter_equals_the_weighted_sum_on_gpu_and_reference_rasters(ctx, space, normalize):
    pos, tri = synthetic.random_soup(40, seed=7)
    attr = np.random.default_rng(3).normal(size=(len(pos), 3))
    gpu = gr.rasterize(pos, tri, (48, 64), ctx=ctx, outputs=(space, "tri_id"))
    ref = glraster.reference.rasterize(pos, tri, (48, 64), outputs=(space, "tri_id"))
    assert gpu.mask.sum() > 500
    for raster, dtype in ((gpu, np.float32), (ref, np.float64)):
        got = interpolate(attr, raster, tri, space, normalize=normalize)
        want = _weighted_sum(attr, raster, tri, space, normalize)
        assert got.dtype == dtype
        # The adapter divides the weights by their sum and multiplies back (normalize=False):
        # a few float64 roundings, relative 4 ulp of the largest term; the float32 result is
        # that rounded once, so within half a float32 ulp of the float64 value plus that.
        scale = np.abs(attr).max() * 3
        tol = 4 * np.finfo(np.float64).eps * scale
        if dtype == np.float32:
            tol += np.finfo(np.float32).eps / 2 * np.abs(want).max()
        np.testing.assert_allclose(got, want, rtol=0, atol=tol)
        assert np.all(got[raster.tri_id < 0] == 0)


def test_adapter_runs_the_float64_core_of_the_one_interpolate(monkeypatch):
    """The math lives in ops.INTERPOLATE: the adapter calls its float64 core once, in
    nvdiffrast's layout."""
    calls = []
    core = ops.INTERPOLATE.core(np.float64)

    class Spy:
        def forward(self, *inputs, **params):
            calls.append((inputs, params))
            return core.forward(*inputs, **params)

    def spy_core(self, dtype):
        assert np.dtype(dtype) == np.float64
        return Spy()

    monkeypatch.setattr(type(ops.INTERPOLATE), "core", spy_core)
    tri_id = np.array([[-1, 0], [1, -1]], np.int32)
    bary = np.zeros((2, 2, 3))
    bary[0, 1], bary[1, 0] = (0.5, 0.25, 0.25), (0.0, 0.0, 2.0)
    r = gr.Raster(resolution=(2, 2), mask=tri_id >= 0, persp=bary, tri_id=tri_id)
    out = interpolate(np.array([[4.0], [8.0], [16.0], [32.0]]), r, np.array([[0, 1, 2],
                                                                              [1, 2, 3]]))
    assert len(calls) == 1
    (attr, rast, rast_db), params = calls[0]
    assert rast.shape == (1, 2, 2, 4) and rast.dtype == np.float64 and attr.dtype == np.float64
    assert rast_db is None and params["diff_attrs"] is None
    np.testing.assert_array_equal(rast[0, 1, 0], [0.0, 0.0, 0.0, 2.0])   # id 2 = index 1 + 1
    # dyadic weights and values: exact
    assert out[0, 1, 0] == 0.5 * 4 + 0.25 * 8 + 0.25 * 16 and out[1, 0, 0] == 32.0
    assert out[0, 0, 0] == 0 and out[1, 1, 0] == 0


def test_barycentrics_summing_to_zero_cannot_be_normalized():
    tri_id = np.array([[0]], np.int32)
    r = gr.Raster(resolution=(1, 1), mask=tri_id >= 0, persp=np.zeros((1, 1, 3)),
                  tri_id=tri_id)
    with pytest.raises(gr.errors.ArgumentError, match=r"raster persp barycentrics sum to 0 "
                       r"at the covered pixel \(y=0, x=0\)") as info:
        interpolate(np.ones((3, 1)), r, [[0, 1, 2]])
    assert info.value.argument == "raster"
    assert interpolate(np.ones((3, 1)), r, [[0, 1, 2]], normalize=False)[0, 0, 0] == 0.0


def test_the_adapter_benchmark_runs_and_agrees_with_the_plain_sum(ctx, capsys):
    from glraster.studies import interpolate_adapter

    assert interpolate_adapter.main(["--sizes", "40x30", "--rounds", "1", "--calls", "1"]) == 0
    row = capsys.readouterr().out.splitlines()[-1].strip("| ").split(" | ")
    assert row[0] == "40x30" and int(row[1]) > 50
    # float32 results of the same float64 sum up to a few roundings: at most one float32
    # ulp of values below 4 (eye coordinates and w of a unit torus), 2^-22
    assert float(row[5]) <= 2.0 ** -22
