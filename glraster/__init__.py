"""glraster: headless GPU rasterization of barycentric coordinates, checked against math."""

__version__ = "0.1.0"

from .context import Context  # noqa: E402
from .errors import BackendUnavailable, ShaderCompileError  # noqa: E402
from .raster import Raster, rasterize  # noqa: E402
