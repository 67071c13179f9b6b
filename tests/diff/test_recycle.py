"""glraster.diff.recycle: an array is handed out again only once nothing references it
(neither a view, nor a tensor sharing it), and then in the same memory; no GL. Each test
asks for a shape of its own (the pool is the process's)."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from glraster.diff import recycle
from glraster.diff.address import address


def _shape(k: int):
    shape = (2, 256, 256 + k, 4)                    # 2 MiB of float32 or more
    assert 4 * np.prod(shape) >= recycle.MIN_BYTES
    return shape


def test_a_free_array_is_handed_out_again_in_the_same_memory():
    first = recycle.empty(_shape(1))
    assert first.shape == _shape(1) and first.dtype == np.float32
    assert first.flags.c_contiguous and first.flags.writeable
    where = address(first)
    del first
    assert address(recycle.empty(_shape(1))) == where


def test_an_array_still_referenced_is_not_handed_out():
    held = recycle.empty(_shape(2))
    view = recycle.empty(_shape(2))[1:]             # a view holds its base
    taken = {address(held), address(view.base)}
    assert len(taken) == 2
    fresh = recycle.empty(_shape(2))
    assert address(fresh) not in taken
    held[...] = 1.0
    view[...] = 2.0
    fresh[...] = 3.0
    assert (held == 1.0).all() and (view == 2.0).all()
    del view
    assert address(recycle.empty(_shape(2))) in taken   # (the view's base, free again)


def test_an_array_a_tensor_shares_is_not_handed_out_until_the_tensor_is_gone():
    torch = pytest.importorskip("torch")
    tensor = torch.from_numpy(recycle.empty(_shape(3)))
    other = recycle.empty(_shape(3))
    assert address(other) != tensor.data_ptr()
    where = tensor.data_ptr()
    del tensor, other
    gc.collect()
    kept = [recycle.empty(_shape(3)) for _ in range(2)]    # (both free again)
    assert where in {address(a) for a in kept}


def test_every_hand_out_is_a_new_object_whose_life_is_its_own():
    """A cache keyed by a weak reference to the array sees the hand-out end, though the
    memory is used again."""
    first = recycle.empty(_shape(4))
    ref, where = weakref.ref(first), address(first)
    del first
    assert ref() is None
    second = recycle.empty(_shape(4))
    assert address(second) == where and ref() is None


def test_small_arrays_are_plain_new_arrays_and_dtypes_are_kept():
    small = recycle.empty((4, 4))
    assert small.base is None and small.shape == (4, 4) and small.dtype == np.float32
    ints = recycle.empty(_shape(5), np.uint32)
    assert ints.dtype == np.uint32 and ints.shape == _shape(5)
