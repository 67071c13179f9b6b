"""The benchmarks' shared fixture: one EGL context per module (timings exclude its start)."""

import pytest

import glraster as gr


@pytest.fixture(scope="module")
def ctx():
    c = gr.Context("egl")
    yield c
    c.release()
