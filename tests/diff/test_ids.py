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


def test_decoding_a_strided_channel_inverts_the_encoding():
    """rast[..., 3] is decoded in place (a strided view), large ids included."""
    rng = np.random.default_rng(0)
    index = rng.integers(-1, ids.MAX_ID, (2, 5, 7))
    index[0, 0, :3] = [-1, 2**24 - 1, 2**24]
    rast = np.zeros(index.shape + (4,), np.float32)
    rast[..., 3] = ids.encode_ids(index)
    assert np.array_equal(ids.decode_ids(rast[..., 3]), index)
    assert np.array_equal(ids.decode_ids(rast[..., 3].astype(np.float64)), index)


@pytest.mark.parametrize("bad", [-np.inf, np.inf, -1.0, 3.5, np.nan, -0.5])
def test_the_first_bad_value_is_the_one_reported(bad):
    values = np.zeros((3, 4), np.float32)
    values[1, 2] = bad
    values[2, 0] = 0.25                        # a later bad value is not the one named
    with pytest.raises(ArgumentError, match=r"at \(1, 2\)"):
        ids.decode_ids(values)
