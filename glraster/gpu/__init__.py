"""The GPU layer, the only importer of moderngl: headless backends, the context and its
caches, shader files, the method registry, the draw pipeline, culling and rasterize."""
