"""The float64 reference rasterizer (importable without moderngl or a GL context)."""

from glraster.reference.rasterizer import (  # noqa: F401
    DEFAULT_EDGE_BAND_PX, DEPTH_TIE, FIXED_ONE, LLVMPIPE, SUBPIXEL_BITS, FillRule,
    ReferenceRaster, TriangleSetup, edge_values, fixed_edges, llvmpipe_edges, rasterize, setup,
)
from glraster.reference.area import AreaFragments, area_coverage, visible_area  # noqa: F401
