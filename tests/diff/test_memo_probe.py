"""The memo's first compare (a sample of the elements) sees a difference that lies away
from the array's edges: two renders of one centred object differ in its middle only."""

import numpy as np

from glraster.diff import memo


def _rasters():
    a = np.zeros((4, 128, 128, 4), np.float32)
    a[:, 32:96, 32:96, :] = 0.5            # the object: the middle half of each image
    b = a.copy()
    b[:, 32:96, 32:96, :] = 0.25           # another view of it: the middle differs
    return a, b


def test_the_probe_meets_a_difference_in_the_middle_of_the_images():
    a, b = _rasters()
    at = memo._probe(a.size)
    assert len(at) == memo.PROBE and at.max() < a.size and len(np.unique(at)) == memo.PROBE
    assert not np.array_equal(a.reshape(-1)[at], b.reshape(-1)[at])


def test_same_bits_still_compares_everything_after_an_equal_probe():
    a, _ = _rasters()
    b = a.copy()
    at = memo._probe(a.size)
    untouched = np.setdiff1d(np.arange(a.size), at)[a.size // 2]
    b.reshape(-1)[untouched] = 7.0         # differs where the probe does not look
    assert memo._same_bits(a, a.copy())
    assert not memo._same_bits(a, b)
    c = a.copy()
    c.reshape(-1)[at[5]] = -0.0 if a.reshape(-1)[at[5]] == 0 else 0.0  # bits, not values
    assert not memo._same_bits(a, c)
