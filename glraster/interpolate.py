"""Per-pixel attributes from a :class:`~glraster.Raster`: an adapter over the one interpolate.

For a covered pixel with triangle ``t = tri_id[y, x]`` and barycentrics
``(b0, b1, b2)`` the attribute is::

    out[y, x] = b0 * attr[tri[t, 0]] + b1 * attr[tri[t, 1]] + b2 * attr[tri[t, 2]]

With ``space="persp"`` the barycentrics are the perspective-correct ones (GL 4.6 eq. 14.9,
the 1/w interpolation already folded in), so the result is the attribute of the 3D surface
point seen through the pixel.  With ``space="screen"`` they are window-space
(``noperspective``, eq. 14.10): linear on the screen, which is what affine texture mapping
does and what window depth obeys.

glraster has one interpolate, the differentiable op :data:`glraster.diff.ops.INTERPOLATE` in
nvdiffrast's layout (``rast`` (B, H, W, 4) = (u, v, z/w, id), the third weight 1 - u - v),
with a GPU core and a float64 core (docs/differentiable.md, "One interpolate").  This
function is its documented adapter for :class:`~glraster.Raster` results: it passes the
raster's barycentrics, divided by their sum, as (u, v) to the float64 core, so the weighted
sum is written once.
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError

__all__ = ["interpolate"]


def interpolate(attr, raster, tri, space: str = "persp", *, normalize: bool = True) -> np.ndarray:
    """Interpolate per-vertex attributes over a :class:`~glraster.Raster`.

    Args:
        attr: (V, C) per-vertex attributes (uv, normals, view depth, colors, ...), or (V,)
            for a single channel.
        raster: a GPU raster (float32 barycentrics) or a reference raster (float64), with
            ``tri_id`` and the barycentrics of ``space`` among its outputs.
        tri: (T, 3) integer vertex indices, the same array that was rasterized.
        space: "persp" (perspective-correct) or "screen" (affine in window space).
        normalize: divide by ``b0 + b1 + b2``.  Exact barycentrics sum to 1 (the reference's
            to ~1e-16), but llvmpipe's ``smooth`` ones carry a common-mode error from its
            1/w plane: on a 48x24 torus at 320x240 their sum is off by up to 2.1e-5
            (median 1.3e-6), and dividing it out brings interpolated view depth within
            1.5e-7 of the float64 reference.  False gives the raw weighted sum.

    Returns:
        (H, W, C) array, or (H, W) for 1-D ``attr``, indexed ``[y, x]`` with row 0 at the
        bottom, of the barycentrics' dtype (float32 for GPU rasters, float64 for reference
        rasters).  The sums are formed in float64 and rounded once.  Empty pixels are 0.

    Raises:
        glraster.errors.ArgumentError naming ``attr`` (None, not finite real numbers, not
        (V, C) or (V,)), ``tri`` (glraster.validate.triangles over attr's rows), ``space``
        or ``raster`` (an output missing, or ids beyond ``tri``).
    """
    space = validate.space(space)
    bary = getattr(raster, space, None)
    if bary is None:
        raise ArgumentError("raster", f"raster has no {space!r} barycentrics; "
                                      f"rasterize with '{space}' in outputs")
    tri_id = getattr(raster, "tri_id", None)
    if tri_id is None:
        raise ArgumentError("raster", "raster has no 'tri_id'; rasterize with 'tri_id' in "
                                      "outputs")
    if bary.ndim != 3 or bary.shape[2] != 3 or tri_id.shape != bary.shape[:2]:
        raise ArgumentError("raster", f"raster barycentrics must be (H, W, 3) with tri_id "
                                      f"(H, W), got {bary.shape} and {tri_id.shape}")

    if attr is None:
        raise ArgumentError(
            "attr", "attr is None: there are no per-vertex values to interpolate. A Mesh whose "
            "file has no texture coordinates has uv None (and one without normals normals "
            "None); check `mesh.uv is not None` or pass another (V, C) array")
    a = validate.real_array("attr", attr)
    squeeze = a.ndim == 1
    if squeeze:
        a = a[:, None]
    if a.ndim != 2:
        raise ArgumentError("attr", f"attr must have shape (V, C) or (V,), got {np.shape(attr)}")
    validate.finite("attr", a, a.astype(np.float64, copy=False))
    t = validate.triangles(tri, a.shape[0], of="attr")

    covered = tri_id >= 0
    ids = tri_id[covered]
    if ids.size and ids.max() >= t.shape[0]:
        raise ArgumentError("raster", f"raster.tri_id refers to triangle {ids.max()} but tri "
                                      f"has {t.shape[0]} triangles")

    # The math lives in the differentiable interpolate (glraster.diff.ops.INTERPOLATE, its
    # float64 core): this adapter hands it the raster in nvdiffrast's layout, with (u, v)
    # the barycentrics divided by their sum, so that 1 - u - v is the third one divided too.
    from glraster.diff import ids as _ids          # imported here: they load numba, and
    from glraster.diff.ops import INTERPOLATE      # `import glraster` stays light
    ys, xs = np.nonzero(covered)
    b = bary[ys, xs].astype(np.float64)                  # (N, 3)
    total = b[:, 0] + b[:, 1] + b[:, 2]
    if normalize and not total.all():
        k = int(np.flatnonzero(total == 0)[0])
        raise ArgumentError("raster", f"raster {space} barycentrics sum to 0 at the covered "
                                      f"pixel (y={ys[k]}, x={xs[k]}): they cannot be normalized")
    scale = np.where(total == 0, 1.0, total)
    rast = np.zeros((1, *tri_id.shape, 4))
    rast[0, ys, xs, 0] = b[:, 0] / scale
    rast[0, ys, xs, 1] = b[:, 1] / scale
    rast[0, ys, xs, 3] = _ids.encode_ids(tri_id[ys, xs])
    # checked above: the float64 core itself, without the op's second pass over the frame
    core = INTERPOLATE.core(np.float64)
    (out, _), _saved = core.forward(a.astype(np.float64, copy=False)[None], rast, None,
                                    tri=t.astype(np.int32, copy=False), diff_attrs=None)
    out = out[0]
    if not normalize:
        out[ys, xs] *= total[:, None]
    out = out.astype(bary.dtype, copy=False)
    return out[..., 0] if squeeze else out
