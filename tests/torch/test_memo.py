"""Remembered no-gradient calls (glraster.diff.memo, through glraster.torch): a call that repeats an earlier one
bit for bit returns copies of its outputs without running the core; any difference (a
bit of an input, an in-place change of an input or output, a keyword argument, an input
requiring a gradient) runs the core, whose result is then the fresh one. Outputs are
compared exactly: a remembered result is the core's result, not an approximation."""

from __future__ import annotations

import pytest
import torch

import glraster.torch as dr
from glraster.diff import memo
from glraster.torch import bridge


@pytest.fixture
def glctx(ctx):
    memo.forget()
    yield dr.RasterizeGLContext(context=ctx)
    memo.forget()


@pytest.fixture
def core_runs(monkeypatch):
    """The core calls (forward or backward) run since the test began (a list)."""
    runs = []
    original = bridge._run

    def counted(gl, entries, work):
        runs.append(work)
        return original(gl, entries, work)

    monkeypatch.setattr(bridge, "_run", counted)
    return runs


def _pos(z=0.25):
    return torch.tensor([[[-0.8, -0.7, z, 1.0], [0.9, -0.6, 0.1, 1.0], [0.1, 0.8, 0.3, 1.2]],
                         [[-0.5, -0.9, 0.2, 1.0], [0.7, 0.2, z, 1.1], [-0.2, 0.9, 0.0, 1.0]]])


TRI = torch.tensor([[0, 1, 2]], dtype=torch.int32)


def _render(glctx, pos, tex):
    """rasterize -> interpolate (with derivatives) -> two texture lookups, as a target
    render does: each output."""
    rast, db = dr.rasterize(glctx, pos, TRI, (16, 12))
    uv, uv_da = dr.interpolate(pos[..., :2].contiguous(), rast, TRI, rast_db=db,
                               diff_attrs="all", glctx=glctx)
    near = dr.texture(tex, uv, filter_mode="nearest", glctx=glctx)
    trilinear = dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear", glctx=glctx)
    return rast, db, uv, uv_da, near, trilinear


def _equal_bits(got, want):
    for g, w in zip(got, want):
        assert torch.equal(g.view(torch.int32), w.view(torch.int32))


def test_a_repeated_no_grad_render_runs_no_core_and_returns_the_same_bits(glctx, core_runs):
    tex = torch.rand(1, 8, 8, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        first = _render(glctx, _pos(), tex)
        ran = len(core_runs)
        again = _render(glctx, _pos(), tex.clone())  # equal inputs, other tensors
    assert ran == 4 and len(core_runs) == ran
    _equal_bits(again, first)
    assert all(a.data_ptr() != f.data_ptr() for a, f in zip(again, first))  # copies


def test_inputs_requiring_no_gradient_are_remembered_with_grad_mode_on(glctx, core_runs):
    pos = _pos()
    dr.rasterize(glctx, pos, TRI, (16, 12))
    dr.rasterize(glctx, pos.clone(), TRI, (16, 12))
    assert len(core_runs) == 1


def test_a_call_a_gradient_flows_through_always_runs(glctx, core_runs):
    pos = _pos().requires_grad_()
    first, _ = dr.rasterize(glctx, pos, TRI, (16, 12))
    again, _ = dr.rasterize(glctx, pos, TRI, (16, 12))
    assert len(core_runs) == 2 and again.grad_fn is not None


@pytest.mark.parametrize("change", ["other bits", "negative zero", "in place", "resolution",
                                    "tri"])
def test_any_difference_runs_the_core(glctx, core_runs, change):
    pos, tri, resolution = _pos(z=0.0), TRI, (16, 12)
    with torch.no_grad():
        dr.rasterize(glctx, pos, tri, resolution)
        if change == "other bits":
            pos = pos.clone()
            pos[1, 1, 0] = torch.nextafter(pos[1, 1, 0], torch.tensor(2.0))
        elif change == "negative zero":
            pos = pos.clone()
            pos[0, 0, 2] = -0.0
        elif change == "in place":
            pos[0, 2, 1] -= 0.5  # the remembered input itself: its version moves on
        elif change == "resolution":
            resolution = (12, 16)
        else:
            tri = TRI[:, [1, 2, 0]].contiguous()
        got = dr.rasterize(glctx, pos, tri, resolution)
    assert len(core_runs) == 2
    memo.forget()
    with torch.no_grad():
        want = dr.rasterize(glctx, pos, tri, resolution)
    _equal_bits(got, want)


def test_an_output_changed_in_place_is_not_handed_out_again(glctx, core_runs):
    with torch.no_grad():
        rast, _ = dr.rasterize(glctx, _pos(), TRI, (16, 12))
        want = rast.clone()
        rast.zero_()
        again, _ = dr.rasterize(glctx, _pos(), TRI, (16, 12))
    assert len(core_runs) == 2
    _equal_bits([again], [want])


def test_copies_handed_out_are_independent(glctx, core_runs):
    with torch.no_grad():
        want, _ = dr.rasterize(glctx, _pos(), TRI, (16, 12))
        want = want.clone()
        second, _ = dr.rasterize(glctx, _pos(), TRI, (16, 12))
        second.fill_(7.0)
        third, _ = dr.rasterize(glctx, _pos(), TRI, (16, 12))
    assert len(core_runs) == 1
    _equal_bits([third], [want])


def test_contexts_do_not_share_calls_and_forget_drops_them(glctx, core_runs, ctx):
    other = dr.RasterizeGLContext(context=ctx)  # the same GL context: the same table
    with torch.no_grad():
        dr.rasterize(glctx, _pos(), TRI, (16, 12))
        dr.rasterize(other, _pos(), TRI, (16, 12))
        assert len(core_runs) == 1
        memo.forget(ctx)
        dr.rasterize(glctx, _pos(), TRI, (16, 12))
    assert len(core_runs) == 2


def test_at_most_entries_calls_are_held_least_recently_used_dropped(glctx, core_runs):
    with torch.no_grad():
        for k in range(memo.ENTRIES + 1):
            dr.rasterize(glctx, _pos(z=0.01 * k), TRI, (16, 12))
        dr.rasterize(glctx, _pos(z=0.01 * memo.ENTRIES), TRI, (16, 12))  # held
        assert len(core_runs) == memo.ENTRIES + 1
        dr.rasterize(glctx, _pos(z=0.0), TRI, (16, 12))  # the first: dropped
    assert len(core_runs) == memo.ENTRIES + 2


def test_a_call_larger_than_max_bytes_is_not_held(glctx, core_runs, monkeypatch):
    monkeypatch.setattr(memo, "MAX_BYTES", 1024)  # rast and rast_db: 2 x 2 x 16 x 12 x 16 B
    with torch.no_grad():
        dr.rasterize(glctx, _pos(), TRI, (16, 12))
        dr.rasterize(glctx, _pos(), TRI, (16, 12))
    assert len(core_runs) == 2


def test_arrays_match_only_when_every_bit_is_the_same():
    # _same_bits: a spread sample first, then 8-byte words where both arrays are
    # C-contiguous, element by element otherwise (a strided view against a copy)
    np = pytest.importorskip("numpy")
    a = np.random.default_rng(0).uniform(-1, 1, (2, 64, 64, 3)).astype(np.float32)
    assert memo._same(a, a.copy()) and memo._same(a, np.asfortranarray(a))
    for index in [(0, 0, 0, 0), (1, 63, 63, 2), (1, 20, 7, 1)]:  # off the sample too
        b = a.copy()
        b[index] = np.nextafter(b[index], np.float32(2))
        assert not memo._same(a, b) and not memo._same(np.asfortranarray(a), b)
    zeros = np.zeros(10, np.float32)
    assert not memo._same(zeros, -zeros) and memo._same(zeros[::2], zeros[::2].copy())
    odd = np.arange(3, dtype=np.int32)  # 12 bytes: no whole number of 8-byte words
    assert memo._same(odd, odd.copy()) and not memo._same(odd, odd[::-1].copy())


def test_the_sample_spans_channels_and_columns_not_one_stride():
    # a plain stride of (V, 6) interleaved attributes or (N, 256, 256, 3) images hits one
    # channel or one image column: arrays equal there (normals, an empty border) passed
    np = pytest.importorskip("numpy")
    for shape in [(2, 15488, 6), (2, 256, 256, 3), (65,), (1000, 7)]:
        size = int(np.prod(shape))
        at = memo._probe(size)
        assert len(np.unique(at)) == memo.PROBE and at.min() >= 0 and at.max() < size
    attrs = memo._probe(2 * 15488 * 6)
    assert len(np.unique(attrs % 6)) == 6
    pixels = memo._probe(2 * 256 * 256 * 3) // 3
    assert len(np.unique(pixels % 256)) > memo.PROBE // 2   # columns
    a = np.zeros((2, 15488, 6), np.float32)
    b = a.copy()
    b[..., 3:] = 1.0  # the same in channel 0 (where a stride lands), not elsewhere
    assert not np.array_equal(a.reshape(-1)[attrs], b.reshape(-1)[attrs])
