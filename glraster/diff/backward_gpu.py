"""Backward passes (and interpolation) on the GPU, in compute shaders.

Every pass runs one invocation per pixel of the flattened (B, H, W) grid. Per-pixel
outputs (interpolated attributes, dL/d rast) are written in place; per-vertex gradients
(dL/d pos, dL/d attr) are sums over the pixels of each vertex's triangles, formed by one
of three accumulations:

``"atomic_float"``
    ``atomicAdd`` on float members of a storage buffer (``GL_NV_shader_atomic_float``,
    which Mesa's llvmpipe offers). Fastest; the order of the additions is the order in
    which invocations reach them, so the float32 result may change in its last bits from
    run to run.
``"cas"``
    The fallback where the extension is missing: an ``atomicCompSwap`` loop on the float's
    bit pattern (core GL 4.3). Same result model as ``"atomic_float"``, slower.
``"per_pixel"`` (``deterministic=True``)
    Each pixel writes its three vertex contributions to a per-pixel buffer; the host sums
    them per vertex in pixel order, in float64 (``np.bincount``), and rounds once. The
    same inputs give bit-identical results on every run, and the sum carries no float32
    accumulation error.

Layouts follow the contract in docs/differentiable.md: ``rast`` (B, H, W, 4) float32 =
(u, v, z/w, triangle index + 1 encoded as a float, 0 = empty), ``rast_db`` (B, H, W, 4) =
(du/dx, du/dy, dv/dx, dv/dy) in window pixels, rows [y, x] with row 0 at the bottom.
"""

from __future__ import annotations

import numpy as np

from glraster.diff import layout
from glraster.gpu.context import Context, default_context
from glraster.gpu.shaders import shader_path

__all__ = [
    "ACCUMULATIONS", "accumulation", "has_atomic_float",
    "interpolate_backward", "interpolate_forward", "rasterize_backward",
    "rasterize_backward_pixels",
]

ACCUMULATIONS = ("atomic_float", "cas", "per_pixel")
_DEFINES = {"atomic_float": "ACCUM_ATOMIC_FLOAT", "cas": "ACCUM_CAS",
            "per_pixel": "ACCUM_PER_PIXEL"}
LOCAL_SIZE = 64
# Largest storage buffer glraster fills in one dispatch (llvmpipe allows 128 MiB); bigger
# inputs are processed in chunks of pixels.
MAX_CHUNK_BYTES = 1 << 26
ID_BITS_OFFSET = 0x4A800000
ID_FLOAT_MAX = 1 << 24


# -- helpers ------------------------------------------------------------------------------
def has_atomic_float(ctx: Context) -> bool:
    """The driver offers atomicAdd on floats in storage buffers (GL_NV_shader_atomic_float)."""
    with ctx:
        return "GL_NV_shader_atomic_float" in ctx.mgl.extensions


def accumulation(ctx: Context, deterministic: bool = False, accumulate: str | None = None) -> str:
    """The accumulation a pass uses: ``accumulate`` when given, else ``"per_pixel"`` when
    ``deterministic``, else ``"atomic_float"`` where the driver has it, else ``"cas"``."""
    if accumulate is not None:
        if accumulate not in ACCUMULATIONS:
            raise ValueError(f"accumulate must be one of {', '.join(ACCUMULATIONS)}, "
                             f"got {accumulate!r}")
        if accumulate == "atomic_float" and not has_atomic_float(ctx):
            raise ValueError("accumulate='atomic_float' needs GL_NV_shader_atomic_float, "
                             f"which {ctx.renderer} does not offer")
        return accumulate
    if deterministic:
        return "per_pixel"
    return "atomic_float" if has_atomic_float(ctx) else "cas"


def check_vertices(name: str, value, channels: int | None, batch: int) -> tuple[np.ndarray, bool]:
    """(V, C) or (B, V, C) float32 per-vertex array; returns it as (B or 1, V, C) and
    whether it was batched. ``channels`` None: any C >= 1."""
    want = f"(V, {channels}) or (B, V, {channels})" if channels else "(V, A) or (B, V, A)"
    a = np.ascontiguousarray(layout.real_array(name, value), dtype=np.float32)
    if a.ndim not in (2, 3) or (channels is not None and a.shape[-1] != channels) \
            or a.shape[-1] < 1:
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    batched = a.ndim == 3
    if batched and a.shape[0] != batch:
        raise ValueError(f"{name} has {a.shape[0]} batch entries but rast has {batch}")
    return (a if batched else a[None]), batched


def _set(program, name: str, value) -> None:
    """Set a uniform the shader uses (the compiler drops unused ones)."""
    try:
        program[name].value = value
    except KeyError:
        pass


def _chunks(total: int, bytes_per_pixel: int):
    """(first, count) ranges of pixels whose per-pixel buffers stay under MAX_CHUNK_BYTES."""
    step = max(LOCAL_SIZE, (MAX_CHUNK_BYTES // max(bytes_per_pixel, 1)) // LOCAL_SIZE * LOCAL_SIZE)
    for first in range(0, total, step):
        yield first, min(step, total - first)


def _run(ctx: Context, program, count: int) -> None:
    program.run(group_x=(count + LOCAL_SIZE - 1) // LOCAL_SIZE)
    ctx.mgl.memory_barrier()


def _read(buffer, count: int, dtype=np.float32) -> np.ndarray:
    return np.frombuffer(buffer.read(size=count * np.dtype(dtype).itemsize), dtype=dtype)


def _zeroed(ctx: Context, name: str, nbytes: int):
    buffer = ctx.scratch_buffer(name, nbytes)
    buffer.clear(size=max(16, nbytes))
    return buffer


def _corner_vertices(rast_chunk_ids: np.ndarray, first: int, tri: np.ndarray,
                     pixels_per_image: int, vertex_stride: int):
    """Covered-pixel mask of a chunk and the (N, 3) vertex rows (batch offset included)."""
    ids = layout.decode_ids(rast_chunk_ids) + 1      # index + 1, 0 = empty
    live = (ids > 0) & (ids <= len(tri))
    rows = tri[ids[live] - 1].astype(np.int64)
    if vertex_stride:
        image = (first + np.flatnonzero(live)) // pixels_per_image
        rows += (image * vertex_stride)[:, None]
    return live, rows


def _reduce(total: np.ndarray, rows: np.ndarray, contrib: np.ndarray, channels) -> None:
    """total[v, c] += sum of contrib[n, j, c] over the (n, j) with rows[n, j] == v, in pixel
    order, in float64 (np.bincount)."""
    keys = rows.ravel()
    for c in channels:
        total[:, c] += np.bincount(keys, weights=contrib[:, :, c].ravel(),
                                   minlength=total.shape[0])


# -- rasterize backward -------------------------------------------------------------------
def rasterize_backward(pos, tri, rast, grad_rast, grad_db=None, *, ctx: Context | None = None,
                       resolution=None, deterministic: bool = False, space: str = "persp",
                       accumulate: str | None = None, _pixels_out=None) -> np.ndarray:
    """dL/d pos of point-sampled rasterization, coverage frozen, on the GPU.

    Args:
        pos: (V, 4) or (B, V, 4) clip-space positions (as rasterized).
        tri: (T, 3) integer vertex indices.
        rast: (B, H, W, 4) float32 (u, v, z/w, triangle id + 1): the forward's output.
        grad_rast: (B, H, W, 4) dL/d rast; channels 0, 1 (u, v) are used, z/w and the id
            carry no gradient (dL/dz = 0).
        grad_db: None or (B, H, W, 4) dL/d rast_db, rast_db = (du/dx, du/dy, dv/dx, dv/dy)
            per window pixel (the second-order terms).
        ctx: the context (default: the process-wide one).
        resolution: (H, W); taken from rast, checked against it when given.
        deterministic: bit-identical results from run to run (``"per_pixel"``).
        space: "persp" (u, v perspective-correct, as GL's smooth) or "screen" (window-space
            barycentrics, noperspective): the space the forward rasterized in.
        accumulate: force one of :data:`ACCUMULATIONS` (tests, measurements).

    Returns:
        float32 array of pos's shape: (dL/dx, dL/dy, 0, dL/dw) per vertex; with (V, 4)
        pos the batch's contributions are summed.
    """
    ctx = ctx or default_context()
    rast = layout.image("rast", rast, dtype=np.float32)
    batch, height, width, _ = rast.shape
    if resolution is not None and tuple(int(r) for r in resolution) != (height, width):
        raise ValueError(f"resolution {tuple(resolution)} does not match rast's "
                         f"(H, W) = {(height, width)}")
    grad_rast = layout.image("grad_rast", grad_rast, rast.shape, np.float32)
    if grad_db is not None:
        grad_db = layout.image("grad_db", grad_db, rast.shape, np.float32)
    pos_shape = np.shape(pos)
    pos3, batched = check_vertices("pos", pos, 4, batch)
    num_vertices = pos3.shape[1]
    tri = layout.triangles(tri, num_vertices)
    if space not in ("persp", "screen"):
        raise ValueError(f"space must be 'persp' or 'screen', got {space!r}")
    mode = accumulation(ctx, deterministic, accumulate)

    defines = {_DEFINES[mode]: None}
    if space == "screen":
        defines["SPACE_SCREEN"] = None
    if grad_db is not None:
        defines["GRAD_DB"] = None
    pixels = batch * height * width
    hw = height * width
    stride = num_vertices if batched else 0
    flat = (rast.reshape(-1, 4), grad_rast.reshape(-1, 4),
            None if grad_db is None else grad_db.reshape(-1, 4))
    total_vertices = pos3.shape[0] * num_vertices
    per_pixel = 16 * 3 if mode == "per_pixel" else 16
    with ctx:
        program = ctx.compute_program(shader_path("diff/backward_rasterize.comp"), defines)
        ctx.storage_buffer("backward.pos", pos3.reshape(-1, 4)).bind_to_storage_buffer(0)
        ctx.storage_buffer("backward.tri", tri).bind_to_storage_buffer(1)
        if mode == "per_pixel":
            total = np.zeros((total_vertices, 4))
        else:
            grad = _zeroed(ctx, "backward.grad_pos", total_vertices * 16)
            grad.bind_to_storage_buffer(5)
        _set(program, "size", (width, height))
        _set(program, "vertex_stride", stride)
        _set(program, "n_tri", len(tri))
        for first, count in _chunks(pixels, per_pixel):
            part = slice(first, first + count)
            ctx.storage_buffer("backward.rast", flat[0][part]).bind_to_storage_buffer(2)
            ctx.storage_buffer("backward.grad_rast", flat[1][part]).bind_to_storage_buffer(3)
            if grad_db is not None:
                ctx.storage_buffer("backward.grad_db", flat[2][part]).bind_to_storage_buffer(4)
            if mode == "per_pixel":
                out = ctx.scratch_buffer("backward.contrib", count * 48)
                out.bind_to_storage_buffer(5)
            _set(program, "n_pixels", count)
            _set(program, "first_pixel", first)
            _run(ctx, program, count)
            if mode == "per_pixel":
                live, rows = _corner_vertices(flat[0][part, 3], first, tri, hw, stride)
                contrib = _read(out, count * 12).reshape(count, 3, 4)
                if _pixels_out is not None:
                    _pixels_out[part] = contrib
                _reduce(total, rows, contrib[live], (0, 1, 3))
        if mode != "per_pixel":
            total = _read(grad, total_vertices * 4).reshape(-1, 4)
    return total.astype(np.float32).reshape(pos_shape)


def rasterize_backward_pixels(pos, tri, rast, grad_rast, grad_db=None, *,
                              ctx: Context | None = None, space: str = "persp") -> np.ndarray:
    """The per-pixel terms of :func:`rasterize_backward`, before the sum over pixels.

    Returns (B, H, W, 3, 4) float32: for each pixel, (dL/dx, dL/dy, 0, dL/dw) of the pixel's
    contribution to the vertices tri[t, 0], tri[t, 1], tri[t, 2] of its triangle (0 on empty
    pixels). For error analysis and tests.
    """
    rast = layout.image("rast", rast, dtype=np.float32)
    out = np.empty((rast.shape[0] * rast.shape[1] * rast.shape[2], 3, 4), np.float32)
    rasterize_backward(pos, tri, rast, grad_rast, grad_db, ctx=ctx, space=space,
                       accumulate="per_pixel", _pixels_out=out)
    return out.reshape(rast.shape[:3] + (3, 4))


# -- interpolate --------------------------------------------------------------------------
def _diff_slots(diff_index, num_attr: int) -> np.ndarray:
    slots = np.full(max(num_attr, 1), -1, np.int32)
    for j, k in enumerate(diff_index):
        slots[k] = j
    return slots


def interpolate_forward(attr3: np.ndarray, batched: bool, rast: np.ndarray, tri: np.ndarray,
                        rast_db: np.ndarray | None, diff_index, *, ctx: Context):
    """GPU interpolation on checked inputs (see :func:`glraster.diff.interpolate.forward`):
    attr3 (B or 1, V, A) float32, rast (B, H, W, 4), tri (T, 3) int32, rast_db (B, H, W, 4)
    or None, diff_index a list of attribute indices. Returns (out, out_da or None)."""
    batch, height, width, _ = rast.shape
    num_attr = attr3.shape[2]
    n_diff = len(diff_index) if rast_db is not None else 0
    pixels = batch * height * width
    out = np.empty((pixels, num_attr), np.float32)
    out_da = np.empty((pixels, 2 * n_diff), np.float32) if n_diff else None
    flat_rast = rast.reshape(-1, 4)
    flat_db = rast_db.reshape(-1, 4) if n_diff else None
    with ctx:
        program = ctx.compute_program(shader_path("diff/interpolate.comp"), {"N_DIFF": n_diff})
        ctx.storage_buffer("interpolate.attr", attr3.reshape(-1)).bind_to_storage_buffer(0)
        ctx.storage_buffer("interpolate.tri", tri).bind_to_storage_buffer(1)
        if n_diff:
            ctx.storage_buffer("interpolate.diff_index",
                               np.asarray(diff_index, np.int32)).bind_to_storage_buffer(5)
        _set(program, "pixels_per_image", height * width)
        _set(program, "vertex_stride", attr3.shape[1] if batched else 0)
        _set(program, "n_tri", len(tri))
        _set(program, "n_attr", num_attr)
        for first, count in _chunks(pixels, 4 * (num_attr + 2 * n_diff) + 32):
            part = slice(first, first + count)
            ctx.storage_buffer("interpolate.rast", flat_rast[part]).bind_to_storage_buffer(2)
            values = ctx.scratch_buffer("interpolate.out", count * num_attr * 4)
            values.bind_to_storage_buffer(3)
            if n_diff:
                ctx.storage_buffer("interpolate.rast_db", flat_db[part]).bind_to_storage_buffer(4)
                derivs = ctx.scratch_buffer("interpolate.out_da", count * 8 * n_diff)
                derivs.bind_to_storage_buffer(6)
            _set(program, "n_pixels", count)
            _set(program, "first_pixel", first)
            _run(ctx, program, count)
            out[part] = _read(values, count * num_attr).reshape(count, num_attr)
            if n_diff:
                out_da[part] = _read(derivs, count * 2 * n_diff).reshape(count, 2 * n_diff)
    out = out.reshape(batch, height, width, num_attr)
    if out_da is not None:
        out_da = out_da.reshape(batch, height, width, 2 * n_diff)
    return out, out_da


def interpolate_backward(attr3: np.ndarray, batched: bool, rast: np.ndarray, tri: np.ndarray,
                         rast_db: np.ndarray | None, diff_index, grad_out: np.ndarray,
                         grad_out_da: np.ndarray | None, *, ctx: Context,
                         deterministic: bool = False, accumulate: str | None = None):
    """GPU backward of interpolation on checked inputs (see
    :func:`glraster.diff.interpolate.backward`). ``grad_out_da`` None: no derivative terms.
    Returns (grad_attr (B or 1, V, A) float32, grad_rast, grad_rast_db or None)."""
    batch, height, width, _ = rast.shape
    num_attr = attr3.shape[2]
    n_diff = len(diff_index) if (rast_db is not None and grad_out_da is not None) else 0
    pixels = batch * height * width
    hw = height * width
    stride = attr3.shape[1] if batched else 0
    mode = accumulation(ctx, deterministic, accumulate)
    grad_rast = np.empty((pixels, 4), np.float32)
    grad_db = np.empty((pixels, 4), np.float32) if n_diff else None
    flat = (rast.reshape(-1, 4), grad_out.reshape(pixels, num_attr),
            rast_db.reshape(-1, 4) if n_diff else None,
            grad_out_da.reshape(pixels, 2 * n_diff) if n_diff else None)
    total_slots = attr3.size
    per_pixel = 4 * (num_attr + 2 * n_diff) + 48 + (12 * num_attr if mode == "per_pixel" else 0)
    with ctx:
        program = ctx.compute_program(shader_path("diff/backward_interpolate.comp"),
                                      {_DEFINES[mode]: None, "N_DIFF": n_diff})
        ctx.storage_buffer("interpolate.attr", attr3.reshape(-1)).bind_to_storage_buffer(0)
        ctx.storage_buffer("interpolate.tri", tri).bind_to_storage_buffer(1)
        if n_diff:
            ctx.storage_buffer("interpolate.diff_slot", _diff_slots(diff_index, num_attr)
                               ).bind_to_storage_buffer(7)
        if mode == "per_pixel":
            total = np.zeros((attr3.shape[0] * attr3.shape[1], num_attr))
        else:
            grad = _zeroed(ctx, "interpolate.grad_attr", total_slots * 4)
            grad.bind_to_storage_buffer(5)
        _set(program, "pixels_per_image", hw)
        _set(program, "vertex_stride", stride)
        _set(program, "n_tri", len(tri))
        _set(program, "n_attr", num_attr)
        for first, count in _chunks(pixels, per_pixel):
            part = slice(first, first + count)
            ctx.storage_buffer("interpolate.rast", flat[0][part]).bind_to_storage_buffer(2)
            ctx.storage_buffer("interpolate.grad_out", flat[1][part]).bind_to_storage_buffer(3)
            out_rast = ctx.scratch_buffer("interpolate.grad_rast", count * 16)
            out_rast.bind_to_storage_buffer(4)
            if mode == "per_pixel":
                contrib_buffer = ctx.scratch_buffer("interpolate.contrib", count * 12 * num_attr)
                contrib_buffer.bind_to_storage_buffer(5)
            if n_diff:
                ctx.storage_buffer("interpolate.rast_db", flat[2][part]).bind_to_storage_buffer(6)
                ctx.storage_buffer("interpolate.grad_out_da", flat[3][part]
                                   ).bind_to_storage_buffer(8)
                out_db = ctx.scratch_buffer("interpolate.grad_rast_db", count * 16)
                out_db.bind_to_storage_buffer(9)
            _set(program, "n_pixels", count)
            _set(program, "first_pixel", first)
            _run(ctx, program, count)
            grad_rast[part] = _read(out_rast, count * 4).reshape(count, 4)
            if n_diff:
                grad_db[part] = _read(out_db, count * 4).reshape(count, 4)
            if mode == "per_pixel":
                live, rows = _corner_vertices(flat[0][part, 3], first, tri, hw, stride)
                contrib = _read(contrib_buffer, count * 3 * num_attr
                                ).reshape(count, 3, num_attr)[live]
                _reduce(total, rows, contrib, range(num_attr))
        if mode != "per_pixel":
            total = _read(grad, total_slots)
    grad_attr = total.astype(np.float32).reshape(attr3.shape)
    grad_rast = grad_rast.reshape(batch, height, width, 4)
    if grad_db is not None:
        grad_db = grad_db.reshape(batch, height, width, 4)
    return grad_attr, grad_rast, grad_db
