"""Geometry (NumPy and numba only): camera and projection matrices, the viewport transform,
llvmpipe's fixed-point fill rule, clipping, triangle conditioning, meshes and synthetic
triangle sets. Nothing here touches OpenGL."""
