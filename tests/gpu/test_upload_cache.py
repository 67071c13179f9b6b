"""glraster.gpu.uploads.UploadCache on its own (no GL): a produced region is adopted only
by the call that produced it, never by a later one whose memory may be another array's."""

from __future__ import annotations

import weakref

from glraster.gpu.uploads import UploadCache


class _Owner:
    pass


def _entry(region, owner):
    return region, ("key", region, 0), weakref.ref(owner)


def test_an_adopted_region_is_held_under_its_key():
    cache, owner = UploadCache(), _Owner()
    region = (4096, 2048)
    added = cache.declare([])
    cache.produced("out", region)
    cache.undeclare(added)
    entry = _entry(region, owner)
    assert cache.adopt(entry)
    assert cache.held(entry[1:]) == "out"
    del owner
    assert cache.held(entry[1:]) is None            # (its owner collected)


def test_what_no_adopt_took_is_dropped_when_the_next_call_starts():
    cache, owner = UploadCache(), _Owner()
    region = (4096, 2048)
    cache.produced("out", region)                   # (a caller that adopts nothing)
    cache.undeclare(cache.declare([]))              # the next front-end call
    assert not cache.adopt(_entry(region, owner))   # (the same memory, another array)
    assert cache.held(("key", region, 0)) is None
