"""glraster.diff.ids: the triangle-id encoding's exact values and its errors (no GL; the
GLSL twin is checked against it in tests/gpu/test_shaders.py)."""

import numpy as np
import pytest

from glraster.diff import ids
from glraster.diff.ids import ID_BIAS, MAX_ID, decode_ids, encode_ids
from glraster.errors import ArgumentError


def test_encoding_is_the_value_then_the_bits_without_a_gap():
    enc = ids.encode_ids(np.array([-1, 0, 2**24 - 1, 2**24, ids.MAX_ID - 1]))
    assert enc[:3].tolist() == [0.0, 1.0, 2.0**24]          # id = index + 1, exact floats
    assert enc[3:].view(np.uint32).tolist() == [ids.ID_BIAS + 2**24 + 1, 0x7F7FFFFF]
    assert enc[3] == np.nextafter(np.float32(2**24), np.float32(np.inf))
    assert np.all(np.diff(enc) > 0)                          # ids order as floats


def test_bad_values_raise_an_argument_error_naming_the_argument(call, argument, message):
    with pytest.raises(ArgumentError, match=message) as info:
        call()
    assert info.value.argument == argument
