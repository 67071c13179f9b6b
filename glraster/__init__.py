"""glraster: headless GPU rasterization of barycentric coordinates, checked against math."""

__version__ = "0.1.0"

from . import camera, reference  # noqa: E402
from .compare import compare  # noqa: E402
from .context import Context  # noqa: E402
from .errors import BackendUnavailable, ShaderCompileError  # noqa: E402
from .interpolate import interpolate  # noqa: E402
from .mesh import Mesh, load_mesh, render_scene  # noqa: E402
from .raster import Raster, rasterize  # noqa: E402

__all__ = [
    "BackendUnavailable", "Context", "Mesh", "Raster", "ShaderCompileError",
    "camera", "compare", "interpolate", "load_mesh", "rasterize", "reference", "render_scene",
]
