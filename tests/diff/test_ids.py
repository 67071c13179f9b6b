"""glraster.diff.ids: the triangle-id encoding's exact values and its errors (no GL; the
GLSL twin is checked against it in tests/gpu/test_shaders.py)."""

import numpy as np
import pytest

from glraster.diff import ids
from glraster.errors import ArgumentError


def test_encoding_is_the_value_then_the_bits_without_a_gap():
    enc = ids.encode_ids(np.array([-1, 0, 2**24 - 1, 2**24, ids.MAX_ID - 1]))
    assert enc[:3].tolist() == [0.0, 1.0, 2.0**24]          # id = index + 1, exact floats
    assert enc[3:].view(np.uint32).tolist() == [ids.ID_BIAS + 2**24 + 1, 0x7F7FFFFF]
    assert enc[3] == np.nextafter(np.float32(2**24), np.float32(np.inf))
    assert np.all(np.diff(enc) > 0)                          # ids order as floats


@pytest.mark.parametrize("call, argument, message", [
    (lambda: ids.encode_ids(np.array([0.5])), "tri_id", "tri_id must have an integer dtype"),
    (lambda: ids.encode_ids([-2]), "tri_id", r"tri_id must be >= -1 \(-1: empty\), got -2"),
    (lambda: ids.encode_ids([ids.MAX_ID]), "tri_id", "to encode as a finite float32"),
    (lambda: ids.decode_ids(np.array([1, 2])), "rast id channel", "must be a float array"),
    (lambda: ids.decode_ids(np.array([0.0, 2.5]), "rast"), "rast",
     r"rast must hold encoded triangle ids \(0: empty\), got 2\.5 at \(1,\)"),
    (lambda: ids.decode_ids(np.array([np.nan], np.float32)), "rast id channel", "got nan"),
])
def test_bad_values_raise_an_argument_error_naming_the_argument(call, argument, message):
    with pytest.raises(ArgumentError, match=message) as info:
        call()
    assert info.value.argument == argument
