"""The interpolate forward reads each chunk of pixels straight into its rows of out and
out_da: split into many chunks, it returns the bits of one dispatch."""

import numpy as np

from glraster.diff import compute
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from glraster.studies.torch_overhead import _scene


def test_chunked_forward_is_bit_identical(ctx, monkeypatch):
    pos, tri, _ = _scene(6)
    args, params = RASTERIZE.check(pos, tri=tri, resolution=(40, 56), grad_db=True, ctx=ctx)
    (rast, rast_db), _ = RASTERIZE.core(np.float32).forward(*args, **params)
    attr = np.random.default_rng(0).random((len(pos), 3), np.float32)
    inputs, params = INTERPOLATE.check(attr, rast, rast_db, tri=tri, diff_attrs=[2, 0, 2],
                                       ctx=ctx)
    core = INTERPOLATE.core(np.float32)
    (out, out_da), _ = core.forward(*inputs, **params)
    assert (rast[..., 3] > 0).mean() > 0.5 and np.abs(out_da).max() > 0
    monkeypatch.setattr(compute, "MAX_CHUNK_BYTES", 1)     # one work group a chunk
    (chunked, chunked_da), _ = core.forward(*inputs, **params)
    assert out.shape == (1, 40, 56, 3) and out_da.shape == (1, 40, 56, 6)
    assert np.array_equal(out.view(np.uint32), chunked.view(np.uint32))
    assert np.array_equal(out_da.view(np.uint32), chunked_da.view(np.uint32))
