"""nvdiffrast's PyTorch API over :mod:`glraster.diff.ops` (the only torch importer; extra
``[torch]``): code written for nvdiffrast runs after ``import glraster.torch as dr``. CPU
tensors; float32 runs on OpenGL, float64 through the float64 reference (for gradcheck).
Layouts: :mod:`glraster.torch.ops`, :mod:`glraster.torch.texture`; docs/differentiable.md.
"""

from glraster.diff.log import get_log_level, set_log_level
from glraster.errors import require_extra

require_extra("torch", "glraster.torch")  # first: without torch, the error names the extra

from glraster.torch.antialias import antialias, antialias_construct_topology_hash
from glraster.torch.context import RasterizeCudaContext, RasterizeGLContext
from glraster.torch.ops import DepthPeeler, interpolate, rasterize
from glraster.torch.texture import TextureMip, texture, texture_construct_mip

__all__ = ["DepthPeeler", "RasterizeCudaContext", "RasterizeGLContext", "TextureMip",
           "antialias", "antialias_construct_topology_hash", "get_log_level", "interpolate",
           "rasterize", "set_log_level", "texture", "texture_construct_mip"]
