"""glraster: headless GPU rasterization of barycentric coordinates, checked against math.

Layers (lower never import higher; pyproject.toml's import-linter contracts say so):
types / validate / errors -> geometry -> io -> verify -> gpu | reference ->
conformance | studies -> cli.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from glraster._version import __version__  # noqa: E402,F401

from glraster import types  # noqa: E402
from glraster.errors import BackendUnavailable, GLError, ShaderCompileError  # noqa: E402
from glraster.geometry import camera  # noqa: E402
from glraster.geometry.mesh import Mesh, load_mesh  # noqa: E402
from glraster.interpolate import interpolate  # noqa: E402
from glraster.types import Raster  # noqa: E402

if TYPE_CHECKING:
    from glraster import reference
    from glraster.gpu.context import Context
    from glraster.gpu.rasterize import rasterize
    from glraster.gpu.render import render_scene
    from glraster.verify.compare import compare

# Imported on first use (PEP 562): the GPU names, so that ``import glraster.reference`` and
# the rest of the CPU side work where moderngl is not installed; the reference and compare,
# so that light users (glraster.client) do not load numba (0.5 s).
_LAZY_NAMES = {
    "Context": "glraster.gpu.context",
    "rasterize": "glraster.gpu.rasterize",
    "render_scene": "glraster.gpu.render",
    "compare": "glraster.verify.compare",
}


def __getattr__(name: str):
    import importlib

    if name == "reference":
        value = importlib.import_module("glraster.reference")
    else:
        module = _LAZY_NAMES.get(name)
        if module is None:
            raise AttributeError(f"module 'glraster' has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY_NAMES) | {"reference"})


__all__ = [
    "BackendUnavailable", "Context", "GLError", "Mesh", "Raster", "ShaderCompileError",
    "camera", "compare", "interpolate", "load_mesh", "rasterize", "reference", "render_scene",
    "types",
]
