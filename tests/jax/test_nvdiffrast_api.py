"""glraster.jax has every public name of nvdiffrast (tests/nvdiffrast_api.py, written from
nvdiffrast's documentation), with its parameters, in order, with their defaults."""

from __future__ import annotations

import inspect
import types

import pytest

pytest.importorskip("jax")

import glraster.jax as dr  # noqa: E402
from tests.nvdiffrast_api import NVDIFFRAST_API, signature_problems  # noqa: E402


@pytest.mark.parametrize("name", sorted(NVDIFFRAST_API))
def test_glraster_jax_has_nvdiffrasts_name_with_its_parameters(name):
    assert signature_problems(dr, name) == []


def test_every_documented_top_level_name_is_exported():
    assert {name.split(".")[0] for name in NVDIFFRAST_API} <= set(dr.__all__)


def test_depth_peeler_is_a_context_manager_and_classes_are_classes():
    for name in ("DepthPeeler", "RasterizeGLContext", "RasterizeCudaContext", "TextureMip"):
        assert inspect.isclass(getattr(dr, name))
    assert callable(dr.DepthPeeler.__enter__) and callable(dr.DepthPeeler.__exit__)


def test_the_problems_check_can_fail():
    # a callable with a parameter missing and one renamed is reported, not accepted
    def rasterize(glctx, pos, triangles, resolution):
        pass

    fake = types.SimpleNamespace(__name__="fake", rasterize=rasterize)
    assert signature_problems(fake, "rasterize")
    assert signature_problems(fake, "interpolate") == ["fake lacks nvdiffrast's interpolate"]
