"""Antialiasing with visibility gradients on the GPU (NumPy API; Laine et al. 2020).

:func:`forward` (the GPU core of :data:`glraster.diff.ops.ANTIALIAS`, with the float64
reference's signature) blends the colours of neighbouring pixels across the silhouette edges of
the rendered mesh, so that the image depends continuously on the vertex positions there;
:func:`backward` returns the gradients of the colour and of the clip-space positions (the
two vertices of each crossing edge). The model, its derivation and its float64 twin are in
:mod:`glraster.diff.antialias_reference` and docs/differentiable.md, "Antialias":

- pairs of horizontally or vertically adjacent pixels whose triangle ids differ; from the
  nearer pixel's triangle (by ``rast``'s z/w) a walk along the segment between their
  centres crosses triangle edges, continuing into the mesh's neighbour beyond each (the
  topology hash), until an edge with no neighbour beyond it: the silhouette, handled by
  the pair whose axis is most across it;
- where it crosses the segment between the centres (tau in (0, 1) from the first pixel A),
  the pixel whose box holds the crossing takes alpha = |1/2 - tau| of the other's colour.

Three compute passes (shaders/diff/antialias_pairs.comp, antialias_blend.comp,
antialias_backward.comp) over lists the host makes (the candidate pairs, their pixels):
the pair records (one invocation per candidate pair), the blend (one per listed pixel, a
gather over its four incident pairs: deterministic), and the
backward, on the blend's compact outputs (per listed pixel its four incident pair records
and its scale, read back into the forward's saved state), so that it runs neither of the
first two again (colour gradients by gather, position gradients summed per vertex by float
atomics, a compare-and-swap loop, or with ``deterministic=True`` in 64-bit fixed point, as
:mod:`glraster.diff.compute`).

Layouts (rows [y, x] with row 0 at the bottom): color (B, H, W, C); rast (B, H, W, 4) from
the rasterizer (u, v, z/w, id); pos (V, 4) shared by the B images or (B, V, 4) one per
image; tri (T, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster.diff import compute as _gpu
from glraster.diff import recycle
from glraster import validate
from glraster.diff.edge_lists import pair_lists, put_rows, take_rows
from glraster.diff.antialias_args import AntialiasSaved, check, wanted
from glraster.diff.antialias_reference import MAX_WALK
from glraster.diff.topology_hash import TopologyHash, antialias_construct_topology_hash
from glraster.gpu.context import Context, context_or_default
from glraster.gpu.shaders import shader_path

__all__ = ["TopologyHash", "antialias_construct_topology_hash", "backward", "forward",
           "pair_records"]

PAIRS = "diff/antialias_pairs.comp"
BLEND = "diff/antialias_blend.comp"
BACKWARD = "diff/antialias_backward.comp"


def _images_per_chunk(batch: int, pixels_per_image: int, bytes_per_pixel: int) -> int:
    per_image = max(1, pixels_per_image * bytes_per_pixel)
    return max(1, min(batch, _gpu.MAX_CHUNK_BYTES // per_image))


class _Passes:
    """The compute passes over one set of inputs, image chunk by image chunk. The host lists
    each chunk's candidate pairs (neighbours whose triangle ids differ) and their pixels;
    the passes run over those lists only (every other pixel keeps its colour, and its
    colour gradient is g)."""

    def __init__(self, ctx: Context, color, rast, pos, tri, th: TopologyHash):
        self.ctx = ctx
        self.color, self.rast, self.tri, self.th = color, rast, tri, th
        self.batch, self.height, self.width, self.channels = color.shape
        self.hw = self.height * self.width
        self.pos3 = pos if pos.ndim == 3 else pos[None]
        self.stride = self.pos3.shape[1] if pos.ndim == 3 else 0

    def chunks(self, bytes_per_pixel: int):
        step = _images_per_chunk(self.batch, self.hw, bytes_per_pixel)
        for first in range(0, self.batch, step):
            yield first, min(step, self.batch - first)

    def lists(self, first: int, count: int):
        """(pair codes 2 A + axis, sorted; listed pixels, sorted) of a chunk, local, uint32
        (:func:`glraster.diff.edge_lists.pair_lists`), from rast's id channel as it is: the
        encoding is one-to-one (glraster.diff.ids) and the values checked, so ids differ
        exactly where their floats do (0.0 and -0.0, both empty, compare equal)."""
        return pair_lists(self.rast[first:first + count, :, :, 3])

    def run_pairs(self, first: int, count: int, codes: np.ndarray):
        """Pass 1 over images first .. first + count - 1; returns the records buffer (the
        records of the listed pairs: the others are not cleared) and the chunk's rast
        buffer."""
        ctx = self.ctx
        program = ctx.compute_program(shader_path(PAIRS), {"MAX_WALK": MAX_WALK})
        table = self.th.table()
        ctx.storage_buffer("antialias.pos", self.pos3.reshape(-1, 4)).bind_to_storage_buffer(0)
        ctx.storage_buffer("antialias.tri", self.tri).bind_to_storage_buffer(1)
        ctx.storage_buffer("antialias.table", table).bind_to_storage_buffer(3)
        entries = self.th.entries if len(self.th.entries) else np.zeros(1, np.int32)
        ctx.storage_buffer("antialias.entries", entries).bind_to_storage_buffer(4)
        canon = self.th.canon.astype(np.int32) if len(self.th.canon) else np.zeros(1, np.int32)
        ctx.storage_buffer("antialias.canon", canon).bind_to_storage_buffer(5)
        n = count * self.hw
        rast = self.rast.reshape(-1, 4)[first * self.hw:(first + count) * self.hw]
        rast_buffer = ctx.storage_buffer("antialias.rast", rast)
        rast_buffer.bind_to_storage_buffer(2)
        records = ctx.scratch_buffer("antialias.records", n * 32)
        records.bind_to_storage_buffer(6)
        ctx.storage_buffer("antialias.pair_list", codes).bind_to_storage_buffer(7)
        _gpu.set_uniform(program, "n_pairs", len(codes))
        _gpu.set_uniform(program, "first_image", first)
        _gpu.set_uniform(program, "size", (self.width, self.height))
        _gpu.set_uniform(program, "vertex_stride", self.stride)
        _gpu.set_uniform(program, "n_tri", len(self.tri))
        _gpu.set_uniform(program, "table_mask", len(table) - 1)
        if len(codes):
            _gpu.run(ctx, program, len(codes))
        return records, rast_buffer

    def listed(self, first: int, pixels: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(L, C) the rows of ``values`` (B, H, W, C) at a chunk's listed pixels: what the
        blend and the backward read of the colour and of its gradient (every other pixel
        keeps its value)."""
        return take_rows(values.reshape(-1, self.channels), first * self.hw, pixels)

    def run_blend(self, records, rast_buffer, pixels: np.ndarray, color: np.ndarray,
                  convex: bool):
        """Pass 2 over the listed pixels, their colours ``color`` (L, C): the compact
        buffers of their blended colours, scales and incident records."""
        ctx = self.ctx
        program = ctx.compute_program(shader_path(BLEND), {"CONVEX": None} if convex else {})
        ctx.storage_buffer("antialias.color", color.reshape(-1)).bind_to_storage_buffer(0)
        records.bind_to_storage_buffer(1)
        rast_buffer.bind_to_storage_buffer(6)
        out = ctx.scratch_buffer("antialias.out", len(pixels) * self.channels * 4)
        out.bind_to_storage_buffer(2)
        scale = ctx.scratch_buffer("antialias.scale", len(pixels) * 4)
        scale.bind_to_storage_buffer(3)
        ctx.storage_buffer("antialias.pixel_list", pixels).bind_to_storage_buffer(4)
        incident = ctx.scratch_buffer("antialias.incident", len(pixels) * 64)
        incident.bind_to_storage_buffer(5)
        _gpu.set_uniform(program, "n_list", len(pixels))
        _gpu.set_uniform(program, "size", (self.width, self.height))
        _gpu.set_uniform(program, "n_channels", self.channels)
        if len(pixels):
            _gpu.run(ctx, program, len(pixels))
        return out, scale, incident


@dataclass(frozen=True, eq=False)
class _Chunk:
    """What the forward found for images first .. first + count - 1 and the backward uses
    again instead of recomputing it: the listed pixels (L,) uint32 (sorted,
    :meth:`_Passes.lists`), their colours (L, C) and pass 2's compact outputs, per listed
    pixel its four incident pair records (L, 4, 4) uint32 and its scale (L,) float32."""

    first: int
    count: int
    pixels: np.ndarray
    color: np.ndarray
    incident: np.ndarray
    scale: np.ndarray

    @classmethod
    def read(cls, first, count, pixels, color, incident, scale) -> "_Chunk":
        """Read a chunk's incident records and scales back from their buffers."""
        n = len(pixels)
        return cls(first, count, pixels, color, _gpu.read(incident, n * 16, np.uint32),
                   _gpu.read(scale, n))


def forward(color, rast, pos, *, tri, topology_hash, pos_gradient_boost=1.0, convex=True,
            ctx: Context | None = None):
    """Antialias ``color`` across the silhouette edges of the mesh, on the GPU, on float32
    arrays checked by :func:`glraster.diff.antialias_args.check`.

    Args:
        color: (B, H, W, C) the image to antialias.
        rast: (B, H, W, 4) the rasterizer's output (u, v, z/w, id) the image was shaded from.
        pos: (V, 4) or (B, V, 4) the clip-space positions it was rasterized from.
        tri: (T, 3) int32 vertex indices.
        topology_hash: from :func:`antialias_construct_topology_hash` for ``tri``.
        pos_gradient_boost: factor on the gradients :func:`backward` gives ``pos``.
        convex: scale a pixel's weights to sum to 1 where they would sum past it (three or
            more blends), so that the output stays within the inputs' range (False: the
            plain sum, which can overshoot).
        ctx: the context (default: the process-wide one).

    Returns:
        ``((out,), saved)``: out (B, H, W, C) float32; saved an
        :class:`~glraster.diff.antialias_args.AntialiasSaved`.
    """
    ctx = context_or_default(ctx)
    passes = _Passes(ctx, color, rast, pos, tri, topology_hash)
    out = recycle.empty(color.shape)    # (a copy of color: its memory used again)
    np.copyto(out, color)
    flat_out = out.reshape(-1, passes.channels)
    kept = []
    with ctx:
        for first, count in passes.chunks(48 + 8 * passes.channels):
            codes, pixels = passes.lists(first, count)
            records, rast_buffer = passes.run_pairs(first, count, codes)
            listed = passes.listed(first, pixels, color)
            values, scale, incident = passes.run_blend(records, rast_buffer, pixels, listed,
                                                       convex)
            put_rows(flat_out, first * passes.hw, pixels, _gpu.read(
                values, len(pixels) * passes.channels).reshape(len(pixels), passes.channels))
            kept.append(_Chunk.read(first, count, pixels, listed, incident, scale))
    saved = AntialiasSaved(color, rast, pos, tri, topology_hash, float(pos_gradient_boost),
                           bool(convex), pairs=tuple(kept), ctx=ctx)
    return (out,), saved


def pair_records(color, rast, pos, tri, topology_hash=None, *, ctx: Context | None = None):
    """The pass-1 records as (B, H, W, 2, 4) uint32 (code, row_a, row_b, bits of tau) per
    pixel A and axis (0: the pair with the right neighbour, 1: with the one above); for
    tests and error analysis (arguments checked as the op's)."""
    ctx = context_or_default(ctx)
    color, rast, pos, tri, th, _, _ = check(color, rast, pos, tri, topology_hash,
                                            dtype=np.float32)
    passes = _Passes(ctx, color, rast, pos, tri, th)
    out = np.zeros((passes.batch * passes.hw, 2, 4), np.uint32)   # (unlisted: no pair)
    with ctx:
        for first, count in passes.chunks(48):
            codes, _ = passes.lists(first, count)
            records, _ = passes.run_pairs(first, count, codes)
            n = count * passes.hw
            got = _gpu.read(records, n * 8, np.uint32).reshape(2 * n, 4)
            out.reshape(-1, 4)[2 * first * passes.hw + codes.astype(np.int64)] = got[codes]
    out[..., 0] &= 3
    return out.reshape(passes.batch, passes.height, passes.width, 2, 4)


class _PositionGradients:
    """Where the backward sums the position gradients (inside ``with ctx``), bound at 6:
    a zeroed float buffer the shader adds into (float atomics or a compare-and-swap loop),
    or (fixed_point) a :class:`~glraster.diff.compute.FixedPointSum`, one exponent per
    image when pos is batched; a vertex gets at most 4 terms per pixel of its group
    (2 pairs per pixel, 2 edge vertices per pair)."""

    def __init__(self, ctx: Context, mode: str, passes: "_Passes"):
        self.ctx, self.mode = ctx, mode
        self.rows = passes.pos3.shape[0] * passes.pos3.shape[1]
        if mode == "fixed_point":
            groups = passes.pos3.shape[0]
            self.acc = _gpu.FixedPointSum(ctx, "antialias.grad_pos", groups,
                                          self.rows * 4 // groups,
                                          4 * passes.batch * passes.hw // groups, "grad_out")

    def passes(self, program):
        """Yield once per pass over all the chunks (the target cleared)."""
        if self.mode == "fixed_point":
            yield from self.acc.passes(program, 6)
        else:
            self.buffer = _gpu.zeroed(self.ctx, "antialias.grad_pos", self.rows * 16)
            yield

    def bind(self) -> None:
        """Bind the target at 6 (pass 1 of each chunk binds its records there)."""
        if self.mode == "fixed_point":
            self.acc.bind(6)
        else:
            self.buffer.bind_to_storage_buffer(6)

    def result(self) -> np.ndarray:
        """(rows, 4) the summed gradients."""
        if self.mode == "fixed_point":
            return self.acc.result().reshape(-1, 4)
        return _gpu.read(self.buffer, self.rows * 4).reshape(-1, 4)


def backward(saved: AntialiasSaved, grad_out, *, needs=None, deterministic: bool = False,
             accumulate: str | None = None):
    """Gradients of :func:`forward`, on the GPU.

    Args:
        saved: the second value :func:`forward` returned.
        grad_out: (B, H, W, C) dL/d out, or None (zero).
        needs: None (all) or three flags (color, rast, pos): without pos the shader
            computes and sums no position gradient (NO_GRAD_POS); without color the
            colour gradients are not read back; nothing runs when neither is wanted.
        deterministic: bit-identical grad_pos from run to run, whatever the order of the
            additions (64-bit fixed-point sums, :class:`glraster.diff.compute.FixedPointSum`
            states the range and the rounding).
        accumulate: force one of :data:`glraster.diff.compute.FIXED_POINT_ACCUMULATIONS`.

    Returns:
        ``(grad_color, None, grad_pos)``: grad_color (B, H, W, C) float32; grad_pos float32
        of pos' shape, (dL/dx, dL/dy, 0, dL/dw) per vertex times ``pos_gradient_boost``
        (with (V, 4) pos the images' contributions are summed); None where not wanted.
        Which pairs blend stays fixed: the gradient flows through the crossings' positions.
    """
    want_color, want_pos = wanted(needs)
    ctx, color = saved.ctx, saved.color
    grad_out = (np.zeros(color.shape, np.float32) if grad_out is None
                else validate.image("grad_out", grad_out, color.shape, np.float32))
    mode = _gpu.accumulation(ctx, deterministic, accumulate, _gpu.FIXED_POINT_ACCUMULATIONS)
    if not (want_color or want_pos):
        return None, None, None
    passes = _Passes(ctx, color, saved.rast, saved.pos, saved.tri, saved.topology_hash)
    hw, channels = passes.hw, passes.channels
    grad_color = recycle.empty(color.shape) if want_color else None
    if want_color:
        np.copyto(grad_color, grad_out)
    listed = [passes.listed(chunk.first, chunk.pixels, grad_out) for chunk in saved.pairs]
    defines = {_gpu.DEFINES[mode]: None}
    if saved.convex:
        defines["CONVEX"] = None
    if not want_pos:
        defines["NO_GRAD_POS"] = None
    with ctx:
        program = ctx.compute_program(shader_path(BACKWARD), defines)
        sums = _PositionGradients(ctx, mode, passes) if want_pos else None
        for _ in (sums.passes(program) if want_pos else [None]):
            for chunk, chunk_grad in zip(saved.pairs, listed):
                if len(chunk.pixels) == 0:
                    continue
                first = chunk.first
                out_gc = _backward_pass(passes, saved, program, chunk, chunk_grad, sums)
                if want_color:
                    put_rows(grad_color.reshape(-1, channels), first * hw, chunk.pixels,
                             _gpu.read(out_gc, len(chunk.pixels) * channels).reshape(
                                 len(chunk.pixels), channels))
        total = sums.result() if want_pos else None
    grad_pos = None
    if want_pos:
        grad_pos = total.reshape(passes.pos3.shape)
        grad_pos = (grad_pos[0] if saved.pos.ndim == 2 else grad_pos).astype(np.float32)
    return grad_color, None, grad_pos


def _backward_pass(passes: _Passes, saved: AntialiasSaved, program, chunk: _Chunk, grad_out,
                   sums: _PositionGradients | None):
    """Pass 3, the backward ``program``, over the listed pixels of one chunk of images, on
    the forward's records, scales and listed colours and ``grad_out`` (L, C) of the listed
    pixels (colour gradients by gather into the returned buffer, position gradients into
    the sums bound at 6)."""
    ctx, channels, pixels = passes.ctx, passes.channels, chunk.pixels
    ctx.storage_buffer("antialias.color", chunk.color).bind_to_storage_buffer(0)
    ctx.storage_buffer("antialias.incident", chunk.incident).bind_to_storage_buffer(1)
    ctx.storage_buffer("antialias.scale", chunk.scale).bind_to_storage_buffer(2)
    ctx.storage_buffer("antialias.grad_out", grad_out).bind_to_storage_buffer(3)
    out_gc = ctx.scratch_buffer("antialias.grad_color", len(pixels) * channels * 4)
    out_gc.bind_to_storage_buffer(4)
    ctx.storage_buffer("antialias.pos", passes.pos3.reshape(-1, 4)).bind_to_storage_buffer(5)
    if sums is not None:
        sums.bind()
    ctx.storage_buffer("antialias.pixel_list", pixels).bind_to_storage_buffer(7)
    _gpu.set_uniform(program, "n_list", len(pixels))
    _gpu.set_uniform(program, "size", (passes.width, passes.height))
    _gpu.set_uniform(program, "n_channels", channels)
    _gpu.set_uniform(program, "boost", saved.pos_gradient_boost)
    _gpu.set_uniform(program, "vertex_stride", passes.stride)
    _gpu.run(ctx, program, len(pixels))
    return out_gc
