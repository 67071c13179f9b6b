"""``rasterize``, ``interpolate`` and ``DepthPeeler`` with nvdiffrast's signatures and layouts,
calls of :mod:`glraster.torch.bridge` on :mod:`glraster.diff.ops`. Layouts (B batch, H x W
image, rows ``[y, x]`` with row 0 at the BOTTOM, as GL windows):

    pos      (V, 4) or (B, V, 4)  clip-space; 2-D: range mode (``ranges`` (B, 2) int rows
             [first, count], else one image), 3-D: instanced mode (``ranges`` ignored)
    tri      (T, 3) int32 (or int64) vertex indices, shared by every image
    rast     (B, H, W, 4)  (u, v, z/w, id): u, v the perspective-correct barycentrics of
             tri[t, 0] and tri[t, 1] at the pixel centre; z/w the clip-space depth; id = t + 1
             as a float32 (the value itself for ids <= 2^24, else the float32 whose bit
             pattern is 0x4a800000 + id), 0 = empty
    rast_db  (B, H, W, 4)  (du/dx, du/dy, dv/dx, dv/dy) per window pixel; (B, H, W, 0) on
             an ``output_db=False`` context
    attr     (V, A) or (B, V, A)  vertex attributes (a batch of 1 broadcasts)
    out      (B, H, W, A)  sum_i b_i attr[tri[t, i]] (0 on empty pixels)
    out_da   (B, H, W, 2 * len(diff_attrs))  (dA/dx, dA/dy) per selected attribute, in order

float32 runs on OpenGL, float64 through the float64 reference (for gradcheck). Gradients:
rasterize sends those of rast's u, v and, with ``grad_db`` on an ``output_db`` context, of
rast_db to ``pos`` (coverage frozen: no visibility gradient, none through z/w or id);
interpolate sends them to ``attr``, rast's u, v and, with ``diff_attrs``, ``rast_db``.
"""

from __future__ import annotations

from glraster.diff.ops import INTERPOLATE, RASTERIZE, depth_peeler
from glraster.diff.rasterizer_context import PeelerScope
from glraster.torch import bridge


def _rasterize_call(glctx, pos, tri, resolution, ranges, grad_db):
    return bridge.Call(RASTERIZE, (pos,), bridge.context(glctx), tri=tri,
                       resolution=resolution, ranges=ranges, grad_db=glctx.output_db,
                       frozen=() if bridge.flag("grad_db", grad_db) else (1,))


@bridge.eager
def rasterize(glctx, pos, tri, resolution, ranges=None, grad_db=True):
    """Rasterize triangles (nvdiffrast's ``rasterize``): ``(rast, rast_db)`` of pos'
    dtype, B = 1 for 2-D pos without ranges (layouts in the module docstring).

    glctx: a RasterizeGLContext (or RasterizeCudaContext); resolution: (height, width);
    ranges: range mode's (B, 2) int tensor; grad_db: propagate rast_db's gradient to pos
    (ignored on an ``output_db=False`` context).
    """
    call = _rasterize_call(glctx, pos, tri, resolution, ranges, grad_db)
    if glctx.active_depth_peeler is not None:
        raise RuntimeError("rasterize() cannot run while a DepthPeeler is active on this "
                           "context; use its rasterize_next_layer()")
    return call()


@bridge.eager
def interpolate(attr, rast, tri, rast_db=None, diff_attrs=None, *, glctx=None):
    """Interpolate vertex attributes (nvdiffrast's ``interpolate``): ``(out, out_da)``.

    rast, rast_db: :func:`rasterize`'s outputs (rast_db only read with ``diff_attrs``);
    diff_attrs: None, "all" or a list of attribute indices whose screen derivatives go to
    out_da; glctx (glraster's addition): the context float32 runs on (None: the default).
    """
    if diff_attrs is None or (isinstance(diff_attrs, (list, tuple)) and not diff_attrs):
        rast_db, diff_attrs = None, None  # as nvdiffrast: rast_db is then not used
    if bridge.tensor("attr", attr).ndim == 3 and attr.shape[0] == 1:
        attr = attr[0]  # a batch of 1 broadcasts (as (V, A))
    return bridge.Call(INTERPOLATE, (attr, rast, rast_db), glctx, tri=tri,
                       diff_attrs=diff_attrs)()


class DepthPeeler(PeelerScope):
    """Successive depth layers (nvdiffrast's ``DepthPeeler``), as a context manager::

        with DepthPeeler(glctx, pos, tri, resolution) as peeler:
            for _ in range(layers):
                rast, rast_db = peeler.rasterize_next_layer()

    Arguments are :func:`rasterize`'s; a layer is its ``(rast, rast_db)`` for the nearest
    surface strictly behind the previous layer's (a pixel empty once stays empty),
    differentiable w.r.t. ``pos`` the same way. While a peeler is active (one per context),
    ``rasterize`` on its context raises RuntimeError.
    """

    @bridge.eager
    def __init__(self, glctx, pos, tri, resolution, ranges=None, grad_db=True):
        self._call = _rasterize_call(glctx, pos, tri, resolution, ranges, grad_db)
        self.raster_ctx = glctx
        self._peeler = None

    def _open(self):
        self._peeler = depth_peeler(*self._call.arrays, **self._call.params)

    @bridge.eager
    def rasterize_next_layer(self):
        """The next layer's ``(rast, rast_db)``; layouts as :func:`rasterize`'s."""
        if self._peeler is None:
            raise RuntimeError("rasterize_next_layer() must be called inside the "
                               "DepthPeeler's with block")
        return self._call(self._peeler.rasterize_next_layer)
