"""Compute-shader dispatch shared by the GPU cores: pixel chunks, buffers, accumulations.

Every GPU backward (and interpolate's forward) runs one invocation per pixel of the
flattened (B, H, W) grid, in chunks whose per-pixel buffers stay under
:data:`MAX_CHUNK_BYTES`. Per-pixel outputs are written in place; per-vertex gradients are
sums over the pixels of each vertex's triangles, formed by one of three accumulations:

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
    them per vertex in pixel order, in float64 (``np.bincount``, :func:`reduce_rows`), and
    rounds once. The same inputs give bit-identical results on every run, and the sum
    carries no float32 accumulation error.
"""

from __future__ import annotations

import numpy as np

from glraster.errors import ArgumentError
from glraster.diff.ids import decode_ids
from glraster.gpu.context import Context

__all__ = [
    "ACCUMULATIONS", "DEFINES", "LOCAL_SIZE", "MAX_CHUNK_BYTES", "accumulation", "chunks",
    "corner_vertices", "has_atomic_float", "read", "reduce_rows", "run", "set_uniform",
    "zeroed",
]

ACCUMULATIONS = ("atomic_float", "cas", "per_pixel")
# the shader define that selects each accumulation
DEFINES = {"atomic_float": "ACCUM_ATOMIC_FLOAT", "cas": "ACCUM_CAS",
           "per_pixel": "ACCUM_PER_PIXEL"}
LOCAL_SIZE = 64
# Largest storage buffer glraster fills in one dispatch (llvmpipe allows 128 MiB); bigger
# inputs are processed in chunks of pixels.
MAX_CHUNK_BYTES = 1 << 26


def has_atomic_float(ctx: Context) -> bool:
    """The driver offers atomicAdd on floats in storage buffers (GL_NV_shader_atomic_float)."""
    with ctx:
        return "GL_NV_shader_atomic_float" in ctx.mgl.extensions


def accumulation(ctx: Context, deterministic: bool = False, accumulate: str | None = None) -> str:
    """The accumulation a pass uses: ``accumulate`` when given, else ``"per_pixel"`` when
    ``deterministic``, else ``"atomic_float"`` where the driver has it, else ``"cas"``."""
    if accumulate is not None:
        if accumulate not in ACCUMULATIONS:
            raise ArgumentError("accumulate", f"accumulate must be one of "
                                f"{', '.join(ACCUMULATIONS)}, got {accumulate!r}")
        if accumulate == "atomic_float" and not has_atomic_float(ctx):
            raise ArgumentError("accumulate", "accumulate='atomic_float' needs "
                                "GL_NV_shader_atomic_float, which "
                                f"{ctx.renderer} does not offer")
        return accumulate
    if deterministic:
        return "per_pixel"
    return "atomic_float" if has_atomic_float(ctx) else "cas"


def set_uniform(program, name: str, value) -> None:
    """Set a uniform the shader uses (the compiler drops unused ones)."""
    try:
        program[name].value = value
    except KeyError:
        pass


def chunks(total: int, bytes_per_pixel: int):
    """(first, count) ranges of pixels whose per-pixel buffers stay under MAX_CHUNK_BYTES."""
    step = max(LOCAL_SIZE, (MAX_CHUNK_BYTES // max(bytes_per_pixel, 1)) // LOCAL_SIZE * LOCAL_SIZE)
    for first in range(0, total, step):
        yield first, min(step, total - first)


def run(ctx: Context, program, count: int) -> None:
    """Dispatch ``count`` invocations (rounded up to whole work groups), then a barrier."""
    program.run(group_x=(count + LOCAL_SIZE - 1) // LOCAL_SIZE)
    ctx.mgl.memory_barrier()


def read(buffer, count: int, dtype=np.float32) -> np.ndarray:
    """The first ``count`` values of ``buffer`` as a 1-D array of ``dtype``."""
    return np.frombuffer(buffer.read(size=count * np.dtype(dtype).itemsize), dtype=dtype)


def zeroed(ctx: Context, name: str, nbytes: int):
    """The context's scratch buffer ``name`` of at least ``nbytes``, cleared to 0."""
    buffer = ctx.scratch_buffer(name, nbytes)
    buffer.clear(size=max(16, nbytes))
    return buffer


def corner_vertices(rast_chunk_ids: np.ndarray, first: int, tri: np.ndarray,
                    pixels_per_image: int, vertex_stride: int):
    """Covered-pixel mask (count,) of a chunk starting at pixel ``first`` and the (N, 3)
    vertex rows of its covered pixels (batch offset ``image * vertex_stride`` included)."""
    ids = decode_ids(rast_chunk_ids) + 1      # index + 1, 0 = empty
    live = (ids > 0) & (ids <= len(tri))
    rows = tri[ids[live] - 1].astype(np.int64)
    if vertex_stride:
        image = (first + np.flatnonzero(live)) // pixels_per_image
        rows += (image * vertex_stride)[:, None]
    return live, rows


def reduce_rows(total: np.ndarray, rows: np.ndarray, contrib: np.ndarray, channels) -> None:
    """total[v, c] += sum of contrib[n, j, c] over the (n, j) with rows[n, j] == v, in pixel
    order, in float64 (np.bincount)."""
    keys = rows.ravel()
    for c in channels:
        total[:, c] += np.bincount(keys, weights=contrib[:, :, c].ravel(),
                                   minlength=total.shape[0])
