"""Judging a raster: the per-pixel error model (tolerance) and the comparison (compare)."""
