"""glraster: headless GPU rasterization of barycentric coordinates, checked against math.

Layers (lower never import higher; pyproject.toml's import-linter contracts say so):
types / validate / errors -> geometry -> io -> verify -> gpu | reference ->
conformance | studies -> cli.
"""

from glraster._version import __version__  # noqa: E402,F401

from glraster import reference, types  # noqa: E402
from glraster.errors import BackendUnavailable, GLError, ShaderCompileError  # noqa: E402
from glraster.geometry import camera  # noqa: E402
from glraster.geometry.mesh import Mesh, load_mesh  # noqa: E402
from glraster.gpu.context import Context  # noqa: E402
from glraster.gpu.rasterize import rasterize  # noqa: E402
from glraster.gpu.render import render_scene  # noqa: E402
from glraster.interpolate import interpolate  # noqa: E402
from glraster.types import Raster  # noqa: E402
from glraster.verify.compare import compare  # noqa: E402

__all__ = [
    "BackendUnavailable", "Context", "GLError", "Mesh", "Raster", "ShaderCompileError",
    "camera", "compare", "interpolate", "load_mesh", "rasterize", "reference", "render_scene",
    "types",
]
