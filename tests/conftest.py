"""Shared fixtures: one context per available backend, and a check that no GL error is left."""

from __future__ import annotations

import pytest

import glraster as gr
from glraster.gpu.backends import available_backends

# Every backend that works on this machine; if none does, "auto" makes the tests fail with
# BackendUnavailable instead of silently skipping them.
BACKENDS = available_backends() or ["auto"]


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
