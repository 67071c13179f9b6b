"""Headless contexts: backends, errors, the default context, caches and compile errors."""

from __future__ import annotations

import os
import resource

import numpy as np
import pytest

import glraster as gr
from glraster.gpu import backends
from glraster.geometry import synthetic
from glraster.gpu.backends import osmesa
from glraster.gpu.context import FRAMEBUFFER_CACHE_SIZE, default_context
from glraster.gpu.shaders import compile_program


def test_context_describes_its_driver(ctx):
    assert ctx.backend in ("egl", "osmesa")
    assert ctx.renderer and ctx.gl_version.startswith("4.")
    assert ctx.max_texture_size >= 4096
    assert ctx.subpixel_bits >= 4  # GL requires at least 4
    assert repr(ctx).startswith("glraster.Context(backend=")


def test_every_backend_on_this_machine_reports_its_name():
    for name in backends.available_backends():
        ctx = gr.Context(name)
        try:
            assert ctx.backend == name
        finally:
            ctx.release()


def test_environment_variable_chooses_the_backend(monkeypatch):
    available = backends.available_backends()
    monkeypatch.setenv("GLRASTER_BACKEND", available[-1])
    ctx = gr.Context(backend=None)
    try:
        assert ctx.backend == available[-1]
    finally:
        ctx.release()
    monkeypatch.setenv("GLRASTER_BACKEND", "vulkan")
    with pytest.raises(ValueError, match=r"backend must be one of .* got 'vulkan' \(from GLRASTER_BACKEND\)"):
        gr.Context(backend=None)


def test_unknown_backend_name():
    with pytest.raises(ValueError, match="backend must be one of 'auto', 'egl', 'osmesa', got 'wgl'"):
        gr.Context("wgl")


def test_missing_library_names_it_and_how_to_install(monkeypatch):
    monkeypatch.setattr(osmesa, "LIBRARY_NAMES", ("libOSMesa-missing.so",))
    monkeypatch.setattr(osmesa.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(gr.BackendUnavailable) as info:
        gr.Context("osmesa")
    message = str(info.value)
    assert "libOSMesa not found (Debian package libosmesa6)" in message
    assert "apt-get install" in message


def test_default_context_is_made_once_and_reused():
    pos, tri = synthetic.random_soup(2, seed=0)
    first = gr.rasterize(pos, tri, (16, 16))
    assert default_context() is default_context()
    assert first.info["backend"] == default_context().backend


def test_caches_do_not_grow_over_10000_calls(ctx):
    pos, tri = synthetic.random_soup(3, seed=1)
    variants = [("persp",), ("depth", "tri_id"), ("persp", "screen", "depth", "tri_id")]
    for outputs in variants:  # warm every variant once
        gr.rasterize(pos, tri, (16, 16), ctx=ctx, outputs=outputs)
    objects = ctx.cached_object_count()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for k in range(10_000):
        gr.rasterize(pos, tri, (16, 16), ctx=ctx, outputs=variants[k % 3])
    assert ctx.cached_object_count() == objects
    # Peak RSS may move by allocator noise, not by a per-call leak (10,000 calls).
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss < 50_000  # KiB


def test_framebuffer_cache_is_bounded(ctx):
    pos, tri = synthetic.random_soup(3, seed=1)
    for size in range(8, 40):
        gr.rasterize(pos, tri, (size, size), ctx=ctx)
    assert len(ctx._framebuffers) <= FRAMEBUFFER_CACHE_SIZE


def test_compile_error_names_the_file_and_line(ctx, tmp_path):
    vert = tmp_path / "ok.vert"
    vert.write_text("#version 450 core\nvoid main() { gl_Position = vec4(0.0); }\n")
    frag = tmp_path / "broken.frag"
    frag.write_text("#version 450 core\nout vec4 color;\n\nvoid main() {\n  color = vec4(1.0) +;\n}\n")
    with ctx:
        with pytest.raises(gr.ShaderCompileError) as info:
            compile_program(ctx.mgl, vert, frag, {"SOME_DEFINE": 1})
    assert f"{frag}:5:" in str(info.value)


def test_contexts_of_both_backends_coexist():
    names = backends.available_backends()
    contexts = [gr.Context(n) for n in names]
    try:
        pos, tri = synthetic.random_soup(20, seed=4)
        results = [gr.rasterize(pos, tri, (32, 32), ctx=c) for c in contexts * 2]
        for r in results[1:]:
            np.testing.assert_array_equal(r.tri_id, results[0].tri_id)
    finally:
        for c in contexts:
            c.release()


def test_release_targets_frees_the_framebuffers_and_rendering_goes_on(ctx):
    pos, tri = synthetic.random_soup(3, seed=2)
    before = gr.rasterize(pos, tri, (24, 24), ctx=ctx)
    gr.rasterize(pos, tri, (20, 20), ctx=ctx, outputs=("depth",))
    programs_and_buffers = ctx.cached_object_count() - sum(
        2 + len(t.attachments) for t in ctx._framebuffers.values())
    ctx.release_targets()
    assert ctx.cached_object_count() == programs_and_buffers
    assert ctx.gl_error() == "GL_NO_ERROR"
    after = gr.rasterize(pos, tri, (24, 24), ctx=ctx)   # the next call allocates again
    np.testing.assert_array_equal(before.persp, after.persp)
    np.testing.assert_array_equal(before.tri_id, after.tri_id)


def test_a_released_context_says_so_and_the_default_is_made_anew(gl_backend, monkeypatch):
    """After release() every use of a context is an ArgumentError naming ctx (not moderngl's
    AttributeError of an InvalidObject); a second release does nothing; a released default
    context is replaced by a new one on the next call that needs it."""
    import glraster.gpu.context as context_module
    from glraster.errors import ArgumentError

    pos, tri = synthetic.random_soup(2, seed=0)
    ctx = gr.Context(gl_backend)
    ctx.release()
    assert ctx.released
    with pytest.raises(ArgumentError) as err:
        gr.rasterize(pos, tri, (16, 16), ctx=ctx)
    assert err.value.argument == "ctx" and "was released" in str(err.value)
    ctx.release()

    released_default = gr.Context(gl_backend)
    released_default.release()
    monkeypatch.setattr(context_module, "_default_context", released_default)
    fresh = default_context()
    try:
        assert fresh is not released_default and not fresh.released
        assert gr.rasterize(pos, tri, (16, 16), ctx=fresh).mask.any()
    finally:
        fresh.release()


def _render_in_child(pipe):
    pos, tri = synthetic.random_soup(2, seed=0)
    try:
        pipe.send(int(gr.rasterize(pos, tri, (16, 16), ctx=gr.Context()).mask.sum()))
    except Exception as exc:   # (sent back whole: the test reads its type and text)
        pipe.send(exc)


# (the fork is the point; the child runs no JAX, nor any thread: a pipe, not a queue)
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
def test_a_process_forked_after_opengl_was_set_up_refuses_instead_of_hanging(gl_context):
    """Mesa's drivers hang for ever in a child forked after the parent made a context (a
    DataLoader's workers under the default 'fork' start method); glraster raises
    ForkedProcess there, naming the way out. A 'spawn'ed child renders as usual."""
    import multiprocessing

    from glraster.errors import BackendUnavailable, ForkedProcess

    for method, expected in (("fork", ForkedProcess), ("spawn", int)):
        mp = multiprocessing.get_context(method)
        receiver, sender = mp.Pipe(duplex=False)
        child = mp.Process(target=_render_in_child, args=(sender,))
        child.start()
        if not receiver.poll(120):
            child.kill()
            pytest.fail(f"the {method}ed child hung")
        result = receiver.recv()
        child.join(60)
        assert isinstance(result, expected), result
        if method == "fork":
            assert result.parent == os.getpid() and "'spawn'" in str(result)
            assert isinstance(result, BackendUnavailable)       # the CLI's exit code 3


def test_a_context_dropped_without_release_is_released_by_the_next_one(gl_backend):
    """A Context collected unreleased (one made per call and dropped, as some nvdiffrast
    code makes its RasterizeGLContext) used to keep its GL context: about 5.5 MB each on
    llvmpipe, measured over 60 in a loop; RSS now stays flat. Its GL context is released
    when the next Context is made (never inside the garbage collector, which may run while
    another context is current)."""
    import gc

    import glraster.gpu.context as context_module

    pos, tri = synthetic.random_soup(2, seed=0)
    held = []
    for _ in range(3):
        ctx = gr.Context(gl_backend)
        gr.rasterize(pos, tri, (16, 16), ctx=ctx)
        held.append(ctx.mgl)
        del ctx
        gc.collect()
    assert len(context_module._dropped) == 1, "the last one waits for the next context"
    survivor = gr.Context(gl_backend)
    try:
        assert context_module._dropped == []
        assert [type(m.mglo).__name__ for m in held] == ["InvalidObject"] * 3   # released
        assert gr.rasterize(pos, tri, (16, 16), ctx=survivor).mask.any()
    finally:
        survivor.release()
    assert context_module._dropped == [], "an explicitly released context is not queued"
