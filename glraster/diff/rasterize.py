"""The differentiable rasterize on the GPU: forward, instanced and range batches, depth peeling.

:func:`forward` rasterizes clip-space triangles into nvdiffrast's layouts:

- ``rast`` (B, H, W, 4) float32: (u, v, z/w, id) per pixel, ``[b, y, x]`` with row 0 at the
  bottom (GL window coordinates). u = b0, v = b1 are the perspective-correct barycentrics
  of the vertices ``tri[t, 0]``, ``tri[t, 1]`` at the pixel centre (``space="screen"``: the
  window-space ones); z/w is the NDC depth z_c / w_c of the surface point there; id is
  the triangle index + 1 as a float (:func:`glraster.diff.layout.encode_ids`, exact for
  any index); all four are 0 on empty pixels.
- ``rast_db`` (B, H, W, 4) float32: (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre, per
  window pixel, 0 on empty pixels.

Everything is computed in the fragment shader (shaders/diff/rasterize.frag) from a
per-triangle record set up on the host in float64, the "homogeneous" method's
(:mod:`glraster.gpu.homogeneous`): with the edge functions e_i = A_i x + B_i y + C_i (rows
of adj(M), M = [[X_j], [Y_j], [w_j]], X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2),
s_i = e_i / det(M), S = sum_j s_j and b_i = s_i / S,

    d b_i / dx = (A_i - b_i sum_j A_j) / (det S)        (y: B instead of A)

the exact derivative at the centre (not a 2x2-quad difference such as dFdx). The
barycentrics are evaluated compensated, so their error does not grow with the distance
from the framebuffer origin. Coverage, the depth test (LESS on a 32-bit float depth
buffer, ties keep the earlier triangle) and triangle ids come from the driver, through the
one draw pipeline (:func:`glraster.gpu.pipeline.draw`).

Batches (the B axis): ``pos`` (B, V, 4) draws ``tri`` over each ``pos[b]`` (instanced
mode); ``pos`` (V, 4) with ``ranges`` (B, 2) draws ``tri[first:first + count]`` for each
row (range mode, ids index the whole ``tri``). Each batch item is one draw into the same
cached framebuffer, read back into its slice of the output (docs/differentiable.md, "GPU",
says why not a layered array texture).

:class:`DepthPeeler` (and :func:`depth_peel`) gives successive depth layers: each keeps, per
pixel, the nearest surface strictly behind the previous layer's z/w (the fragment shader
samples the previous layer's z/w and discards fragments at or in front of it).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from glraster import validate
from glraster.diff import layout
from glraster.gpu import cull as _cull
from glraster.gpu import homogeneous as _homogeneous
from glraster.gpu import pipeline
from glraster.gpu.context import Context, default_context
from glraster.gpu.shaders import shader_path

VERT = "diff/rasterize.vert"
FRAG = "diff/rasterize.frag"
RECORD_STRIDE = 28  # floats per triangle record, see shaders/diff/rasterize.frag

# Host-side culling below this many triangles costs more than the setup records it saves.
CULL_MIN_TRIANGLES = 256


@dataclass
class RasterizeSaved:
    """What the backward of :func:`forward` needs.

    pos        : (V, 4) or (B, V, 4) float32 clip space, as validated
    tri        : (T, 3) int32
    resolution : (height, width)
    ranges     : (B, 2) int64 [first, count] or None
    rast       : (B, H, W, 4) float32, the forward's output
    space      : "persp" or "screen"
    """

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple
    ranges: np.ndarray | None
    rast: np.ndarray
    space: str = "persp"


@functools.lru_cache(maxsize=8)
def _shader_path(name: str):
    return shader_path(name)


def setup_records(clip: np.ndarray, resolution) -> np.ndarray:
    """(T, RECORD_STRIDE) float32 records for shaders/diff/rasterize.frag from ``clip``
    (T, 3, 4) float32: the "homogeneous" method's 24 values, then z_j / k (k = max_j |w_j|)
    for j = 0, 1, 2 and one pad."""
    rec = np.zeros((len(clip), RECORD_STRIDE), np.float32)
    if len(clip):
        rec[:, :_homogeneous.STRIDE] = _homogeneous.setup(clip, resolution, fp64=False)
        c = clip.astype(np.float64)
        k = np.abs(c[..., 3]).max(1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            rec[:, 24:27] = np.nan_to_num(c[..., 2] / k, nan=0.0, posinf=0.0, neginf=0.0)
    return rec


class _Forward:
    """Validated inputs, per-item triangles (culled) and setup records, and the draws of
    one forward (the peeler draws the same items once per layer)."""

    def __init__(self, pos, tri, resolution, ctx, ranges, grad_db, space):
        self.ctx = ctx if ctx is not None else default_context()
        self.ctx.require_gl(45, "glraster.diff.rasterize", "shader storage buffers, GLSL 4.50")
        self.pos = layout.positions(pos, np.float32)
        self.tri = layout.triangles(tri, self.pos.shape[-2])
        self.height, self.width = validate.resolution(resolution, self.ctx.max_texture_size)
        self.space = layout.space(space)
        if grad_db not in (True, False):
            raise ValueError(f"grad_db must be True or False, got {grad_db!r}")
        self.grad_db = bool(grad_db)
        self.ranges = layout.ranges(ranges, len(self.tri), self.pos.ndim)
        item_bytes = self.pos[0].nbytes if self.pos.ndim == 3 else self.pos.nbytes
        if item_bytes > self.ctx.max_storage_block_size:
            raise ValueError(f"pos takes {item_bytes} bytes per batch item, above the driver's "
                             "shader storage block limit of "
                             f"{self.ctx.max_storage_block_size} bytes")
        self.batch = layout.batch_size(self.pos, self.ranges)
        self.colors = {"rast": (4, "f4")}
        if self.grad_db:
            self.colors["rast_db"] = (4, "f4")
        self._items = [self._item(b) for b in range(self.batch)]
        # the setup records of every item's drawn triangles in one vectorized call
        clip = [pos[tri] for pos, tri, _, _ in self._items]
        records = setup_records(np.concatenate(clip), (self.height, self.width))
        split = np.cumsum([len(c) for c in clip])[:-1]
        self._records = np.split(records, split)

    def _item(self, b):
        """(pos, drawn tri, caller ids of the drawn triangles or None, id_base) of item b."""
        if self.pos.ndim == 3:
            pos, first, tri = self.pos[b], 0, self.tri
        elif self.ranges is not None:
            first, count = (int(x) for x in self.ranges[b])
            pos, tri = self.pos, self.tri[first:first + count]
        else:
            pos, first, tri = self.pos, 0, self.tri
        kept = None
        if len(tri) >= CULL_MIN_TRIANGLES:
            culling = _cull.cull(pos, tri, (self.height, self.width),
                                 llvmpipe=self.ctx.is_llvmpipe,
                                 subpixel_bits=self.ctx.subpixel_bits)
            if not culling.all_kept:
                kept = (culling.kept + first).astype(np.int32)
                tri = tri[culling.kept]
        return pos, np.ascontiguousarray(tri), kept, first

    def spec(self, b, prev_depth=None) -> tuple[pipeline.Draw, np.ndarray, np.ndarray]:
        pos, tri, kept, first = self._items[b]
        defines = pipeline.output_defines(self.colors)
        if self.space == "screen":
            defines["SPACE_SCREEN"] = 1
        if kept is not None:
            defines["REMAP"] = 1
        if prev_depth is not None:
            defines["PEEL"] = 1
        with self.ctx:
            program, vao = self.ctx.program(_shader_path(VERT), _shader_path(FRAG), defines)
        per_triangle = {}
        if len(tri):
            per_triangle[2] = self._records[b]
        if kept is not None:
            per_triangle[3] = kept
        uniforms = {"id_base": first} if "id_base" in program else {}
        textures = {"prev_depth": prev_depth} if prev_depth is not None else {}
        spec = pipeline.Draw(program, vao, self.colors, per_triangle=per_triangle,
                             uniforms=uniforms, textures=textures)
        return spec, pos, tri

    def new_outputs(self):
        shape = (self.batch, self.height, self.width, 4)
        rast = np.empty(shape, np.float32)
        rast_db = np.empty(shape, np.float32) if self.grad_db else None
        return rast, rast_db

    def draw(self, b, rast, rast_db, prev_depth=None):
        spec, pos, tri = self.spec(b, prev_depth)
        out = {"rast": rast[b]}
        if rast_db is not None:
            out["rast_db"] = rast_db[b]
        pipeline.draw(self.ctx, spec, pos, tri, (self.height, self.width), out=out,
                      during="rasterizing (glraster.diff)")

    def saved(self, rast) -> RasterizeSaved:
        return RasterizeSaved(self.pos, self.tri, (self.height, self.width), self.ranges,
                              rast, self.space)


def forward(pos, tri, resolution, *, ctx: Context | None = None, ranges=None,
            grad_db: bool = True, space: str = "persp"):
    """Rasterize for differentiation: ``(rast, rast_db or None, saved)``.

    Parameters
    ----------
    pos : (V, 4) or (B, V, 4) array_like of float
        Clip-space positions; 3-D is instanced mode (``tri`` drawn over each ``pos[b]``).
    tri : (T, 3) array_like of int
        Vertex indices.
    resolution : (height, width)
    ctx : Context, optional
        Defaults to the process-wide context.
    ranges : (B, 2) array_like of int, optional
        Range mode (``pos`` 2-D): item b draws ``tri[first:first + count]``; ids index the
        whole ``tri``.
    grad_db : bool
        Also compute ``rast_db`` (else None is returned in its place).
    space : {"persp", "screen"}
        u, v are perspective-correct ("persp") or window-space ("screen") barycentrics.

    Returns
    -------
    rast : (B, H, W, 4) float32
        (u, v, z/w, id), ``[b, y, x]``, row 0 at the bottom; id = triangle index + 1
        (:func:`glraster.diff.layout.encode_ids`), 0 on empty pixels. B = 1 for 2-D
        ``pos`` without ranges.
    rast_db : (B, H, W, 4) float32 or None
        (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre (window pixels), 0 where empty.
    saved : RasterizeSaved
    """
    job = _Forward(pos, tri, resolution, ctx, ranges, grad_db, space)
    rast, rast_db = job.new_outputs()
    for b in range(job.batch):
        job.draw(b, rast, rast_db)
    return rast, rast_db, job.saved(rast)


class DepthPeeler:
    """Successive depth layers of one scene (the B axis as in :func:`forward`).

    Each :meth:`rasterize_next_layer` call returns ``(rast, rast_db or None, saved)`` of
    the next layer: per pixel, the nearest surface strictly behind the previous layer's z/w
    (fragments at or in front of it are discarded in the fragment shader, which samples
    the previous layer's z/w from a float texture). The first layer equals
    :func:`forward`; a pixel empty in one layer is empty in every later one.

    Use as a context manager, or call :meth:`release`, to free the depth texture.
    """

    def __init__(self, pos, tri, resolution, *, ctx: Context | None = None, ranges=None,
                 grad_db: bool = True, space: str = "persp"):
        self._job = _Forward(pos, tri, resolution, ctx, ranges, grad_db, space)
        self.ctx = self._job.ctx
        self.layer = 0
        self._prev = None      # (B, H, W) float32 z/w of the last layer, +inf where empty
        self._texture = None

    def rasterize_next_layer(self):
        """The next layer: ``(rast, rast_db or None, saved)`` as from :func:`forward`."""
        job = self._job
        rast, rast_db = job.new_outputs()
        if self.layer == 0:
            for b in range(job.batch):
                job.draw(b, rast, rast_db)
        else:
            texture = self._depth_texture()
            for b in range(job.batch):
                with self.ctx:
                    texture.write(self._prev[b])
                job.draw(b, rast, rast_db, prev_depth=texture)
        self._prev = np.where(rast[..., 3] != 0, rast[..., 2], np.float32(np.inf))
        self.layer += 1
        return rast, rast_db, job.saved(rast)

    def _depth_texture(self):
        if self._texture is None:
            with self.ctx:
                tex = self.ctx.mgl.texture((self._job.width, self._job.height), 1,
                                           dtype="f4")
                tex.filter = (self.ctx.mgl.NEAREST, self.ctx.mgl.NEAREST)
                self._texture = tex
        return self._texture

    def release(self):
        if self._texture is not None:
            with self.ctx:
                self._texture.release()
            self._texture = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


def depth_peel(pos, tri, resolution, *, ctx: Context | None = None, ranges=None,
               layers: int = 2, grad_db: bool = True, space: str = "persp"):
    """The first ``layers`` depth layers: a list of ``(rast, rast_db or None, saved)``, as
    from :meth:`DepthPeeler.rasterize_next_layer` (layer 0 equals :func:`forward`)."""
    layers = validate.positive_int("layers", layers)
    with DepthPeeler(pos, tri, resolution, ctx=ctx, ranges=ranges, grad_db=grad_db,
                     space=space) as peeler:
        return [peeler.rasterize_next_layer() for _ in range(layers)]
