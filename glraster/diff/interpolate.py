"""The interpolate op's GPU core: attribute interpolation over a raster, forward and backward.

The core of :data:`glraster.diff.ops.INTERPOLATE` for float32 (the float64 one is
:mod:`glraster.diff.interpolate_reference`, with the same signatures); inputs arrive
checked by :meth:`INTERPOLATE.check <glraster.diff.op.Op.check>`.

For a covered pixel of triangle ``t`` with ``rast = (u, v, z/w, t + 1)``::

    out = u a[tri[t, 0]] + v a[tri[t, 1]] + (1 - u - v) a[tri[t, 2]]

and, for the attributes chosen by ``diff_attrs``, their screen derivatives by the chain
rule through ``rast_db = (du/dx, du/dy, dv/dx, dv/dy)``::

    dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx,   dA/dy = (a0 - a2) du/dy + (a1 - a2) dv/dy

Both passes are compute shaders (shaders/diff/interpolate.comp,
shaders/diff/backward_interpolate.comp), :data:`glraster.diff.compute.RUN_PIXELS`
consecutive pixels per invocation (a triangle's corners read once per stretch of its pixels)
and the attribute count a compile-time constant, dispatched in chunks by
:mod:`glraster.diff.compute`; dL/d attr is summed per vertex by one of its accumulations.
The gathered inputs (attributes, triangles, rast, rast_db and the incoming gradients) are
read through buffer textures over their storage buffers (:mod:`glraster.diff.buffer_views`):
on llvmpipe several times faster than storage-buffer loads at per-pixel addresses, the
same floats.
"""

from __future__ import annotations

import numpy as np

from glraster.diff import buffer_views, compute, recycle
from glraster.diff.address import address
from glraster.diff.saved import InterpolateSaved
from glraster.gpu.context import Context, context_or_default
from glraster.gpu.shaders import shader_path

__all__ = ["InterpolateSaved", "backward", "forward"]

FORWARD = "diff/interpolate.comp"
BACKWARD = "diff/backward_interpolate.comp"


# Buffer textures (GL 4.6 section 8.9) over the passes' input buffers, on texture units
# _TEXEL_UNIT + the unit of include/interpolate_views.glsl (no other pass samples there).
_TEXEL_UNIT = 16
_UNIT_ATTR, _UNIT_TRI, _UNIT_RAST, _UNIT_RAST_DB, _UNIT_GRAD_OUT, _UNIT_GRAD_OUT_DA = range(6)


def _row_vec(num_attr: int) -> int:  # floats per fetch of an attribute row
    return buffer_views.float_vec(num_attr)


def _bind_view(ctx: Context, unit: int, buffer, texels: int, fmt: int, what: str) -> None:
    """Bind the first ``texels`` texels of ``buffer`` (of the sized format ``fmt``) as a
    buffer texture on unit _TEXEL_UNIT + ``unit``. Inside ``with ctx``."""
    buffer_views.bind(ctx, _TEXEL_UNIT + unit, buffer, texels * buffer_views.texel_bytes(fmt),
                      fmt, f"interpolate's {what}", "use fewer vertices or attributes")


def _bind_pixels(ctx: Context, unit: int, name: str, values: np.ndarray, vec: int) -> None:
    """Upload ``values`` (C-contiguous float32) to storage buffer ``name`` and bind it as a
    buffer texture of ``vec`` floats a texel on ``unit``."""
    _bind_view(ctx, unit, ctx.storage_buffer(name, values), values.size // vec,
               buffer_views.FLOATS[vec], name.split(".")[-1])


def _columns(diff_index: tuple) -> tuple[tuple, list]:
    """The distinct chosen attributes (first-listed order) and, per listing, its place
    among them: the GPU derives each attribute once, repeats are copies."""
    unique = tuple(dict.fromkeys(diff_index))
    return unique, [unique.index(k) for k in diff_index]


class _Pass:
    """What both passes bind: attributes and triangles (buffer textures) on ``ctx``, and the
    uniforms of the flattened (B, H, W) pixel grid."""

    def __init__(self, attr: np.ndarray, rast: np.ndarray, tri: np.ndarray, ctx: Context):
        self.attr3 = attr if attr.ndim == 3 else attr[None]
        # a batch of one attribute set broadcasts: every image reads vertex rows 0 .. V-1
        self.stride = self.attr3.shape[1] if self.attr3.shape[0] > 1 else 0
        self.rast, self.tri, self.ctx = rast, tri, ctx
        self.batch, self.height, self.width, _ = rast.shape
        self.pixels = self.batch * self.height * self.width
        self.num_attr = self.attr3.shape[2]
        self.vec = _row_vec(self.num_attr)

    def defines(self) -> dict:
        return {"N_ATTR": self.num_attr, "ATTR_VEC": self.vec, "TEXEL_UNIT": _TEXEL_UNIT,
                "RUN": compute.RUN_PIXELS}

    def bind(self, program) -> None:
        ctx = self.ctx
        _bind_pixels(ctx, _UNIT_ATTR, "interpolate.attr", self.attr3.reshape(-1), self.vec)
        _bind_view(ctx, _UNIT_TRI, ctx.storage_buffer("interpolate.tri", self.tri),
                   len(self.tri), buffer_views.GL_RGB32I, "tri")
        compute.set_uniform(program, "pixels_per_image", self.height * self.width)
        compute.set_uniform(program, "vertex_stride", self.stride)
        compute.set_uniform(program, "n_tri", len(self.tri))

    def image(self, flat: np.ndarray) -> np.ndarray:
        return flat.reshape(self.batch, self.height, self.width, -1)


def forward(attr, rast, rast_db=None, *, tri, diff_attrs=None, ctx: Context | None = None):
    """Interpolate per-vertex attributes over a raster, on the GPU.

    Args (checked by :meth:`INTERPOLATE.check <glraster.diff.op.Op.check>`):
        attr: (V, A) or (B', V, A) float32 per-vertex attributes (B' = 1 broadcasts).
        rast: (B, H, W, 4) float32 (u, v, z/w, triangle index + 1; 0 = empty), rows [y, x]
            with row 0 at the bottom.
        rast_db: None or (B, H, W, 4) float32 (du/dx, du/dy, dv/dx, dv/dy) per window pixel;
            needed for ``diff_attrs``.
        tri: (T, 3) int32 vertex indices (the rasterized ones).
        diff_attrs: None or a tuple of attribute indices whose screen derivatives to return
            (in that order; a repeated index repeats its columns).
        ctx: the context (default: the process-wide one).

    Returns:
        ``((out, out_da), saved)``: out (B, H, W, A) float32; out_da (B, H, W, 2 D) float32
        with (dA_k/dx, dA_k/dy) for the D chosen attributes in diff_attrs' order
        ((B, H, W, 0) when none is chosen); saved an :class:`InterpolateSaved`. Empty
        pixels are 0 in both.
    """
    ctx = context_or_default(ctx)
    diff_index = tuple(diff_attrs or ())
    if not diff_index:
        rast_db = None
    job = _Pass(attr, rast, tri, ctx)
    unique, place = _columns(diff_index)
    out, out_da = _forward(job, rast_db, unique)
    if len(unique) != len(diff_index):
        pairs = out_da.reshape(out_da.shape[:3] + (len(unique), 2))
        out_da = np.ascontiguousarray(pairs[..., place, :].reshape(out.shape[:3] + (-1,)))
    return (out, out_da), InterpolateSaved(attr, rast, tri, rast_db, diff_index, ctx)


def _forward(job: _Pass, rast_db, diff_index: tuple):
    """out (B, H, W, A) and out_da (B, H, W, 2 D) of the distinct chosen attributes."""
    ctx, num_attr = job.ctx, job.num_attr
    n_diff = len(diff_index)
    out = recycle.empty((job.pixels, num_attr))     # (every row read back below)
    out_da = np.empty((job.pixels, 2 * n_diff), np.float32)
    flat_rast = job.rast.reshape(-1, 4)
    flat_db = rast_db.reshape(-1, 4) if n_diff else None
    run = compute.RUN_PIXELS
    with ctx:
        program = ctx.compute_program(shader_path(FORWARD), {"N_DIFF": n_diff,
                                                             **job.defines()})
        job.bind(program)
        if n_diff:
            ctx.storage_buffer("interpolate.diff_index",
                               np.asarray(diff_index, np.int32)).bind_to_storage_buffer(5)
        for first, count in compute.chunks(job.pixels, 4 * (num_attr + 2 * n_diff) + 32):
            part = slice(first, first + count)
            _bind_pixels(ctx, _UNIT_RAST, "interpolate.rast", flat_rast[part], 4)
            values = ctx.scratch_buffer("interpolate.out", count * num_attr * 4)
            values.bind_to_storage_buffer(3)
            if n_diff:
                _bind_pixels(ctx, _UNIT_RAST_DB, "interpolate.rast_db", flat_db[part], 4)
                derivs = ctx.scratch_buffer("interpolate.out_da", count * 8 * n_diff)
                derivs.bind_to_storage_buffer(6)
            compute.set_uniform(program, "n_pixels", count)
            compute.set_uniform(program, "first_pixel", first)
            compute.run(ctx, program, -(-count // run))
            # straight into the outputs' rows (one copy, not bytes then array)
            values.read_into(out[part], size=count * num_attr * 4)
            if n_diff:
                derivs.read_into(out_da[part], size=count * 8 * n_diff)
    return job.image(out), job.image(out_da)


def backward(saved: InterpolateSaved, grad_out=None, grad_out_da=None, *, needs=None,
             deterministic: bool = False, accumulate: str | None = None):
    """Gradients of :func:`forward`, on the GPU.

    Args:
        saved: the forward's :class:`InterpolateSaved`.
        grad_out: (B, H, W, A) dL/d out, or None (zero).
        grad_out_da: (B, H, W, 2 D) dL/d out_da, or None / (B, H, W, 0) (zero).
        needs: None or (want_attr, want_rast, want_rast_db). Nothing is dispatched when
            none is wanted; an unwanted grad_attr is not accumulated (the shader's
            NO_GRAD_ATTR), unwanted per-pixel gradients neither written nor read back.
        deterministic: bit-identical grad_attr from run to run, whatever the order of the
            additions (64-bit fixed-point sums, :class:`glraster.diff.compute.FixedPointSum`
            states the range and the rounding); otherwise float atomics.
        accumulate: force one of :data:`glraster.diff.compute.FIXED_POINT_ACCUMULATIONS`.

    Returns:
        ``(grad_attr, grad_rast, grad_rast_db)``: grad_attr float32 of attr's shape (a
        broadcast attr gets the sum over the batch); grad_rast (B, H, W, 4) float32
        (dL/du, dL/dv, 0, 0); grad_rast_db (B, H, W, 4) float32
        dL/d(du/dx, du/dy, dv/dx, dv/dy), None without derivative terms (no diff_attrs in
        the forward, or no grad_out_da). Empty pixels are 0; unwanted entries None.
    """
    want = (True, True, True) if needs is None else tuple(bool(n) for n in needs)
    n_diff = len(saved.diff_attrs)
    if grad_out_da is not None and (grad_out_da.shape[-1] == 0 or not n_diff):
        grad_out_da = None
    want = (want[0], want[1], want[2] and grad_out_da is not None)
    if not any(want) or (grad_out is None and grad_out_da is None):
        return tuple(_zeros_if(w, shape) for w, shape in zip(want, _shapes(saved)))
    job = _Pass(saved.attr, saved.rast, saved.tri, saved.ctx)
    if grad_out is None:
        grad_out = np.zeros(saved.rast.shape[:3] + (job.num_attr,), np.float32)
    unique, place = _columns(saved.diff_attrs)
    if grad_out_da is not None and len(unique) != n_diff:
        pairs = grad_out_da.reshape(grad_out_da.shape[:3] + (n_diff, 2))
        folded = np.zeros(pairs.shape[:3] + (len(unique), 2), np.float32)
        for j, col in enumerate(place):
            folded[..., col, :] += pairs[..., j, :]
        grad_out_da = folded.reshape(pairs.shape[:3] + (-1,))
    mode = compute.accumulation(saved.ctx, deterministic, accumulate,
                                compute.FIXED_POINT_ACCUMULATIONS)
    grad_attr, grad_rast, grad_db = _Backward(job, saved, unique, mode, want).run(
        np.ascontiguousarray(grad_out, np.float32),
        None if grad_out_da is None else np.ascontiguousarray(grad_out_da, np.float32))
    if grad_attr is not None:
        grad_attr = grad_attr.reshape(saved.attr.shape)
    return grad_attr, grad_rast, grad_db


def _shapes(saved: InterpolateSaved):
    return saved.attr.shape, saved.rast.shape, saved.rast.shape


def _zeros_if(wanted: bool, shape):
    return np.zeros(shape, np.float32) if wanted else None


class _Backward:
    """One backward dispatch (the shader's storage bindings: 4 grad_rast, 5 the accumulated
    grad_attr, 7 the chosen attributes' slots, 9 grad_rast_db; buffer textures for attr,
    tri, rast, rast_db, grad_out and grad_out_da)."""

    def __init__(self, job: _Pass, saved: InterpolateSaved, diff_index: tuple, mode: str,
                 want: tuple[bool, bool, bool]):
        self.job, self.saved, self.diff_index = job, saved, diff_index
        self.mode, self.want = mode, want

    def run(self, grad_out: np.ndarray, grad_out_da: np.ndarray | None):
        job, mode, ctx = self.job, self.mode, self.job.ctx
        num_attr = job.num_attr
        n_diff = len(self.diff_index) if grad_out_da is not None else 0
        want_attr, want_rast, want_db = self.want
        flat = (job.rast.reshape(-1, 4), grad_out.reshape(job.pixels, num_attr),
                self.saved.rast_db.reshape(-1, 4) if n_diff else None,
                grad_out_da.reshape(job.pixels, 2 * n_diff) if n_diff else None)
        grad_rast = recycle.empty((job.pixels, 4)) if want_rast else None   # (all read back)
        grad_db = np.empty((job.pixels, 4), np.float32) if want_db and n_diff else None
        per_pixel = 4 * (num_attr + 2 * n_diff) + 48
        run = compute.RUN_PIXELS
        defines = {compute.DEFINES[mode]: None, "N_DIFF": n_diff, **job.defines()}
        if not want_attr:
            defines["NO_GRAD_ATTR"] = None
        if grad_rast is None and grad_db is None:
            defines["NO_GRAD_RAST"] = None

        def dispatch():
            for first, count in compute.chunks(job.pixels, per_pixel):
                part = slice(first, first + count)
                out_rast, out_db = self._chunk(program, flat, first, count, n_diff, run)
                # straight into the outputs' rows (one copy, not bytes then array)
                if grad_rast is not None:
                    out_rast.read_into(grad_rast[part], size=count * 16)
                    if count == job.pixels:  # all of it: the buffer holds grad_rast's bytes
                        ctx.uploads.produced("interpolate.grad_rast",
                                             (address(grad_rast), grad_rast.nbytes))
                if grad_db is not None:
                    out_db.read_into(grad_db[part], size=count * 16)

        total = None
        with ctx:
            program = ctx.compute_program(shader_path(BACKWARD), defines)
            job.bind(program)
            if n_diff:
                ctx.storage_buffer("interpolate.diff_slot", self._slots()
                                   ).bind_to_storage_buffer(7)
            if mode == "fixed_point" and want_attr:
                # one exponent per image when attr is batched (an item then sums the same
                # bits as a call on it alone); a value gets at most 3 terms per pixel
                groups = job.attr3.shape[0]
                acc = compute.FixedPointSum(ctx, "interpolate.grad_attr", groups,
                                            job.attr3.size // groups, 3 * job.pixels // groups,
                                            "grad_out")
                for _ in acc.passes(program, 5):
                    dispatch()
                total = acc.result()
            else:
                if want_attr:
                    grad = compute.zeroed(ctx, "interpolate.grad_attr", job.attr3.size * 4)
                    grad.bind_to_storage_buffer(5)
                dispatch()
                if want_attr:
                    total = compute.read(grad, job.attr3.size)
        grad_attr = total
        return (grad_attr,
                None if grad_rast is None else job.image(grad_rast),
                None if grad_db is None else job.image(grad_db))

    def _slots(self) -> np.ndarray:
        """Per attribute: its place among the chosen ones, or -1."""
        slots = np.full(max(self.job.num_attr, 1), -1, np.int32)
        for j, k in enumerate(self.diff_index):
            slots[k] = j
        return slots

    def _chunk(self, program, flat, first: int, count: int, n_diff: int, run: int):
        """Run pixels first .. first + count - 1, ``run`` per invocation: the buffers
        holding their grad_rast and grad_rast_db (or None)."""
        ctx = self.job.ctx
        part = slice(first, first + count)
        _bind_pixels(ctx, _UNIT_RAST, "interpolate.rast", flat[0][part], 4)
        _bind_pixels(ctx, _UNIT_GRAD_OUT, "interpolate.grad_out", flat[1][part], self.job.vec)
        out_rast = ctx.scratch_buffer("interpolate.grad_rast", count * 16)
        out_rast.bind_to_storage_buffer(4)
        out_db = None
        if n_diff:
            _bind_pixels(ctx, _UNIT_RAST_DB, "interpolate.rast_db", flat[2][part], 4)
            _bind_pixels(ctx, _UNIT_GRAD_OUT_DA, "interpolate.grad_out_da", flat[3][part], 2)
            out_db = ctx.scratch_buffer("interpolate.grad_rast_db", count * 16)
            out_db.bind_to_storage_buffer(9)
        compute.set_uniform(program, "n_pixels", count)
        compute.set_uniform(program, "first_pixel", first)
        compute.run(ctx, program, -(-count // run))
        return out_rast, out_db
