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

from glraster.errors import ArgumentError

__all__ = ["interpolate"]

_SPACES = {"persp": "persp", "screen": "screen"}


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
    """
    if space not in _SPACES:
        raise ValueError(f"space must be 'persp' or 'screen', got {space!r}")
    bary = getattr(raster, _SPACES[space], None)
    if bary is None:
        raise ValueError(f"raster has no {space!r} barycentrics; "
                         f"rasterize with '{space}' in outputs")
    tri_id = getattr(raster, "tri_id", None)
    if tri_id is None:
        raise ValueError("raster has no 'tri_id'; rasterize with 'tri_id' in outputs")
    if bary.ndim != 3 or bary.shape[2] != 3 or tri_id.shape != bary.shape[:2]:
        raise ValueError(f"raster barycentrics must be (H, W, 3) with tri_id (H, W), got "
                         f"{bary.shape} and {tri_id.shape}")

    if attr is None:
        raise ValueError(
            "attr is None: there are no per-vertex values to interpolate. A Mesh whose file "
            "has no texture coordinates has uv None (and one without normals normals None); "
            "check `mesh.uv is not None` or pass another (V, C) array")
    try:
        a = np.asarray(attr)
    except (TypeError, ValueError):
        raise ValueError("attr must be a numeric array of shape (V, C)") from None
    if a.dtype.kind not in "biuf":
        raise ValueError(f"attr must be numeric, got dtype {a.dtype}")
    squeeze = a.ndim == 1
    if squeeze:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError(f"attr must have shape (V, C) or (V,), got {np.shape(attr)}")

    t = np.asarray(tri)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"tri must have shape (T, 3), got {t.shape}")
    if t.dtype.kind not in "iu":
        raise ValueError(f"tri must hold integers, got dtype {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= a.shape[0]):
        raise ValueError(f"tri indexes vertices 0..{a.shape[0] - 1} of attr, got indices "
                         f"in [{t.min()}, {t.max()}]")

    covered = tri_id >= 0
    ids = tri_id[covered]
    if ids.size and ids.max() >= t.shape[0]:
        raise ValueError(f"raster.tri_id refers to triangle {ids.max()} but tri has "
                         f"{t.shape[0]} triangles")

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
