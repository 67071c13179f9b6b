"""Rasterizing on the GPU: the :class:`Raster` result and :func:`rasterize`."""

from __future__ import annotations

import functools

import numpy as np

from glraster import validate
from glraster.errors import GLError
from glraster.types import OUTPUTS, Raster
from glraster.gpu import cull as _cull
from glraster.gpu import homogeneous as _homogeneous
from glraster.gpu.context import Context, default_context
from glraster.gpu.shaders import shader_path

# method name -> (vertex shader file, fragment shader file)
METHODS = {
    "hw": ("raster/raster.vert", "raster/raster.frag"),
    "divw": ("raster/pull.vert", "methods/divw.frag"),
    "homogeneous": ("raster/pull.vert", "methods/homogeneous.frag"),
    "homogeneous64": ("raster/pull.vert", "methods/homogeneous.frag"),
    "solve4": ("raster/pull.vert", "methods/solve4.frag"),
}
METHOD_NOTES = {
    "hw": "the driver's smooth / noperspective interpolation",
    "divw": "noperspective barycentrics divided by per-vertex w in the shader (seed 002 eq. 2.4.9)",
    "homogeneous": "2D homogeneous edge functions per pixel, relative to a vertex, compensated float32",
    "homogeneous64": "the same in float64 (GL 4.0 fp64)",
    "solve4": "seed 000's 4x4 linear system per pixel, float32 Gaussian elimination",
}

# Below this many triangles host-side culling saves less than it costs (a few numpy calls,
# ~0.1 ms); the driver drops such triangles itself, with the same result.
CULL_MIN_TRIANGLES = 256

# name -> (components, dtype) of the color target holding it
COLOR_FORMATS = {"persp": (3, "f4"), "screen": (3, "f4"), "tri_id": (1, "i4")}


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


def _mask_from(values: dict) -> np.ndarray:
    """Coverage from whichever output was read back (each one identifies covered pixels).

    tri_id >= 0; depth < 1 (a fragment must pass LESS against the cleared 1.0); the
    barycentrics of a covered pixel sum to ~1, those of an empty one to 0.
    """
    if "tri_id" in values:
        return values["tri_id"] >= 0
    if "depth" in values:
        return values["depth"] < 1.0
    bary = values.get("persp", values.get("screen"))
    return bary.sum(axis=2) > 0.5


def rasterize(
    pos,
    tri,
    resolution,
    *,
    ctx: Context | None = None,
    outputs=OUTPUTS,
    method: str = "hw",
    shader_files: tuple | None = None,
    cull_backfaces: bool = False,
    cull: bool | str = "auto",
    affine: bool | None = None,
    extra_defines: dict | None = None,
) -> Raster:
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
        How barycentrics are computed (see METHOD_NOTES and docs/performance.md). Coverage,
        depth and triangle ids always come from the driver's rasterizer.
    shader_files : (vert, frag), optional
        Alternative shader files with the interface of ``raster.vert`` / ``raster.frag``
        (used by fault injection); only with ``method="hw"``.
    cull_backfaces : bool
        Drop clockwise triangles (window space, GL's default front face is CCW).
    cull : True, False or "auto"
        Drop before upload the triangles that cannot produce a fragment (outside the view
        volume, zero area; see :mod:`glraster.cull`). The image is the same either way.
        "auto" culls for the methods that do per-triangle work on the host (homogeneous,
        homogeneous64) and whenever back faces are culled; for the others llvmpipe's own
        trivial reject is cheaper than the host test plus the id remapping (measured in
        docs/performance.md).
    affine : bool or None
        None: take the affine path when every used vertex has the same w (persp equals
        screen, so one interpolation and one readback serve both). False: never.

    extra_defines : dict, optional
        More ``#define``s for the method's shaders, for diagnostics (glraster.studies.stress uses
        SPLIT64 of homogeneous.frag to read float64 results as two float32 parts).

    Returns
    -------
    Raster
        ``tri_id`` always indexes the caller's ``tri``, culled or not.
        ``info["culled"]`` counts dropped triangles by reason; ``info["affine"]`` tells
        whether the affine path was taken.
    """
    names = validate.outputs(outputs)
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    if shader_files is not None and method != "hw":
        raise ValueError(f"shader_files replaces the 'hw' shaders; got method {method!r}")
    if affine not in (None, False):
        raise ValueError(f"affine must be None (automatic) or False, got {affine!r}")
    ctx = ctx if ctx is not None else default_context()
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution, ctx.max_texture_size)

    # -- skip what the scene does not need ----------------------------------------------
    kept = None
    info = {"backend": ctx.backend, "renderer": ctx.renderer, "method": method,
            "culled": {}, "affine": False}
    if cull not in (True, False, "auto"):
        raise ValueError(f"cull must be True, False or 'auto', got {cull!r}")
    if cull == "auto":
        cull = method.startswith("homogeneous") or cull_backfaces
    if len(tri) >= CULL_MIN_TRIANGLES and (cull or cull_backfaces):
        culling = _cull.cull(pos, tri, (height, width), backfaces=cull_backfaces,
                             llvmpipe=ctx.is_llvmpipe, subpixel_bits=ctx.subpixel_bits)
        info["culled"] = culling.reasons
        if not culling.all_kept:
            kept = culling.kept
            tri = tri[kept]
    if pos.nbytes > ctx.max_storage_block_size:
        raise ValueError(
            f"pos takes {pos.nbytes} bytes, above the driver's shader storage block "
            f"limit of {ctx.max_storage_block_size} bytes ({ctx.max_storage_block_size // 16} vertices)"
        )
    # (never with custom shader files: fault injection must exercise the persp path)
    is_affine = affine is None and shader_files is None and len(tri) > 0 and _same_w(pos, tri)
    info["affine"] = is_affine

    # the color targets: on the affine path persp and screen are the same values
    wanted = set(names)
    if is_affine and "persp" in wanted:
        wanted = (wanted - {"persp"}) | {"screen"}
    colors = {n: COLOR_FORMATS[n] for n in OUTPUTS if n in wanted and n in COLOR_FORMATS}

    if shader_files is not None:
        vert, frag = shader_files
    else:
        vert, frag = METHODS[method]
    defines = {}
    for location, name in enumerate(colors):
        defines[f"OUT_{name.upper()}"] = 1
        defines[f"{name.upper()}_LOCATION"] = location
    # hw (raster.frag, shared with the fault-injection copies) remaps on the host
    remap_in_shader = method != "hw" and kept is not None and "tri_id" in colors
    if remap_in_shader:
        defines["REMAP"] = 1
    if method != "hw":
        if is_affine:
            defines["AFFINE"] = 1
        if method == "divw" and ("persp" in colors or "screen" in colors):
            defines["VARY_SCREEN"] = 1
        if method == "homogeneous64":
            defines["FP64"] = 1
    if extra_defines:
        defines.update(extra_defines)
    needs_bary = "persp" in colors or "screen" in colors
    records = None
    if method.startswith("homogeneous") and needs_bary and len(tri):
        records = _homogeneous.setup(pos[tri], (height, width), fp64=method == "homogeneous64")

    values = {}
    with ctx:
        mgl = ctx.mgl
        program, vao = ctx.program(_shader_path(vert), _shader_path(frag), defines)
        if method == "solve4" and needs_bary:
            program["u_ndc_scale"].value = (2.0 / width, 2.0 / height)
        targets = ctx.targets((height, width), colors, depth_texture="depth" in names)
        targets.fbo.use()
        targets.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if len(tri):
            ctx.storage_buffer("positions", pos).bind_to_storage_buffer(0)
            # Triangles go in batches whose index, setup and id arrays each fit one storage
            # block; ids stay exact (tri_base, or the global ids of REMAP).
            batch = ctx.max_storage_block_size // (3 * tri.itemsize)
            if records is not None:
                batch = min(batch, ctx.max_storage_block_size // records[0].nbytes)
            if cull_backfaces:
                mgl.enable(mgl.CULL_FACE)
            try:
                for number, base in enumerate(range(0, len(tri), batch)):
                    # One buffer per batch: llvmpipe shades fragments when the binned
                    # draw is flushed, after a later batch would have overwritten a
                    # shared buffer that the fragment shader reads (measured).
                    suffix = f"/{number}" if number else ""
                    part = tri[base:base + batch]
                    ctx.storage_buffer("indices" + suffix, part).bind_to_storage_buffer(1)
                    if records is not None:
                        ctx.storage_buffer("setup" + suffix, records[base:base + batch]) \
                            .bind_to_storage_buffer(2)
                    if remap_in_shader:
                        ctx.storage_buffer("ids" + suffix, kept[base:base + batch]) \
                            .bind_to_storage_buffer(3)
                    if "tri_base" in program:
                        program["tri_base"].value = base
                    vao.render(mgl.TRIANGLES, vertices=3 * len(part))
            finally:
                if cull_backfaces:
                    mgl.disable(mgl.CULL_FACE)
        for name, (components, dtype) in colors.items():
            shape = (height, width, components) if components > 1 else (height, width)
            out = np.empty(shape, np.float32 if dtype == "f4" else np.int32)
            targets.fbo.read_into(
                out, components=components, attachment=targets.color[name], dtype=dtype
            )
            values[name] = out
        if "depth" in names:
            depth = np.empty((height, width), np.float32)
            targets.fbo.read_into(depth, components=1, attachment=-1, dtype="f4")
            values["depth"] = depth
        error = mgl.error
    if error != "GL_NO_ERROR":
        raise GLError(error, "rasterizing")
    if "tri_id" in values:
        ids = values["tri_id"]
        ids -= 1  # stored as index + 1 so that the clear value 0 means empty
        if kept is not None and not remap_in_shader:
            ids[...] = np.concatenate([[-1], kept]).astype(np.int32)[ids + 1]
    if is_affine and "persp" in names:
        screen = values["screen"]
        values["persp"] = screen if "screen" not in names else screen.copy()
        if "screen" not in names:
            del values["screen"]
    return Raster(resolution=(height, width), mask=_mask_from(values), info=info, **values)
