"""Rasterizing on the GPU: :func:`rasterize`.

Validation, then what the scene does not need is skipped (culling before upload, the
affine path when every w is equal, only the requested targets), then one draw through
:mod:`glraster.gpu.pipeline` with the shaders of the chosen :mod:`method <glraster.gpu.methods>`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError
from glraster.gpu import cull as _cull
from glraster.gpu import pipeline
from glraster.gpu.context import Context, context_or_default
from glraster.gpu.methods import (  # noqa: F401 (public)
    METHODS,
    Method,
    for_context,
    get,
)
from glraster.gpu.shaders import shader_path
from glraster.types import OUTPUTS, Raster, first_covered_sample, per_pixel

# Below this many triangles host-side culling saves less than it costs (a few numpy calls,
# ~0.1 ms); the driver drops such triangles itself, with the same result.
CULL_MIN_TRIANGLES = 256

# name -> (components, moderngl dtype) of the color target holding a float32 output
COLOR_FORMATS = {"persp": (3, "f4"), "screen": (3, "f4"), "tri_id": (1, "i4")}
# float64 barycentrics, read back exactly: each value as two uint32 halves
# (unpackDouble2x32) in an RG32UI target of its own (three per output keep every texture
# under llvmpipe's 1.5 GiB limit up to 10000x10000)
FLOAT64_PARTS = {".b0": (2, "u4"), ".b1": (2, "u4"), ".b2": (2, "u4")}


@functools.lru_cache(maxsize=64)
def _shader_path(name: str):
    """shader_path, resolved once per name (it touches the file system)."""
    return shader_path(name)


def _same_w(pos: np.ndarray, tri: np.ndarray) -> bool:
    """Every vertex used by ``tri`` has the same clip w (checked over all of ``pos`` first,
    which is cheaper and usually decides)."""
    w = pos[:, 3]
    if (w == w[0]).all():
        return True
    used = w[tri]
    return bool((used == used[0, 0]).all())


def color_targets(names, method: Method) -> dict:
    """Target name -> (components, dtype) for the requested color outputs, in canonical
    order; float64 methods split persp / screen into exact uint32 parts."""
    colors = {}
    for name in OUTPUTS:
        if name not in names or name not in COLOR_FORMATS:
            continue
        if name != "tri_id" and method.value_dtype == "f8":
            for suffix, fmt in FLOAT64_PARTS.items():
                colors[name + suffix] = fmt
        else:
            colors[name] = COLOR_FORMATS[name]
    return colors


def _check_out(out, names, shape, value_dtype) -> dict:
    """The arrays of ``out`` (a :class:`Raster`) to fill, by output name; ValueError naming
    the field when one is missing or has the wrong shape, dtype or layout."""
    if not isinstance(out, Raster):
        raise ArgumentError("out", f"out must be a glraster.Raster (e.g. an earlier result), got "
                                   f"{type(out).__name__}")
    height, width = shape
    wanted = {"persp": ((height, width, 3), value_dtype), "screen": ((height, width, 3), value_dtype),
              "depth": ((height, width), np.float32), "tri_id": ((height, width), np.int32),
              "mask": ((height, width), np.bool_)}
    arrays = {}
    for name in (*names, "mask"):
        array = getattr(out, name)
        want_shape, want_dtype = wanted[name]
        if not isinstance(array, np.ndarray):
            raise ArgumentError("out", f"out.{name} must be an array of shape {want_shape} "
                                       f"for the requested outputs, got {type(array).__name__}")
        if array.shape != want_shape or array.dtype != want_dtype \
                or not array.flags.c_contiguous or not array.flags.writeable:
            raise ArgumentError(
                "out",
                f"out.{name} must be a writeable C-contiguous {np.dtype(want_dtype).name} "
                f"array of shape {want_shape}, got {array.dtype.name} {array.shape}"
                f"{'' if array.flags.c_contiguous else ' (not C-contiguous)'}"
                f"{'' if array.flags.writeable else ' (read-only)'}")
        arrays[name] = array
    return arrays


def rasterize(pos, tri, resolution, *, ctx: Context | None = None, outputs=OUTPUTS,
              method: str = "hw", shader_files: tuple | None = None,
              cull_backfaces: bool = False, cull: bool | str = "auto",
              affine: bool | None = None, out: Raster | None = None, samples: int = 1,
              interpolation: str = "center") -> Raster:
    """Rasterize triangles on the GPU and read back barycentric targets.

    Parameters
    ----------
    pos : (V, 4) array_like of float
        Clip-space positions (x_c, y_c, z_c, w_c); converted to float32 once.
    tri : (T, 3) array_like of int
        Vertex indices; T may be 0 (an empty image).
    resolution : (height, width)
    ctx : Context, optional
        Defaults to a lazily created process-wide context.
    outputs : sequence of {"persp", "screen", "depth", "tri_id"}
        Only these are rendered and read back; the others are None in the result.
    method : {"hw", "divw", "homogeneous", "homogeneous64", "solve4"}
        How barycentrics are computed (:data:`glraster.gpu.methods.METHODS`,
        docs/performance.md). Coverage, depth and triangle ids always come from the
        driver's rasterizer. "homogeneous64" returns float64 persp / screen. "hw" runs on
        OpenGL 3.3 too (vertex attributes instead of storage buffers, the same values);
        the others need 4.5 and raise a ValueError naming the versions on an older context.
    shader_files : (vert, frag), optional
        Alternative shader files with the interface of ``raster/raster.vert`` /
        ``raster/raster.frag`` (``raster33/`` on a GL 3.3 context; used by fault
        injection); only with ``method="hw"``.
    cull_backfaces : bool
        Drop clockwise triangles (window space, GL's default front face is CCW): the
        driver's face culling (GL_CULL_FACE), and with host culling (``cull``) also
        before upload.
    cull : True, False or "auto"
        Drop before upload the triangles that cannot produce a fragment (outside the view
        volume, zero area, back faces with ``cull_backfaces``; see
        :mod:`glraster.gpu.cull`). The image is the same either way. "auto" culls for the
        methods with per-triangle host work (``cull_by_default``) and whenever back faces
        are culled; for the others llvmpipe's own trivial reject is cheaper than the host
        test plus the id remapping (docs/performance.md). False leaves everything to the
        driver, back faces to GL_CULL_FACE alone.
    affine : bool or None
        None: take the affine path when every used vertex has the same w (persp equals
        screen, so one interpolation and one readback serve both). False: never.
    out : Raster, optional
        A raster of the same resolution holding arrays for the requested outputs and the
        mask (e.g. an earlier result): they are filled in place, no new frame-sized
        arrays are allocated. The returned Raster shares them. Only with ``samples=1``.
    samples : int
        Samples per pixel: 1 (single-sample rendering, the pixel center) or a count the
        driver offers (``ctx.sample_counts``, powers of two up to GL_MAX_SAMPLES;
        llvmpipe: 1 and 4). With S > 1 ``tri_id``, ``depth`` and ``mask`` are per sample,
        (H, W, S); ``sample_positions`` (S, 2) are the driver's (docs/multisampling.md).
    interpolation : {"center", "centroid", "sample"}
        Where barycentrics are evaluated when S > 1: at the pixel center, at a point
        inside both the pixel and the triangle (GLSL ``centroid``), or at every sample
        (GLSL ``sample``: per-sample shading, ``persp`` / ``screen`` (H, W, S, 3)). With
        "center" / "centroid" ``persp`` / ``screen`` are (H, W, 3): the fragment of the
        pixel's lowest-numbered covered sample (:func:`glraster.types.first_covered_sample`).
        Methods "hw" and "divw" offer all three; "homogeneous", "homogeneous64" and
        "solve4" compute at gl_FragCoord and offer "center" only. With S = 1 every mode
        is the pixel center.

    Returns
    -------
    Raster
        ``tri_id`` always indexes the caller's ``tri``, culled or not.
        ``info["culled"]`` counts dropped triangles by reason; ``info["affine"]`` tells
        whether the affine path was taken.
    """
    names, samples, interpolation = _check_options(outputs, method, samples, interpolation,
                                                   out, shader_files, affine, cull)
    ctx = context_or_default(ctx)
    m = for_context(method, ctx)  # hw below GL 4.5: the vertex-attribute variant
    if samples > 1:
        _check_multisampling(ctx, m, samples, interpolation)
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    resolution = validate.resolution(resolution, ctx.max_texture_size)
    value_dtype = np.float64 if m.value_dtype == "f8" else np.float32
    fill = _check_out(out, names, resolution, value_dtype) if out is not None else {}

    info = {"backend": ctx.backend, "renderer": ctx.renderer, "method": method,
            "culled": {}, "affine": False, "vertex_input": m.vertex_input}
    tri, kept = _culled(ctx, m, pos, tri, resolution, cull, cull_backfaces, info)
    # (never with custom shader files: fault injection must exercise the persp path)
    is_affine = affine is None and shader_files is None and len(tri) > 0 and _same_w(pos, tri)
    info["affine"] = is_affine
    variant = _variant(m, names, is_affine, kept, samples, interpolation)
    spec = _draw_spec(ctx, m, variant, pos, tri, kept, resolution, shader_files,
                      read_depth="depth" in names, cull_backfaces=cull_backfaces,
                      samples=samples)
    values = pipeline.draw(ctx, spec, pos, tri, resolution,
                           out=_caller_targets(fill, variant.colors, names, is_affine, m))
    positions = values.pop("sample_positions", None)
    values = _outputs(values, fill, names, m, is_affine,
                      None if variant.remap_in_shader else kept)
    mask = pipeline.coverage(values)
    if "mask" in fill:
        mask = _copy_into(fill["mask"], mask)
    if samples > 1:
        return multisampled(values, mask, positions, interpolation, resolution, info)
    return Raster(resolution=resolution, mask=mask, info=info, **values)


# -- the steps of rasterize ---------------------------------------------------------------
def _check_options(outputs, method, samples, interpolation, out, shader_files, affine, cull):
    """``(names, samples, interpolation)`` validated, and ValueError naming the option
    when one is not allowed or does not go with another."""
    names = validate.outputs(outputs)
    get(method)
    samples = validate.samples(samples)
    interpolation = validate.interpolation(interpolation)
    if samples > 1 and out is not None:
        raise ArgumentError("out", "out is only supported with samples=1 (multisampled "
                                   "arrays have a sample axis)")
    if shader_files is not None and method != "hw":
        raise ArgumentError(
            "shader_files", f"shader_files replaces the 'hw' shaders; got method {method!r}")
    if affine not in (None, False):
        raise ArgumentError("affine", f"affine must be None (automatic) or False, got {affine!r}")
    if cull not in (True, False, "auto"):
        raise ArgumentError("cull", f"cull must be True, False or 'auto', got {cull!r}")
    return names, samples, interpolation


def _culled(ctx, m: Method, pos, tri, resolution, cull, cull_backfaces: bool, info: dict):
    """``(tri, kept)``: the triangles to draw, and None or the (K,) indices into the
    caller's ``tri`` of those kept, after dropping what cannot produce a fragment
    (:mod:`glraster.gpu.cull`; counts by reason in ``info["culled"]``). ValueError when
    ``pos`` does not fit in one storage block of the driver."""
    kept = None
    if cull == "auto":
        cull = m.cull_by_default or cull_backfaces
    if len(tri) >= CULL_MIN_TRIANGLES and cull:
        culling = _cull.cull(pos, tri, resolution, backfaces=cull_backfaces,
                             llvmpipe=ctx.is_llvmpipe, subpixel_bits=ctx.subpixel_bits)
        info["culled"] = culling.reasons
        if not culling.all_kept:
            kept = culling.kept
            tri = tri[kept]
    if not m.vertex_input and pos.nbytes > ctx.max_storage_block_size:
        raise ArgumentError(
            "pos",
            f"pos takes {pos.nbytes} bytes, above the driver's shader storage block "
            f"limit of {ctx.max_storage_block_size} bytes "
            f"({ctx.max_storage_block_size // 16} vertices)")
    return tri, kept


@dataclass(frozen=True)
class _Variant:
    """The shader variant of one draw.

    colors          : color target name -> (components, dtype), in attachment order
    defines         : the ``#define``s of the method's shaders for those targets
    remap_in_shader : the shader maps drawn triangles to the caller's ids (``REMAP``)
    needs_bary      : persp or screen is computed
    """

    colors: dict
    defines: dict
    remap_in_shader: bool
    needs_bary: bool


def _variant(m: Method, names, is_affine: bool, kept, samples: int,
             interpolation: str) -> _Variant:
    """The targets and defines that compute ``names`` with method ``m`` and no more."""
    # the color targets: on the affine path persp and screen are the same values
    wanted = set(names)
    if is_affine and "persp" in wanted:
        wanted = (wanted - {"persp"}) | {"screen"}
    colors = color_targets(wanted, m)
    needs_bary = "persp" in wanted or "screen" in wanted

    defines = dict(m.defines) if m.name != "hw" else {}
    defines.update(pipeline.output_defines(colors))
    # hw (raster.frag, shared with the fault-injection mutants) remaps on the host
    remap_in_shader = m.remaps_ids and kept is not None and "tri_id" in colors
    if remap_in_shader:
        defines["REMAP"] = 1
    if m.name != "hw" and is_affine:
        defines["AFFINE"] = 1
    if m.varies_screen and needs_bary:
        defines["VARY_SCREEN"] = 1
    if samples > 1 and interpolation != "center" and needs_bary:
        defines["INTERPOLATION"] = interpolation
        if m.vertex_input:
            defines["AUX_QUALIFIERS"] = 1
    return _Variant(colors, defines, remap_in_shader, needs_bary)


def _draw_spec(ctx, m: Method, variant: _Variant, pos, tri, kept, resolution, shader_files,
               *, read_depth: bool, cull_backfaces: bool, samples: int) -> pipeline.Draw:
    """The draw of ``tri`` with ``variant``'s program: the method's per-triangle setup
    (storage binding 2) and the remap table (binding 3), uniforms, state."""
    per_triangle = {}
    if m.setup is not None and variant.needs_bary and len(tri):
        per_triangle[2] = m.setup(pos[tri], resolution)
    if variant.remap_in_shader:
        per_triangle[3] = kept
    vert, frag = shader_files if shader_files is not None else (m.vert, m.frag)
    with ctx:
        program, vao = ctx.program(_shader_path(vert), _shader_path(frag), variant.defines)
    return pipeline.Draw(
        program, vao, variant.colors, read_depth=read_depth, per_triangle=per_triangle,
        uniforms=m.uniforms(*resolution) if m.uniforms and variant.needs_bary else {},
        cull_backfaces=cull_backfaces, vertex_input=m.vertex_input, samples=samples)


def _caller_targets(fill: dict, colors: dict, names, is_affine: bool, m: Method) -> dict:
    """The caller's arrays (``out=``) that targets are read into directly: those whose
    layout is the target's own."""
    targets_out = {n: fill[n] for n in colors if n in fill}
    if is_affine and "persp" in fill and "screen" not in names:
        targets_out.pop("screen", None)
        if m.value_dtype == "f4":
            targets_out["screen"] = fill["persp"]
    if "depth" in fill:
        targets_out["depth"] = fill["depth"]
    return targets_out


def _outputs(values: dict, fill: dict, names, m: Method, is_affine: bool, remap) -> dict:
    """The outputs from the targets read back: float64 joined from its parts, triangle ids
    decoded (mapped through ``remap`` (K,) when the host remaps), persp filled from screen
    on the affine path."""
    if m.value_dtype == "f8":
        values = _join_float64(values, fill)
    if "tri_id" in values:
        pipeline.decode_ids(values["tri_id"], remap)
    if is_affine and "persp" in names:
        screen = values["screen"]
        if "screen" in names:
            persp = fill.get("persp")
            values["persp"] = screen.copy() if persp is None else _copy_into(persp, screen)
        else:
            values["persp"] = screen if "persp" not in fill else _copy_into(fill["persp"], screen)
            del values["screen"]
    return values


def multisampled(values: dict, mask, positions, interpolation: str, resolution,
                 info: dict) -> Raster:
    """The :class:`Raster` of a multisampled draw from its per-sample arrays ``values``
    (tri_id / depth (H, W, S), persp / screen (H, W, S, 3)), ``mask`` (H, W, S) and the
    driver's ``positions`` (S, 2): "center" / "centroid" keep one barycentric value per
    pixel, that of the lowest-numbered covered sample's fragment."""
    if interpolation != "sample":
        first = first_covered_sample(mask)
        for name in ("persp", "screen"):
            if name in values:
                values[name] = per_pixel(values[name], first)
    return Raster(resolution=resolution, mask=mask, info=info, samples=len(positions),
                  interpolation=interpolation, sample_positions=positions, **values)


def _check_multisampling(ctx, m: Method, samples: int, interpolation: str) -> None:
    """ValueError naming what is missing when ``ctx`` cannot draw method ``m`` with
    ``samples`` per pixel and ``interpolation``."""
    offered = ctx.sample_counts
    if samples not in offered:
        raise ArgumentError(
            "samples",
            f"samples={samples} is not offered by this driver ({ctx.renderer}): choose one "
            f"of {offered} (GL_MAX_SAMPLES and the integer / depth texture limits: "
            f"{ctx.max_samples})")
    if interpolation not in m.interpolations:
        raise ArgumentError(
            "method",
            f"method {m.name!r} computes barycentrics at gl_FragCoord (the pixel center) and "
            f"offers interpolation {m.interpolations}, got {interpolation!r}; use method "
            f"'hw' or 'divw'")
    if m.vertex_input and interpolation != "center":
        missing = [e for e in ("GL_ARB_shading_language_420pack", "GL_ARB_gpu_shader5")
                   if e not in ctx.mgl.extensions]
        if missing:
            raise ArgumentError(
                "interpolation",
                f"interpolation={interpolation!r} on the OpenGL 3.3 path needs "
                f"{' and '.join(missing)}, which this driver ({ctx.renderer}) lacks")


def _copy_into(dest: np.ndarray, src: np.ndarray) -> np.ndarray:
    if dest is not src:
        np.copyto(dest, src)
    return dest


def _join_float64(values: dict, fill: dict) -> dict:
    """Float64 persp / screen (H, W, 3) from their uint32 parts, one target per channel."""
    joined = {n: a for n, a in values.items() if "." not in n}
    for name in ("persp", "screen"):
        if name + ".b0" not in values:
            continue
        dest = fill.get(name)
        if dest is None:
            dest = np.empty(values[name + ".b0"].shape[:-1] + (3,), np.float64)
        for k in range(3):
            dest[..., k:k + 1] = _doubles(values[f"{name}.b{k}"])
        joined[name] = dest
    return joined


def _doubles(words: np.ndarray) -> np.ndarray:
    """(H, W, 2 C) uint32 (low, high) word pairs from GLSL's unpackDouble2x32 -> (H, W, C)
    float64 with exactly those bits (independent of the host's byte order)."""
    bits = (words[..., 1::2].astype(np.uint64) << np.uint64(32)) | words[..., 0::2]
    return bits.view(np.float64)
