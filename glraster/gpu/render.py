"""Rendering a mesh or scene (geometry.mesh) through :func:`glraster.rasterize`."""

from __future__ import annotations

from glraster.geometry.mesh import scene_geometry
from glraster.gpu.rasterize import rasterize


def render_scene(scene, resolution=(256, 256), *, view=None, proj=None, ctx=None,
                 outputs=("persp", "screen", "depth", "tri_id"), method: str = "hw"):
    """Rasterize a mesh or scene with :func:`glraster.rasterize`.

    Arguments as :func:`scene_geometry` plus ``ctx``, ``outputs`` and ``method`` of
    :func:`glraster.rasterize`.

    Returns:
        :class:`glraster.Raster` whose ``tri_id`` indexes ``raster.info["geometry"].tri``;
        ``raster.info["geometry"]`` is the :class:`SceneGeometry` (world-space mesh with
        uv / normals for :func:`glraster.interpolate`, view, proj).
    """
    geo = scene_geometry(scene, resolution, view=view, proj=proj)
    r = rasterize(geo.pos, geo.tri, geo.resolution, ctx=ctx, outputs=outputs, method=method)
    r.info["geometry"] = geo
    return r
