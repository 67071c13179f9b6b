"""glraster.torch has every public name of nvdiffrast.torch, with its parameters.

The names, parameters and defaults below are written out from nvdiffrast's documentation,
the "PyTorch API reference" section of https://nvlabs.github.io/nvdiffrast/ (not from its
code). Each glraster callable must take the documented parameters first, in that order,
positional-or-keyword as documented, with the documented defaults; anything glraster adds
must come after them and have a default, so that every call written for nvdiffrast binds the
same way.
"""

from __future__ import annotations

import inspect

import pytest

import glraster.torch as dr
from tests.nvdiffrast_api import NVDIFFRAST_API, REQUIRED


def _resolve(name):
    obj = dr
    for part in name.split("."):
        obj = getattr(obj, part, None)
        assert obj is not None, f"glraster.torch lacks nvdiffrast's {name}"
    return obj


def _parameters(name, obj):
    params = list(inspect.signature(obj).parameters.values())
    if "." in name:             # a method: drop self
        assert params and params[0].name == "self", f"{name} is not a plain method"
        params = params[1:]
    return params


@pytest.mark.parametrize("name", sorted(NVDIFFRAST_API))
def test_glraster_torch_has_nvdiffrasts_name_with_its_parameters(name):
    documented = NVDIFFRAST_API[name]
    params = _parameters(name, _resolve(name))
    head = [(p.name, p.default) for p in params[:len(documented)]]
    assert head == documented, f"{name}: documented {documented}, glraster has {head}"
    for p in params[:len(documented)]:
        assert p.kind == inspect.Parameter.POSITIONAL_OR_KEYWORD, f"{name}({p.name}) is {p.kind}"
    for p in params[len(documented):]:    # glraster's additions: optional, keyword-only
        assert p.kind == inspect.Parameter.KEYWORD_ONLY and p.default is not REQUIRED, (
            f"{name}: glraster's extra parameter {p.name} must be keyword-only with a default")


def test_every_documented_top_level_name_is_exported():
    top = {name.split(".")[0] for name in NVDIFFRAST_API}
    assert top <= set(dr.__all__)


def test_depth_peeler_is_a_context_manager_and_classes_are_classes():
    assert inspect.isclass(dr.DepthPeeler) and inspect.isclass(dr.RasterizeGLContext)
    assert inspect.isclass(dr.RasterizeCudaContext)
    assert callable(dr.DepthPeeler.__enter__) and callable(dr.DepthPeeler.__exit__)
