"""JAX front end of :mod:`glraster.diff` with nvdiffrast's names and signatures (the only
module that imports jax; optional extra ``[jax]``).

Code written for nvdiffrast runs on JAX arrays::

    import glraster.jax as dr

    glctx = dr.RasterizeGLContext()
    rast, rast_db = dr.rasterize(glctx, pos, tri, resolution=(H, W))
    color, _ = dr.interpolate(col, rast, tri)

Every op is differentiable (``jax.grad``, ``jax.vjp``), runs inside ``jax.jit`` (``tri``,
``resolution``, modes and the topology hash are static) and under ``jax.vmap`` (a mapped
leading axis becomes the op's batch axis). float32 arrays run on OpenGL, float64 arrays
(``jax_enable_x64``) on the float64 reference. One bridge does it all:
:mod:`glraster.jax.bridge`; docs/jax.md.
"""

from glraster.errors import require_extra

require_extra("jax", "glraster.jax")  # first: without jax, the error names the extra

from glraster.diff.log import get_log_level, set_log_level
from glraster.jax.antialias import antialias, antialias_construct_topology_hash
from glraster.jax.context import RasterizeCudaContext, RasterizeGLContext
from glraster.jax.ops import DepthPeeler, interpolate, rasterize
from glraster.jax.texture import TextureMip, texture, texture_construct_mip

__all__ = ["DepthPeeler", "RasterizeCudaContext", "RasterizeGLContext", "TextureMip",
           "antialias", "antialias_construct_topology_hash", "get_log_level", "interpolate",
           "rasterize", "set_log_level", "texture", "texture_construct_mip"]
