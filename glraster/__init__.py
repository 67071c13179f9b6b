"""glraster: headless GPU rasterization of barycentric coordinates, checked against math."""

__version__ = "0.1.0"

from . import reference  # noqa: E402
from .compare import compare  # noqa: E402
from .context import Context  # noqa: E402
from .errors import BackendUnavailable, ShaderCompileError  # noqa: E402
from .raster import Raster, rasterize  # noqa: E402

__all__ = [
    "BackendUnavailable", "Context", "Raster", "ShaderCompileError",
    "compare", "rasterize", "reference",
]
