"""The one draw pipeline: render targets, batched draws, readback and id decoding.

:func:`draw` renders T triangles into float / integer color targets and a 32-bit float
depth buffer, and reads back what was asked. The shaders get the clip positions in one of
three ways:

* storage buffers (GLSL 4.50 shaders), ``glDrawArrays(3 T)``: vertex k is corner k % 3 of
  triangle k / 3, positions at binding 0 and indices at binding 1 pulled by
  ``gl_VertexID``; optional per-triangle buffers at bindings 2, 3, ...;
* indexed (``Draw.indexed``, GLSL 4.50 shaders that need no corner number):
  ``glDrawElements(3 T)`` with ``tri`` as the index buffer and the (V, 4) positions as the
  vertex attribute ``a_position``, per-triangle buffers as above. The driver's vertex
  cache then shades a vertex shared by neighbouring triangles once, where the pulled path
  shades all 3 T corners (llvmpipe's draw module, which runs the vertex stage on one
  thread: measured 11% less time for a 30k-triangle mesh at 256², docs/performance.md);
* vertex attributes (GL 3.3, ``Draw.vertex_input``): the host de-indexes the triangles
  into a vertex buffer of 3 T positions, the attribute ``a_position``, beside the vertex
  numbers k (``a_vertex``; see :meth:`Context.attribute_array`).

The triangles and the fragments they produce are the same on every path (gl_PrimitiveID
counts the triangles of a draw call in order, GL 4.5 section 11.1.3.9).

Multisampling (``Draw.samples`` S > 1): the targets are multisample textures, depth too,
and every sample is read back exactly by a resolve pass (``raster/resolve.frag``: one
``texelFetch`` per sample into a single-sample target S times as wide), never by the
driver's averaging blit; each target then reads back with a sample axis after W.

:func:`glraster.rasterize`, the fault-injection mutants and the differentiable ops all
draw through it.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np

from glraster.errors import ArgumentError, GLError
from glraster.gpu.shaders import shader_path

# moderngl dtype name -> NumPy dtype of a read-back target
NUMPY_DTYPES = {"f4": np.float32, "f2": np.float16, "i4": np.int32, "u4": np.uint32}
# moderngl dtype -> (multisample sampler, vector type) of the resolve pass
RESOLVE_TYPES = {"f4": ("sampler2DMS", "vec4"), "f2": ("sampler2DMS", "vec4"),
                 "i4": ("isampler2DMS", "ivec4"), "u4": ("usampler2DMS", "uvec4")}


@dataclass
class Draw:
    """What to draw and where.

    program, vao : the linked program and its attribute-less vertex array (Context.program)
    colors       : target name -> (components, moderngl dtype), in attachment order (the
                   shader writes target k at ``layout(location = k)``)
    read_depth   : read back window depth (a depth texture instead of a renderbuffer)
    per_triangle : storage binding -> (T, ...) C-contiguous array, split into the same
                   batches as the indices (setup records, kept ids)
    uniforms     : name -> value, set once before drawing
    cull_backfaces : enable GL_CULL_FACE (CCW front faces) for this draw
    depth_test   : False disables GL_DEPTH_TEST (which also stops depth writes)
    textures     : sampler uniform name -> moderngl texture read by the shaders (e.g. the
                   previous layer's depth when peeling); the k-th is bound to unit k
    vertex_input : positions as the vertex attribute ``a_position`` of a de-indexed vertex
                   buffer (GL 3.3 shaders, e.g. ``raster33/``) instead of storage buffers;
                   ``per_triangle`` must then be empty
    indexed      : ``glDrawElements`` over ``tri`` with positions as the vertex attribute
                   ``a_position`` (the program's vao is not used; gl_VertexID is the
                   vertex's index, there is no corner number)
    samples      : samples per pixel (1: single-sample targets, today's path); > 1 needs a
                   count the context offers (``Context.sample_counts``)
    depth_clear, depth_func : the depth buffer's clear value and the test ("<": LESS)
    """

    program: object
    vao: object
    colors: dict
    read_depth: bool = False
    per_triangle: dict = field(default_factory=dict)
    uniforms: dict = field(default_factory=dict)
    cull_backfaces: bool = False
    depth_test: bool = True
    textures: dict = field(default_factory=dict)
    vertex_input: bool = False
    indexed: bool = False
    samples: int = 1
    depth_clear: float = 1.0
    depth_func: str = "<"


# Triangles per draw on the vertex-attribute path: bounds the host's de-indexed copy of
# the positions (48 MiB) and the vertex buffer; ids stay global through ``tri_base``.
VERTEX_BATCH_TRIANGLES = 1 << 20


def draw(ctx, spec: Draw, pos: np.ndarray, tri: np.ndarray, resolution, *,
         out: dict | None = None, during: str = "rasterizing") -> dict:
    """Render ``tri`` (T, 3) int32 over ``pos`` (V, 4) float32 at ``resolution`` (H, W).

    Returns target name -> array read back: (H, W, C) for C > 1 components, else (H, W),
    of the target's NumPy dtype, plus "depth" (H, W) float32 when ``spec.read_depth``.
    With ``spec.samples`` S > 1 every array has a sample axis after W ((H, W, S, C) or
    (H, W, S)) and "sample_positions" (S, 2) float64 holds the positions the driver
    reports for the framebuffer (GL_SAMPLE_POSITION, pixel units, y up).
    Arrays given in ``out`` (same names, shapes and dtypes) are filled instead of new ones.
    Raises :class:`GLError` if the driver reports an error.
    """
    with ctx:
        targets = _render(ctx, spec, pos, tri, resolution, 0)
        if spec.samples > 1:
            values = _read_samples(ctx, spec, targets, resolution)
        else:
            values = _read(spec, targets, resolution, out or {})
        error = ctx.mgl.error
    if error != "GL_NO_ERROR":
        raise GLError(error, during)
    return values


def draw_many(ctx, draws, resolution, *, during: str = "rasterizing") -> list[dict]:
    """:func:`draw` of each ``(spec, pos, tri, out)`` of ``draws`` (single-sample specs),
    every one into its own framebuffer and buffers, and only then all read back: the
    driver may render a framebuffer's draws while the next ones are set up, where a read
    after each draw waits for it (llvmpipe queues a framebuffer's binned scene when another
    is bound). The same draws, so the same pixels as :func:`draw`. At most
    :data:`glraster.gpu.context.FRAMEBUFFER_SLOTS` draws. Returns :func:`draw`'s dicts."""
    with ctx:
        targets = render_many(ctx, [draw[:3] for draw in draws], resolution)
        values = [_read(spec, target, resolution, out or {})
                  for (spec, _, _, out), target in zip(draws, targets)]
        error = ctx.mgl.error
    if error != "GL_NO_ERROR":
        raise GLError(error, during)
    return values


def render_many(ctx, draws, resolution, *, flush: bool = False) -> list:
    """Draw each ``(spec, pos, tri)`` of ``draws`` (single-sample specs, at most
    :data:`glraster.gpu.context.FRAMEBUFFER_SLOTS`) into framebuffer slot 0, 1, ... and
    read nothing back: the :class:`glraster.gpu.context.Targets` of each, whose textures
    later GL work of the caller reads (they hold the draw until the slot is drawn again).
    ``flush``: glFlush after each draw (GL 4.4 core section 2.3.2), so that the driver
    starts on it while the host sets up the next (and the caller what comes after).
    The caller checks for GL errors."""
    with ctx:
        targets = []
        for slot, (spec, pos, tri) in enumerate(draws):
            targets.append(_render(ctx, spec, pos, tri, resolution, slot))
            if flush:
                ctx.gl_function("glFlush", None)()
        return targets


def _render(ctx, spec: Draw, pos, tri, resolution, slot: int):
    """Clear the targets of framebuffer ``slot`` and draw into them; returns them."""
    program = spec.program
    for name, value in spec.uniforms.items():
        program[name].value = value
    targets = ctx.targets(resolution, spec.colors, depth_texture=spec.read_depth,
                          samples=spec.samples, slot=slot)
    targets.fbo.use()
    targets.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=spec.depth_clear)
    for unit, (name, texture) in enumerate(spec.textures.items()):
        texture.use(location=unit)
        program[name].value = unit
    if len(tri):
        _draw_batches(ctx, spec, pos, tri, f"@{slot}" if slot else "")
    return targets


def _read(spec: Draw, targets, resolution, out: dict) -> dict:
    """The single-sample targets of ``spec`` read back (into ``out``'s arrays if given)."""
    height, width = resolution
    values = {}
    for name, (components, dtype) in spec.colors.items():
        shape = (height, width, components) if components > 1 else (height, width)
        array = out.get(name)
        if array is None:
            array = np.empty(shape, NUMPY_DTYPES[dtype])
        targets.fbo.read_into(array, components=components,
                              attachment=targets.color[name], dtype=dtype)
        values[name] = array
    if spec.read_depth:
        depth = out.get("depth")
        if depth is None:
            depth = np.empty((height, width), np.float32)
        targets.fbo.read_into(depth, components=1, attachment=-1, dtype="f4")
        values["depth"] = depth
    return values


def _draw_batches(ctx, spec: Draw, pos, tri, tag: str = "") -> None:
    """The draw calls: triangles go in batches whose index and per-triangle arrays each fit
    one storage block (vertex input: of VERTEX_BATCH_TRIANGLES); ``tri_base`` keeps the
    ids written by the shader global. ``tag`` ends the buffers' names (a framebuffer
    slot's own buffers)."""
    mgl = ctx.mgl
    if spec.vertex_input:
        if spec.per_triangle:
            raise ValueError("per-triangle storage buffers need the storage-buffer path "
                             "(OpenGL 4.5), not vertex_input")
        batch = VERTEX_BATCH_TRIANGLES
    else:
        positions = ctx.storage_buffer("positions" + tag, pos)
        if spec.indexed:
            batch = len(tri)  # the index buffer is no storage block
        else:
            positions.bind_to_storage_buffer(0)
            batch = ctx.max_storage_block_size // (3 * tri.itemsize)
        for array in spec.per_triangle.values():
            batch = min(batch, ctx.max_storage_block_size // max(array[0].nbytes, 1))
    if spec.cull_backfaces:
        mgl.enable(mgl.CULL_FACE)
    if not spec.depth_test:
        mgl.disable(mgl.DEPTH_TEST)
    if spec.depth_func != "<":
        mgl.depth_func = spec.depth_func
    try:
        for number, base in enumerate(range(0, len(tri), batch)):
            # One buffer per batch: llvmpipe shades fragments when the binned draw is
            # flushed, after a later batch would have overwritten a shared buffer that the
            # fragment shader reads (measured).
            suffix = (f"/{number}" if number else "") + tag
            part = tri[base:base + batch]
            if spec.vertex_input:
                corners = pos[part.reshape(-1)]  # (3 t, 4): corner k of triangle j at 3 j + k
                vao = ctx.attribute_array(spec.program, "vertices" + suffix, corners)
            else:
                indices = ctx.storage_buffer("indices" + suffix, part)
                if spec.indexed:
                    vao = _indexed_array(ctx, spec.program, "indices" + suffix, positions,
                                         indices)
                else:
                    vao = spec.vao
                    indices.bind_to_storage_buffer(1)
                for binding, array in spec.per_triangle.items():
                    ctx.storage_buffer(f"binding{binding}{suffix}", array[base:base + batch]) \
                        .bind_to_storage_buffer(binding)
            if "tri_base" in spec.program:
                spec.program["tri_base"].value = base
            vao.render(mgl.TRIANGLES, vertices=3 * len(part))
    finally:
        if spec.cull_backfaces:
            mgl.disable(mgl.CULL_FACE)
        if not spec.depth_test:
            mgl.enable(mgl.DEPTH_TEST)
        if spec.depth_func != "<":
            mgl.depth_func = "<"


# Context -> {(program glo, index buffer name): (program, positions, indices, vao)}
_INDEXED_ARRAYS = weakref.WeakKeyDictionary()


def _indexed_array(ctx, program, name: str, positions, indices):
    """The vertex array drawing ``program`` with ``a_position`` from the buffer
    ``positions`` ((V, 4) float32) and the uint32 index buffer ``indices`` (a storage
    buffer of ``ctx``; int32 indices >= 0 have the same bits). Cached per program and
    index buffer name, remade when either buffer was replaced (grown)."""
    cache = _INDEXED_ARRAYS.setdefault(ctx, {})
    key = (program.glo, name)
    cached = cache.get(key)
    if cached is None or cached[0] is not program or cached[1] is not positions \
            or cached[2] is not indices:
        if cached is not None and cached[0] is program:
            cached[3].release()
        vao = ctx.mgl.vertex_array(program, [(positions, "4f", "a_position")],
                                   index_buffer=indices, index_element_size=4)
        cache[key] = cached = (program, positions, indices, vao)
    return cached[3]


def _read_samples(ctx, spec: Draw, targets, resolution) -> dict:
    """Every sample of the multisample ``targets``, exactly: the resolve pass copies
    sample s of pixel (x, y) to (S x + s, y) of single-sample targets (color formats
    unchanged, depth as R32F), read back as (H, W, S, C) / (H, W, S) arrays."""
    height, width = resolution
    samples = targets.samples
    if width * samples > ctx.max_texture_size:
        raise ArgumentError(
            "resolution",
            f"resolution {height}x{width} with samples={samples}: the exact readback needs "
            f"a target {width * samples} wide, above the driver's limit of "
            f"{ctx.max_texture_size}; use a width up to {ctx.max_texture_size // samples}")
    mgl = ctx.mgl
    sources = {name: (fmt, targets.attachments[targets.color[name]])
               for name, fmt in spec.colors.items()}
    if spec.read_depth:
        sources["depth"] = ((1, "f4"), targets.depth)
    formats = {name: fmt for name, (fmt, _) in sources.items()}
    defines = {"SAMPLES": samples}
    for slot, (components, dtype) in enumerate(formats.values()):
        defines[f"SLOT{slot}_SAMPLER"], defines[f"SLOT{slot}_VEC"] = RESOLVE_TYPES[dtype]
    program, vao = ctx.program(shader_path("raster/resolve.vert"),
                               shader_path("raster/resolve.frag"), defines)
    resolved = ctx.targets((height, width * samples), formats, depth_texture=False)
    resolved.fbo.use()
    for slot, (_, texture) in enumerate(sources.values()):
        texture.use(location=slot)
        program[f"u_in{slot}"].value = slot
    mgl.disable(mgl.DEPTH_TEST)
    try:
        vao.render(mgl.TRIANGLES, vertices=3)
    finally:
        mgl.enable(mgl.DEPTH_TEST)
    values = {}
    for name, (components, dtype) in formats.items():
        shape = (height, width, samples) + ((components,) if components > 1 else ())
        array = np.empty(shape, NUMPY_DTYPES[dtype])
        resolved.fbo.read_into(array, components=components,
                               attachment=resolved.color[name], dtype=dtype)
        values[name] = array
    values["sample_positions"] = targets.sample_positions.copy()
    return values


def output_defines(colors: dict) -> dict:
    """``OUT_<NAME>`` and ``<NAME>_LOCATION`` defines for the targets of ``colors`` (names
    are upper-cased, dots become underscores), locations in attachment order."""
    defines = {}
    for location, name in enumerate(colors):
        key = name.upper().replace(".", "_")
        defines[f"OUT_{key}"] = 1
        defines[f"{key}_LOCATION"] = location
    return defines


def decode_ids(ids: np.ndarray, kept: np.ndarray | None = None) -> np.ndarray:
    """Triangle ids in place: targets hold index + 1 (the clear value 0 means empty), so
    subtract one; with ``kept`` (K,) the drawn triangles were ``tri[kept]`` and ids are
    mapped back to the caller's indexing. Empty pixels become -1."""
    ids -= 1
    if kept is not None:
        ids[...] = np.concatenate([[-1], kept]).astype(np.int32)[ids + 1]
    return ids


def coverage(values: dict) -> np.ndarray:
    """(H, W) bool coverage from whichever output was read back (each identifies covered
    pixels): tri_id >= 0; depth < 1 (a fragment must pass LESS against the cleared 1.0);
    barycentrics of a covered pixel sum to ~1, those of an empty one to 0."""
    if "tri_id" in values:
        return values["tri_id"] >= 0
    if "depth" in values:
        return values["depth"] < 1.0
    bary = values.get("persp", values.get("screen"))
    return bary.sum(axis=-1) > 0.5
