"""The float64 reference rasterizer (importable without moderngl or a GL context)."""

from glraster.reference.rasterizer import (  # noqa: F401
    DEFAULT_EDGE_BAND_PX, DEPTH_TIE, FIXED_ONE, SUBPIXEL_BITS, ReferenceRaster, TriangleSetup,
    edge_values, llvmpipe_edges, rasterize, setup,
)
