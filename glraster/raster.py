"""Rasterizing on the GPU: the :class:`Raster` result and :func:`rasterize`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import validate
from .context import Context, default_context
from .shaders import shader_path

# method name -> (vertex shader file, fragment shader file)
METHODS = {"hw": ("raster.vert", "raster.frag")}

# name -> (components, dtype) of the color target holding it
COLOR_FORMATS = {"persp": (3, "f4"), "screen": (3, "f4"), "tri_id": (1, "i4")}


@dataclass
class Raster:
    """Per-pixel rasterization result. Arrays are indexed ``[y, x]``, row 0 at the bottom.

    persp  : (H, W, 3) float32 or None   perspective-correct barycentrics (b0, b1, b2)
    screen : (H, W, 3) float32 or None   window-space (noperspective) barycentrics
    depth  : (H, W)    float32 or None   window z in [0, 1]; 1.0 where empty
    tri_id : (H, W)    int32 or None     index into ``tri``; -1 where empty
    mask   : (H, W)    bool              pixel covered by some triangle

    Empty pixels hold barycentrics 0, depth 1.0, triangle id -1. An output that was not
    requested is None. Reference rasters hold float64 values.
    """

    resolution: tuple
    mask: np.ndarray
    persp: np.ndarray | None = None
    screen: np.ndarray | None = None
    depth: np.ndarray | None = None
    tri_id: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(n for n in validate.OUTPUTS if getattr(self, n) is not None)


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
    outputs=validate.OUTPUTS,
    method: str = "hw",
    shader_files: tuple | None = None,
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
    method : str
        How barycentrics are computed; "hw" uses the driver's interpolation of ``smooth``
        and ``noperspective`` varyings.
    shader_files : (vert, frag), optional
        Alternative shader files with the same interface (used by fault injection).

    Returns
    -------
    Raster
    """
    names = validate.outputs(outputs)
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    ctx = ctx if ctx is not None else default_context()
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution, ctx.max_texture_size)
    if pos.nbytes > ctx.max_storage_block_size:
        raise ValueError(
            f"pos takes {pos.nbytes} bytes, above the driver's shader storage block "
            f"limit of {ctx.max_storage_block_size} bytes ({ctx.max_storage_block_size // 16} vertices)"
        )
    # Triangles go in batches that fit one storage block; ids stay exact (tri_base).
    batch = ctx.max_storage_block_size // tri.itemsize // 3

    vert, frag = shader_files if shader_files is not None else METHODS[method]
    defines = {}
    colors = {n: COLOR_FORMATS[n] for n in names if n in COLOR_FORMATS}
    for location, name in enumerate(colors):
        defines[f"OUT_{name.upper()}"] = 1
        defines[f"{name.upper()}_LOCATION"] = location

    values = {}
    with ctx:
        program, vao = ctx.program(shader_path(vert), shader_path(frag), defines)
        targets = ctx.targets((height, width), colors, depth_texture="depth" in names)
        targets.fbo.use()
        targets.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if len(tri):
            ctx.storage_buffer("positions", pos).bind_to_storage_buffer(0)
            for base in range(0, len(tri), batch):
                part = tri[base:base + batch]
                ctx.storage_buffer("indices", part).bind_to_storage_buffer(1)
                if "tri_base" in program:
                    program["tri_base"].value = base
                vao.render(ctx.mgl.TRIANGLES, vertices=3 * len(part))
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
        error = ctx.mgl.error
    if error != "GL_NO_ERROR":
        raise RuntimeError(f"OpenGL reported {error} while rasterizing")
    if "tri_id" in values:
        values["tri_id"] -= 1  # stored as index + 1 so that the clear value 0 means empty
    return Raster(
        resolution=(height, width),
        mask=_mask_from(values),
        info={"backend": ctx.backend, "renderer": ctx.renderer, "method": method},
        **values,
    )
