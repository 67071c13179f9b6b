"""PyTorch autograd wrappers of :mod:`glraster.diff` with nvdiffrast's signatures (the only
module that imports torch; optional extra ``[torch]``). Code written for nvdiffrast runs
after ``import glraster.torch as dr`` instead of ``import nvdiffrast.torch as dr``.

Tensors live on the CPU. float32 runs on OpenGL (glraster's GPU ops), float64 through the
float64 reference, so ``torch.autograd.gradcheck`` checks the closed-form gradients.
Layouts: :mod:`glraster.torch.ops`; docs/differentiable.md, "PyTorch".
"""

from glraster.torch.antialias import antialias, antialias_construct_topology_hash
from glraster.torch.context import RasterizeCudaContext, RasterizeGLContext
from glraster.torch.log import get_log_level, set_log_level
from glraster.torch.ops import DepthPeeler, interpolate, rasterize
from glraster.torch.texture import TextureMip, texture, texture_construct_mip

__all__ = ["DepthPeeler", "RasterizeCudaContext", "RasterizeGLContext", "TextureMip",
           "antialias", "antialias_construct_topology_hash", "get_log_level", "interpolate",
           "rasterize", "set_log_level", "texture", "texture_construct_mip"]
