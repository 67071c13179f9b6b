"""Shared fixtures: one context per available backend, and a check that no GL error is left.

The ``gl`` marker
-----------------
A test needs OpenGL if and only if it asks for one of the fixtures below:

* ``ctx`` / ``gl_context``: a context of each available backend (pass ``ctx=ctx``);
* ``gl_backend``: that backend's name, for GL work in a subprocess or through the CLI
  (``--backend NAME`` or ``GLRASTER_BACKEND``), or in a context the test makes itself.

Those tests are marked ``gl`` automatically (``pytest -m "not gl"`` runs the rest on a
machine without Mesa). A test that needs GL in another way (pyrender's own EGL context)
says so with ``@pytest.mark.gl``.

Every other test runs with GL closed (see :func:`pytest_runtest_protocol`): opening a
context, the default one included, raises :class:`GLNotDeclared`, so a test that reaches
the GPU without declaring it fails on every machine instead of silently needing Mesa.
"""

from __future__ import annotations

import pytest

import glraster as gr
from glraster.gpu import context as gpu_context
from glraster.gpu import backends
from glraster.gpu.backends import available_backends

# Every backend that works on this machine; if none does, "auto" makes the tests fail with
# BackendUnavailable instead of silently skipping them.
BACKENDS = available_backends() or ["auto"]

GL_FIXTURES = frozenset({"ctx", "gl_context", "gl_backend"})

# Tests that open GL without one of those fixtures, in files being reworked by their
# owners: marked gl here until their files declare it (then delete the entry). A renamed
# test drops out of this list and fails loudly, as any undeclared one does.
UNDECLARED_GL_TESTS = frozenset({
    "tests/gpu/test_context.py::test_every_backend_on_this_machine_reports_its_name",
    "tests/gpu/test_context.py::test_environment_variable_chooses_the_backend",
    "tests/gpu/test_context.py::test_default_context_is_made_once_and_reused",
    "tests/gpu/test_context.py::test_contexts_of_both_backends_coexist",
    "tests/conformance/test_html_report.py::test_report_files_and_content",
    "tests/conformance/test_html_report.py::test_report_renders_in_headless_chromium",
})

# What a non-gl test finds in $GLRASTER_BACKEND: a `glraster` subprocess started without
# --backend stops with "backend must be one of ..., got '<this>' (from GLRASTER_BACKEND)".
UNDECLARED_BACKEND = "none: this test is not marked gl (use the ctx or gl_backend fixture)"


class GLNotDeclared(BaseException):
    """A test not marked ``gl`` tried to open an OpenGL context.

    A BaseException on purpose: code on the way catches Exception (``check.run`` records a
    crashing scene as a failed scene and goes on), and the refusal must reach pytest.
    """


@pytest.fixture(scope="session", params=BACKENDS)
def gl_context(request):
    ctx = gr.Context(backend=request.param)
    yield ctx
    ctx.release()


@pytest.fixture
def ctx(gl_context):
    """The backend's context; fails the test if it leaves a GL error set."""
    assert gl_context.gl_error() == "GL_NO_ERROR", "a GL error was pending before the test"
    yield gl_context
    assert gl_context.gl_error() == "GL_NO_ERROR", "the test left a GL error set"


@pytest.fixture
def gl_backend(gl_context):
    """The backend's name ("egl" or "osmesa"), for GL in a subprocess or the CLI."""
    return gl_context.backend


def pytest_collection_modifyitems(config, items):
    for item in items:
        if (GL_FIXTURES.intersection(getattr(item, "fixturenames", ()))
                or item.nodeid in UNDECLARED_GL_TESTS):
            item.add_marker(pytest.mark.gl)


def _closed(nodeid, what):
    def refuse(*args, **kwargs):
        raise GLNotDeclared(
            f"{nodeid} opens {what} but is not marked gl: give it the `ctx` fixture "
            "(and pass ctx=ctx), or `gl_backend` for a subprocess or the CLI "
            "(--backend NAME), or @pytest.mark.gl for GL outside glraster")
    return refuse


def _refusing_create(create, nodeid):
    def refusing_create(self):
        mgl = create(self)
        mgl.release()
        self.release()
        _closed(nodeid, f"an OpenGL context ({self.name})")()
    return refusing_create


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Close GL around setup, call and teardown of every test not marked ``gl``.

    A hook rather than an autouse fixture: it also covers the module- and session-scoped
    fixtures that the test's setup creates.
    """
    if item.get_closest_marker("gl") is not None:
        return (yield)
    with pytest.MonkeyPatch.context() as mp:
        # The default context (rasterize(ctx=None), Context() without a backend).
        mp.setattr(gpu_context, "_default_context", None)
        real_create_backend = gpu_context.create_backend
        refuse_default = _closed(item.nodeid, "the default GL context")
        mp.setattr(gpu_context, "create_backend",
                   lambda backend=None: refuse_default() if backend is None
                   else real_create_backend(backend))
        # A named backend (Context("egl"), available_backends()): its own checks run as
        # usual (a bad name is a ValueError, a missing library BackendUnavailable); a
        # context it does make is released at once and refused.
        for cls in backends.BACKENDS.values():
            mp.setattr(cls, "create", _refusing_create(cls.create, item.nodeid))
        # Subprocesses: `glraster ...` without --backend fails.
        mp.setenv("GLRASTER_BACKEND", UNDECLARED_BACKEND)
        return (yield)
