"""An interpolate whose tri indexes past attr's rows names attr (it named pos, which
interpolate does not take), in every front end: torch and the op (checked once, for both
of its cores)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from glraster.diff.ops import INTERPOLATE

TRI = np.array([[0, 1, 2], [1, 3, 2]], np.int32)     # indexes vertices 0..3
ATTR = np.ones((3, 2))                               # one row short
RAST = np.zeros((1, 4, 4, 4))                        # empty pixels: only validation runs
MESSAGE = r"^tri index 3 is out of range for attr with 3 rows \(vertices\)$"


def test_torch_interpolate_names_attr():
    with pytest.raises(ValueError, match=MESSAGE):
        dr.interpolate(torch.tensor(ATTR), torch.tensor(RAST), torch.tensor(TRI))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_op_interpolate_names_attr(dtype):
    # the check runs before either core, so this needs no GL
    with pytest.raises(ValueError, match=MESSAGE):
        INTERPOLATE.forward(ATTR.astype(dtype), RAST.astype(dtype), tri=TRI)


def test_rasterize_still_names_pos():
    from glraster import validate

    with pytest.raises(ValueError, match=r"^tri index 3 is out of range for pos with 3 "
                                         r"vertices$"):
        validate.triangles(TRI, 3)
