"""The rasterize op's GPU core: forward, backward, instanced and range batches, depth peeling.

The core of :data:`glraster.diff.ops.RASTERIZE` for float32 (the float64 one is
:mod:`glraster.diff.rasterize_reference`, with the same signatures); inputs arrive checked
by :meth:`RASTERIZE.check <glraster.diff.op.Op.check>` and are not checked again.

:func:`forward` rasterizes clip-space triangles into nvdiffrast's layouts:

- ``rast`` (B, H, W, 4) float32: (u, v, z/w, id) per pixel, ``[b, y, x]`` with row 0 at the
  bottom (GL window coordinates). u = b0, v = b1 are the perspective-correct barycentrics
  of the vertices ``tri[t, 0]``, ``tri[t, 1]`` at the pixel centre (``space="screen"``: the
  window-space ones); z/w is the NDC depth z_c / w_c of the surface point there; id is
  the triangle index + 1 as a float (:func:`glraster.diff.layout.encode_ids`, exact for
  any index); all four are 0 on empty pixels.
- ``rast_db`` (B, H, W, 4) float32: (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre, per
  window pixel, 0 on empty pixels; (B, H, W, 0) with ``grad_db=False``.

Two passes per image. The raster pass (shaders/diff/rasterize.frag), an indexed draw
through the one draw pipeline (:func:`glraster.gpu.pipeline.render_many`,
``Draw.indexed``: each shared vertex shaded once), takes coverage, the depth test (LESS on
a 32-bit float depth buffer, ties keep the earlier triangle) and the triangle of each pixel
from the driver, and writes only that triangle's number. The resolve pass
(shaders/diff/rasterize.comp), one compute invocation per pixel, then computes everything
else from a per-triangle record set up on the host in float64, the "homogeneous" method's
(:mod:`glraster.gpu.homogeneous`): with the edge functions e_i = A_i x + B_i y + C_i (rows
of adj(M), M = [[X_j], [Y_j], [w_j]], X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2),
s_i = e_i / det(M), S = sum_j s_j and b_i = s_i / S,

    d b_i / dx = (A_i - b_i sum_j A_j) / (det S)        (y: B instead of A)

the exact derivative at the centre (not a 2x2-quad difference such as dFdx). The
barycentrics are evaluated compensated, so their error does not grow with the distance
from the framebuffer origin. Evaluating each covered pixel once there, instead of every
fragment that passes the depth test in the driver's partly covered 4x4 blocks, costs 30%
less for a 30k-triangle mesh at 256² (docs/performance.md); the values are the same
operations on the same inputs, so the same bits.

Batches (the B axis): ``pos`` (B, V, 4) draws ``tri`` over each ``pos[b]`` (instanced
mode); ``pos`` (V, 4) with ``ranges`` (B, 2) draws ``tri[first:first + count]`` for each
row (range mode, ids index the whole ``tri``). Each batch item is one draw into the same
cached framebuffer, read back into its slice of the output (docs/differentiable.md, "GPU",
says why not a layered array texture).

:func:`backward` is the derivative of those closed forms at the fixed pixel centres
(coverage frozen: point sampling has no visibility gradient), one compute-shader invocation
per pixel (shaders/diff/backward_rasterize.comp), summed per vertex by one of the
accumulations of :mod:`glraster.diff.compute`.

:class:`DepthPeeler` gives successive depth layers: each keeps, per pixel, the nearest
surface strictly behind the previous layer's z/w (the fragment shader evaluates z/w from the record, samples the previous layer's z/w and discards
fragments at or in front of it).
"""

from __future__ import annotations

import functools
import weakref

import numpy as np

from glraster.errors import ArgumentError, GLError
from glraster import validate
from glraster.diff import buffer_views, checked, compute, layout, recycle
from glraster.diff.saved import RasterizeSaved
from glraster.gpu import cull as _cull
from glraster.gpu import homogeneous_kernel
from glraster.gpu import pipeline
from glraster.gpu.context import (FRAMEBUFFER_SLOTS, SLOT_PIXELS, Context,
                                  context_or_default)
from glraster.gpu.shaders import shader_path

__all__ = ["DepthPeeler", "RasterizeSaved", "backward", "backward_pixels", "forward",
           "setup_records"]

VERT = "diff/rasterize.vert"
FRAG = "diff/rasterize.frag"
RESOLVE = "diff/rasterize.comp"
BACKWARD = "diff/backward_rasterize.comp"
RECORD_STRIDE = 28  # floats per triangle record, see shaders/diff/rasterize_record.glsl
RESOLVE_LOCAL = (8, 8)  # the resolve pass's work group in pixels (rasterize.comp's)
RECORD_VEC4S = RECORD_STRIDE // 4
# The resolve pass reads the records from an RGBA32F texture (rasterize_record.glsl says
# why): RECORDS_PER_ROW records a row (14336 texels, within GL 4.5's minimum
# GL_MAX_TEXTURE_SIZE of 16384), at most RECORD_TEXTURE_ROWS rows (2M records, 224 MiB)
# a dispatch.
RECORDS_PER_ROW = 2048
RECORD_TEXTURE_ROWS = 1024

# Context -> its record texture (grown by doubling, like the storage buffers)
_RECORD_TEXTURES = weakref.WeakKeyDictionary()

# Host-side culling below this many triangles costs more than the setup records it saves.
CULL_MIN_TRIANGLES = 256
# A triangle the cull drops produces no fragment when drawn (its tests are conservative),
# so the culled list (a gather of tri, and ids remapped in the shader) is used only when it
# drops at least this fraction of an item's triangles: dropping 0.8% of the 30,720 of the
# envmap scene saved less than the gather cost (measured: a forward 1.5 to 8 ms CPU
# faster without it, of 45 to 57).
CULL_MIN_DROPPED = 0.25
# An item of at least CULL_SAMPLE_TRIANGLES triangles is culled only when every
# CULL_SAMPLE_STRIDE-th of them alone (:func:`glraster.gpu.cull.dropped_estimate`) has at
# least CULL_MIN_DROPPED / 2 dropped: the envmap blob's full cull (30,720 triangles, 0.8%
# dropped, the list then unused) took 0.3 ms an item, the sample a tenth of that. Culled or
# not, the image is the same (the cull is conservative), so a wrong guess costs time only.
CULL_SAMPLE_TRIANGLES = 8192
CULL_SAMPLE_STRIDE = 16


@functools.lru_cache(maxsize=8)
def _shader_path(name: str):
    return shader_path(name)


def setup_records(pos: np.ndarray, tri: np.ndarray, resolution, out=None) -> np.ndarray:
    """(T, RECORD_STRIDE) float32 records for shaders/diff/rasterize.frag of the triangles
    ``tri`` (T, 3) int over ``pos`` (V, 4) float32: the "homogeneous" method's 24 values,
    then z_j / k (k = max_j |w_j|) for j = 0, 1, 2 and one pad, in one compiled pass
    (:func:`glraster.gpu.homogeneous_kernel.records`). ``out``: a (T, RECORD_STRIDE)
    float32 array to write into instead of a new one."""
    height, width = resolution
    if out is None:
        out = np.empty((len(tri), RECORD_STRIDE), np.float32)
    homogeneous_kernel.records(pos, tri, width, height, out, True)
    return out


class _Forward:
    """Per-item triangles (culled) and setup records, and the two passes of one forward on
    checked inputs (the peeler draws the same items once per layer)."""

    def __init__(self, pos, tri, resolution, ranges, grad_db, space, ctx):
        self.ctx = context_or_default(ctx)
        self.ctx.require_gl(45, "glraster.diff.rasterize", "shader storage buffers, GLSL 4.50")
        self.pos, self.tri, self.ranges = pos, tri, ranges
        self.grad_db, self.space = grad_db, space
        # the driver's limits (the op's check knows no context)
        self.height, self.width = validate.resolution(resolution, self.ctx.max_texture_size)
        item_bytes = pos[0].nbytes if pos.ndim == 3 else pos.nbytes
        if item_bytes > self.ctx.max_storage_block_size:
            raise ArgumentError("pos", f"pos takes {item_bytes} bytes per batch item, above "
                                "the driver's shader storage block limit of "
                                f"{self.ctx.max_storage_block_size} bytes")
        self.batch = layout.batch_size(pos, ranges)
        self.colors = {"drawn": (1, "i4")}
        self._items = [self._item(b) for b in range(self.batch)]
        self._per_row = RECORDS_PER_ROW
        self._offsets = np.cumsum([0] + [len(tri) for _, tri, _, _ in self._items]).tolist()
        # the records, item b's from _offsets[b], made per item by :meth:`records` when
        # first read (after the item's raster pass is issued)
        self._records = np.empty((self._offsets[-1], RECORD_STRIDE), np.float32)
        self._made = set()
        self._draw = None  # the raster pass's Draw (without a previous layer)
        defines = {"RECORDS_PER_ROW": self._per_row}
        if grad_db:
            defines["OUT_RAST_DB"] = 1
        if space == "screen":
            defines["SPACE_SCREEN"] = 1
        self._resolve_defines = defines
        # the resolve writes each band at its place in one buffer holding the whole
        # output (when it fits a chunk and every place is at a whole number of 256-byte
        # steps, GL 4.5's largest SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT): read back
        # whole, that buffer then holds rast for the ops that read it next
        whole = 16 * self.batch * self.height * self.width
        self._whole = whole if (whole <= compute.MAX_CHUNK_BYTES
                                and self.height * self.width % 16 == 0) else 0
        self._placed = set()  # the items resolved at their place since hand_over

    def records(self, items) -> np.ndarray:
        """The setup records of the items' drawn triangles, one item after the other:
        (sum T_b, RECORD_STRIDE) float32 (:func:`setup_records`; item b's from
        ``_offsets[b]``), those of ``items`` made now if not yet."""
        for b in items:
            if b not in self._made:
                pos, tri, _, _ = self._items[b]
                setup_records(pos, tri, (self.height, self.width),
                              out=self._records[self._offsets[b]:self._offsets[b + 1]])
                self._made.add(b)
        return self._records

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
        driver = dict(llvmpipe=self.ctx.is_llvmpipe, subpixel_bits=self.ctx.subpixel_bits)
        if len(tri) >= CULL_MIN_TRIANGLES and (
                len(tri) < CULL_SAMPLE_TRIANGLES
                or _cull.dropped_estimate(pos, tri, (self.height, self.width),
                                          stride=CULL_SAMPLE_STRIDE, **driver)
                >= CULL_MIN_DROPPED / 2):
            culling = _cull.cull(pos, tri, (self.height, self.width), **driver)
            if len(culling.kept) <= (1.0 - CULL_MIN_DROPPED) * len(tri):
                kept = (culling.kept + first).astype(np.int32)
                tri = tri[culling.kept]
        return pos, np.ascontiguousarray(tri), kept, first

    def spec(self, b, prev_depth=None) -> tuple[pipeline.Draw, np.ndarray, np.ndarray]:
        """The raster pass of item b: (Draw, pos, drawn tri)."""
        pos, tri, _, _ = self._items[b]
        if prev_depth is None and self._draw is not None:
            return self._draw, pos, tri
        defines = {"PEEL": 1} if prev_depth is not None else {}
        with self.ctx:
            program, vao = self.ctx.program(_shader_path(VERT), _shader_path(FRAG), defines)
        per_triangle, textures = {}, {}
        if prev_depth is not None:
            textures["prev_depth"] = prev_depth
            if len(tri):
                per_triangle[2] = self.records([b])[self._offsets[b]:self._offsets[b + 1]]
        spec = pipeline.Draw(program, vao, self.colors, per_triangle=per_triangle,
                             textures=textures, indexed=True)
        if prev_depth is None:
            self._draw = spec  # (the same for every item)
        return spec, pos, tri

    def new_outputs(self):
        shape = (self.batch, self.height, self.width, 4)
        rast = recycle.empty(shape)  # (every pixel resolved: as np.empty, no page faults)
        rast_db = recycle.empty(shape if self.grad_db else shape[:-1] + (0,))
        return rast, rast_db

    def _groups(self, items) -> list:
        """``items`` (consecutive) in the groups of one resolve dispatch each: all of them
        when each has one record texture's worth of records, together they fit one record
        texture and their outputs one storage block, else one by one."""
        per_block = self._per_row * RECORD_TEXTURE_ROWS
        tris = [len(self._items[b][1]) for b in items]
        rows = -(-sum(tris) // self._per_row)  # (consecutive records)
        nbytes = 16 * len(items) * self.height * self.width
        if (len(items) > 1 and max(tris) <= per_block and rows <= RECORD_TEXTURE_ROWS
                and nbytes <= self.ctx.max_storage_block_size):
            return [list(items)]
        return [[b] for b in items]

    def _resolve(self, items, targets, rast, rast_db):
        """The resolve pass of consecutive ``items`` (one of :meth:`_groups`) from their
        raster passes' ``targets`` into their slices of ``rast`` (and ``rast_db``): bands
        of rows whose outputs fit one storage block, each dispatched once per record
        texture's worth of records (the first also writes the empty pixels), then read
        back. More than one item: one band, one texture, one dispatch."""
        ctx, width, height = self.ctx, self.width, self.height
        parts = [self._items[b] for b in items]
        if len(items) == 1 and not len(parts[0][1]):
            self._placed.discard(items[0])  # (its place in the buffer is not written)
            rast[items[0]] = 0.0
            if self.grad_db:
                rast_db[items[0]] = 0.0
            return
        defines = dict(self._resolve_defines)
        remap = any(kept is not None for _, _, kept, _ in parts)
        if remap:
            defines["REMAP"] = 1
        program = ctx.compute_program(_shader_path(RESOLVE), defines)
        for unit, target in enumerate(targets):
            target.attachments[target.color["drawn"]].bind_to_image(unit, read=True,
                                                                    write=False)
        pad = (0,) * (FRAMEBUFFER_SLOTS - len(items))
        compute.set_uniform(program, "id_base", tuple(first for *_, first in parts) + pad)
        compute.set_uniform(program, "records", 0)
        per_block = self._per_row * RECORD_TEXTURE_ROWS
        blocks = range(0, max(len(tri) for _, tri, _, _ in parts), per_block)
        band = height if len(items) > 1 else max(1, ctx.max_storage_block_size // (16 * width))
        first_item, last_item = items[0], items[-1] + 1
        for first_row in range(0, height, band):
            rows = min(band, height - first_row)
            nbytes = 16 * len(items) * rows * width
            offset = 16 * width * (first_item * height + first_row) if self._whole else 0
            outputs = [ctx.scratch_buffer("rasterize.rast", self._whole or nbytes)]
            if self.grad_db:
                outputs.append(ctx.scratch_buffer("rasterize.rast_db", self._whole or nbytes))
            for binding, buffer in enumerate(outputs, 3):
                buffer.bind_to_storage_buffer(binding, offset=offset, size=nbytes)
            compute.set_uniform(program, "size", (width, rows))
            compute.set_uniform(program, "first_row", first_row)
            for start in blocks:
                counts = tuple(min(per_block, max(len(tri) - start, 0))
                               for _, tri, _, _ in parts)
                if first_row == 0 or len(blocks) > 1:
                    bases = self._upload_records(items, start, per_block)
                    compute.set_uniform(program, "record_base", bases + pad)
                if remap:
                    ids = [kept[start:start + count] if kept is not None
                           else np.arange(first + start, first + start + count, dtype=np.int32)
                           for (_, _, kept, first), count in zip(parts, counts)]
                    ctx.storage_buffer("rasterize.ids", np.concatenate(ids)) \
                        .bind_to_storage_buffer(5)
                    compute.set_uniform(program, "ids_first",
                                        tuple(np.cumsum((0,) + counts[:-1]).tolist()) + pad)
                compute.set_uniform(program, "record_first", start)
                compute.set_uniform(program, "record_count", counts + pad)
                compute.set_uniform(program, "write_empty", int(start == 0))
                program.run(group_x=-(-width // RESOLVE_LOCAL[0]),
                            group_y=-(-rows // RESOLVE_LOCAL[1]), group_z=len(items))
            ctx.mgl.memory_barrier()
            for buffer, out in zip(outputs, (rast, rast_db)):
                buffer.read_into(out[first_item:last_item, first_row:first_row + rows],
                                 size=nbytes, offset=offset)
        if self._whole:
            self._placed.update(items)

    def hand_over(self, rast) -> None:
        """When every item of ``rast`` was resolved at its place in buffer
        "rasterize.rast" (since the last call), tell the upload cache that the buffer
        holds rast's bytes (:func:`glraster.diff.checked.produced`)."""
        whole = len(self._placed) == self.batch
        checked.produced(rast if whole else None, self.ctx.uploads, "rasterize.rast")
        self._placed = set()

    def _upload_records(self, items, start: int, count: int) -> tuple:
        """Records start .. start + count - 1 of each of ``items`` (one block: several items
        only when each has at most ``count`` records, and then start is 0) into the
        context's record texture, bound to texture unit 0: consecutive in the host array,
        so written at once, only their own texels (the whole rows, then the part of the
        last); the texture index of each item's first record."""
        ctx, offsets, per_row = self.ctx, self._offsets, self._per_row
        first = offsets[items[0]] + start
        end = offsets[items[-1] + 1] if len(items) > 1 else \
            min(first + count, offsets[items[0] + 1])
        width, rows = per_row * RECORD_VEC4S, max(1, -(-(end - first) // per_row))
        texture = _RECORD_TEXTURES.get(ctx)
        if texture is None or texture.width != width or texture.height < rows:
            if texture is not None:
                texture.release()
            texture = ctx.mgl.texture((width, min(RECORD_TEXTURE_ROWS,
                                                  1 << (rows - 1).bit_length())), 4, dtype="f4")
            texture.filter = (ctx.mgl.NEAREST, ctx.mgl.NEAREST)
            _RECORD_TEXTURES[ctx] = texture
        full, rest = divmod(end - first, per_row)
        records = self.records(items)
        if full:
            texture.write(memoryview(records[first:first + full * per_row]).cast("B"),
                          viewport=(0, 0, width, full))
        if rest:
            texture.write(memoryview(records[first + full * per_row:end]).cast("B"),
                          viewport=(0, full, rest * RECORD_VEC4S, 1))
        texture.use(location=0)
        return tuple(offsets[b] + start - first for b in items)

    def draw(self, b, rast, rast_db, prev_depth=None):
        """Item b into ``rast``, ``rast_db`` (``prev_depth``: the peeler's texture)."""
        self._passes([b], rast, rast_db, prev_depth)

    def draw_all(self, rast, rast_db):
        """Every item into ``rast``, ``rast_db``: small images a few at a time, each group's
        raster passes drawn before their resolve passes read them (the driver renders one
        framebuffer while the next draw is set up)."""
        group = max(1, min(FRAMEBUFFER_SLOTS, SLOT_PIXELS // (self.height * self.width)))
        for first in range(0, self.batch, group):
            self._passes(range(first, min(first + group, self.batch)), rast, rast_db)

    def _passes(self, items, rast, rast_db, prev_depth=None):
        ctx = self.ctx
        with ctx:
            # each draw flushed: the driver rasterizes it while the host sets up the next
            # one, then the records that the resolve passes read
            targets = pipeline.render_many(
                ctx, [self.spec(b, prev_depth) for b in items], (self.height, self.width),
                flush=True)
            slots = dict(zip(items, targets))
            for group in self._groups(items):
                self._resolve(group, [slots[b] for b in group], rast, rast_db)
            error = ctx.mgl.error
        if error != "GL_NO_ERROR":
            raise GLError(error, "rasterizing (glraster.diff)")

    def saved(self, rast) -> RasterizeSaved:
        return RasterizeSaved(self.pos, self.tri, (self.height, self.width), self.ranges,
                              rast, self.space, self.ctx)


def forward(pos, *, tri, resolution, ranges=None, grad_db: bool = True, space: str = "persp",
            ctx: Context | None = None):
    """Rasterize for differentiation: ``((rast, rast_db), saved)``.

    Parameters (checked by :meth:`RASTERIZE.check <glraster.diff.op.Op.check>`)
    ----------
    pos : (V, 4) or (B, V, 4) float32
        Clip-space positions; 3-D is instanced mode (``tri`` drawn over each ``pos[b]``).
    tri : (T, 3) int32
        Vertex indices.
    resolution : (height, width)
    ranges : (B, 2) int64 or None
        Range mode (``pos`` 2-D): item b draws ``tri[first:first + count]``; ids index the
        whole ``tri``.
    grad_db : bool
        Also compute ``rast_db`` (else it is (B, H, W, 0)).
    space : {"persp", "screen"}
        u, v are perspective-correct ("persp") or window-space ("screen") barycentrics.
    ctx : Context, optional
        Defaults to the process-wide context.

    Returns
    -------
    rast : (B, H, W, 4) float32
        (u, v, z/w, id), ``[b, y, x]``, row 0 at the bottom; id = triangle index + 1
        (:func:`glraster.diff.layout.encode_ids`), 0 on empty pixels. B = 1 for 2-D
        ``pos`` without ranges.
    rast_db : (B, H, W, 4) or (B, H, W, 0) float32
        (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre (window pixels), 0 where empty.
    saved : RasterizeSaved
    """
    job = _Forward(pos, tri, resolution, ranges, grad_db, space, ctx)
    rast, rast_db = job.new_outputs()
    job.draw_all(rast, rast_db)
    job.hand_over(rast)
    return (rast, rast_db), job.saved(rast)


# --------------------------------------------------------------------------- backward

# The backward reads its gathered inputs through buffer textures (GL 4.6 section 8.9;
# :mod:`glraster.diff.buffer_views` says why) on texture units _TEXEL_UNIT + these (texture
# samples on 8-14, interpolate on 16-21).
_TEXEL_UNIT = 24
_UNIT_POS, _UNIT_TRI, _UNIT_RAST, _UNIT_GRAD_RAST, _UNIT_GRAD_DB = range(5)
_GL_RGBA32F = buffer_views.FLOATS[4]
# A work group of the accumulating passes is a tile of 64 runs of RUN_PIXELS pixels,
# _TILE_RUNS a row (backward_rasterize.comp).
_TILE_RUNS = 2


def backward(saved: RasterizeSaved, grad_rast=None, grad_db=None, *, needs=None,
             deterministic: bool = False, accumulate: str | None = None):
    """dL/d pos of point-sampled rasterization, coverage frozen: ``(grad_pos,)``.

    Args:
        saved: the forward's :class:`RasterizeSaved`.
        grad_rast: (B, H, W, 4) dL/d rast or None (zero); channels 0, 1 (u, v) are used,
            z/w and the id carry no gradient (dL/dz = 0).
        grad_db: (B, H, W, 4) dL/d rast_db (the second-order terms), or None / a
            (B, H, W, 0) array (zero).
        needs: None or (want_pos,): ``(None,)`` when pos' gradient is not wanted.
        deterministic: bit-identical results from run to run, whatever the order of the
            additions (``"fixed_point"``: :class:`glraster.diff.compute.FixedPointSum`
            states the range and the rounding).
        accumulate: force one of :data:`glraster.diff.compute.FIXED_POINT_ACCUMULATIONS`
            (tests, measurements).

    Returns:
        ``(grad_pos,)``, float32 of pos' shape: (dL/dx, dL/dy, 0, dL/dw) per vertex; with
        (V, 4) pos the batch's contributions are summed.
    """
    if needs is not None and not needs[0]:
        return (None,)
    if grad_db is not None and grad_db.shape[-1] == 0:
        grad_db = None
    if grad_rast is None and grad_db is None:
        return (np.zeros(saved.pos.shape, np.float32),)
    mode = compute.accumulation(saved.ctx, deterministic, accumulate,
                                compute.FIXED_POINT_ACCUMULATIONS)
    return (_Backward(saved, grad_rast, grad_db, mode).run(),)


def backward_pixels(saved: RasterizeSaved, grad_rast, grad_db=None) -> np.ndarray:
    """The per-pixel terms of :func:`backward`, before the sum over pixels.

    Returns (B, H, W, 3, 4) float32: for each pixel, (dL/dx, dL/dy, 0, dL/dw) of the pixel's
    contribution to the vertices tri[t, 0], tri[t, 1], tri[t, 2] of its triangle (0 on empty
    pixels). For error analysis and tests.
    """
    rast = saved.rast
    return _Backward(saved, grad_rast, grad_db, "per_pixel").run().reshape(
        rast.shape[:3] + (3, 4))


class _Backward:
    """One backward dispatch: the program and the per-vertex buffers, then the chunks of
    pixels (the shader's buffer textures: pos, tri, rast, grad_rast, grad_db; its storage
    buffer 5: the accumulated gradient or the per-pixel contributions)."""

    def __init__(self, saved: RasterizeSaved, grad_rast, grad_db, mode: str):
        self.saved, self.mode = saved, mode
        self.ctx = saved.ctx
        rast = saved.rast
        self.batch, self.height, self.width, _ = rast.shape
        if grad_rast is None:
            grad_rast = np.zeros(rast.shape, np.float32)
        self.flat = (rast.reshape(-1, 4),
                     np.ascontiguousarray(grad_rast, np.float32).reshape(-1, 4),
                     None if grad_db is None
                     else np.ascontiguousarray(grad_db, np.float32).reshape(-1, 4))
        pos = saved.pos
        self.pos3 = pos if pos.ndim == 3 else pos[None]
        self.stride = pos.shape[-2] if pos.ndim == 3 else 0
        self.defines = {compute.DEFINES[mode]: None, "TEXEL_UNIT": _TEXEL_UNIT}
        self.run_length = compute.RUN_PIXELS if mode != "per_pixel" else 1
        if self.run_length > 1:
            self.defines.update(RUN=self.run_length, TILE_RUNS=_TILE_RUNS)
        if saved.space == "screen":
            self.defines["SPACE_SCREEN"] = None
        if grad_db is not None:
            self.defines["GRAD_DB"] = None

    def run(self) -> np.ndarray:
        """grad_pos of pos' shape, or (per_pixel) the (B H W, 3, 4) per-pixel terms."""
        ctx, tri, mode = self.ctx, self.saved.tri, self.mode
        total_vertices = self.pos3.shape[0] * self.pos3.shape[1]
        pixels = self.batch * self.height * self.width
        with ctx:
            program = ctx.compute_program(shader_path(BACKWARD), self.defines)
            self._view(_UNIT_POS, "backward.pos", self.pos3.reshape(-1, 4), _GL_RGBA32F)
            self._view(_UNIT_TRI, "backward.tri", tri, buffer_views.GL_RGB32I)
            compute.set_uniform(program, "size", (self.width, self.height))
            compute.set_uniform(program, "vertex_stride", self.stride)
            compute.set_uniform(program, "n_tri", len(tri))
            if mode == "per_pixel":
                terms = np.empty((pixels, 3, 4), np.float32)
                for first, count in self._chunks(48):
                    terms[first:first + count] = self._chunk(program, first, count)
                return terms
            if mode == "fixed_point":
                # one exponent per image when pos is batched (an item then sums the same
                # bits as a call on it alone); a value gets at most 3 terms per pixel
                groups = self.batch if self.stride else 1
                acc = compute.FixedPointSum(ctx, "backward.grad_pos", groups,
                                            total_vertices * 4 // groups,
                                            3 * pixels // groups, "grad_rast")
                for _ in acc.passes(program, 5):
                    for first, count in self._chunks(16):
                        self._chunk(program, first, count)
                total = acc.result()
            else:
                grad = compute.zeroed(ctx, "backward.grad_pos", total_vertices * 16)
                grad.bind_to_storage_buffer(5)
                for first, count in self._chunks(16):
                    self._chunk(program, first, count)
                total = compute.read(grad, total_vertices * 4)
        return total.reshape(self.saved.pos.shape)

    def _chunks(self, bytes_per_pixel: int):
        """(first, count) ranges of whole image rows (the B H rows stacked) whose per-pixel
        buffers stay under compute.MAX_CHUNK_BYTES."""
        w, total = self.width, self.batch * self.height
        step = max(1, compute.MAX_CHUNK_BYTES // (bytes_per_pixel * w))
        for first_row in range(0, total, step):
            yield first_row * w, min(step, total - first_row) * w

    def _view(self, unit: int, name: str, values: np.ndarray, fmt: int) -> None:
        """Upload ``values`` (C-contiguous rows of one texel each) to storage buffer
        ``name`` and bind it as a buffer texture of format ``fmt`` on unit _TEXEL_UNIT +
        ``unit``. Inside ``with ctx``."""
        buffer_views.bind(self.ctx, _TEXEL_UNIT + unit, self.ctx.storage_buffer(name, values),
                          values.nbytes, fmt, f"rasterize's backward {name.split('.')[-1]}",
                          "use fewer vertices or triangles")

    def _chunk(self, program, first: int, count: int):
        """Run pixels first .. first + count - 1; their (count, 3, 4) contributions in
        per-pixel mode, else None (they went to the atomic sum)."""
        ctx = self.ctx
        part = slice(first, first + count)
        rast, grad_rast, grad_db = self.flat
        self._view(_UNIT_RAST, "backward.rast", rast[part], _GL_RGBA32F)
        self._view(_UNIT_GRAD_RAST, "backward.grad_rast", grad_rast[part], _GL_RGBA32F)
        if grad_db is not None:
            self._view(_UNIT_GRAD_DB, "backward.grad_db", grad_db[part], _GL_RGBA32F)
        if self.mode == "per_pixel":
            out = ctx.scratch_buffer("backward.contrib", count * 48)
            out.bind_to_storage_buffer(5)
        compute.set_uniform(program, "n_pixels", count)
        compute.set_uniform(program, "first_pixel", first)
        if self.run_length > 1:   # tiles of 64 / _TILE_RUNS rows, _TILE_RUNS runs wide
            tiles_x = -(-self.width // (_TILE_RUNS * self.run_length))
            tiles_y = -(-(count // self.width) // (compute.LOCAL_SIZE // _TILE_RUNS))
            compute.run(ctx, program, tiles_x * tiles_y * compute.LOCAL_SIZE)
        else:
            compute.run(ctx, program, count)
        if self.mode == "per_pixel":
            return compute.read(out, count * 12).reshape(count, 3, 4)
        return None


# --------------------------------------------------------------------------- depth peeling


class DepthPeeler:
    """Successive depth layers of one scene (the B axis as in :func:`forward`), from
    checked rasterize arguments (those of :func:`forward`).

    Each :meth:`rasterize_next_layer` call returns ``((rast, rast_db), saved)`` of the next
    layer, ``saved`` for :func:`backward`: per pixel, the nearest surface strictly behind
    the previous layer's z/w (fragments at or in front of it are discarded in the fragment
    shader, which samples the previous layer's z/w from a float texture). The first layer
    equals :func:`forward`; a pixel empty in one layer is empty in every later one.

    Use as a context manager, or call :meth:`release`, to free the depth texture.
    """

    def __init__(self, pos, *, tri, resolution, ranges=None, grad_db: bool = True,
                 space: str = "persp", ctx: Context | None = None):
        self._job = _Forward(pos, tri, resolution, ranges, grad_db, space, ctx)
        self.ctx = self._job.ctx
        self.layer = 0
        self._prev = None      # (B, H, W) float32 z/w of the last layer, +inf where empty
        self._texture = None

    def rasterize_next_layer(self):
        """The next layer: ``((rast, rast_db), saved)`` as from :func:`forward`."""
        job = self._job
        rast, rast_db = job.new_outputs()
        if self.layer == 0:
            job.draw_all(rast, rast_db)
        else:
            texture = self._depth_texture()
            for b in range(job.batch):
                with self.ctx:
                    texture.write(self._prev[b])
                job.draw(b, rast, rast_db, prev_depth=texture)
        job.hand_over(rast)
        self._prev = np.where(rast[..., 3] != 0, rast[..., 2], np.float32(np.inf))
        self.layer += 1
        return (rast, rast_db), job.saved(rast)

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
