"""validate.triangles over every integer dtype and byte order: its one-reduction test (the
unsigned view's max) accepts exactly the index arrays its min / max test does."""

from __future__ import annotations

import numpy as np
import pytest

from glraster import validate
from glraster.errors import ArgumentError

DTYPES = ["i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", ">i4", "<i8", ">u2"]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("num_vertices", [1, 5, 127, 128, 200, 2 ** 15, 2 ** 31])
def test_same_verdict_as_min_max(dtype, num_vertices):
    dt = np.dtype(dtype)
    info = np.iinfo(dt)
    for values in ([0, 1, 4], [0, 0, 0], [0, info.max, 1], [0, info.min, 1], [-1, 0, 1],
                   [0, 127, 128], [0, 2 ** 14, 3], [4, 2 ** 24, 0]):
        arr = np.array([values, values[::-1]], dtype=object)
        lo, hi = min(values), max(values)
        if lo < info.min or hi > info.max:
            continue
        arr = arr.astype(dt)
        if lo < 0:
            with pytest.raises(ArgumentError, match=f"tri must hold indices >= 0, got {lo}"):
                validate.triangles(arr, num_vertices)
        elif hi >= num_vertices:
            with pytest.raises(ArgumentError, match=f"tri index {hi} is out of range"):
                validate.triangles(arr, num_vertices)
        else:
            out = validate.triangles(arr, num_vertices)
            assert out.dtype == np.int32 and out.flags.c_contiguous
            np.testing.assert_array_equal(out, np.array([values, values[::-1]]))


def test_strided_view():
    arr = np.array([[0, 1, 2, 9], [2, 1, 0, -1]], np.int32)[:, 2::-1]
    np.testing.assert_array_equal(validate.triangles(arr, 3), [[2, 1, 0], [0, 1, 2]])
    with pytest.raises(ArgumentError, match="tri must hold indices >= 0, got -1"):
        validate.triangles(np.array([[0, 1, 2, 9], [2, 1, 0, -1]], np.int32)[:, 1:], 3)
