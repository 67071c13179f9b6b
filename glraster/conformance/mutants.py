"""Fault injection: deliberately wrong variants of the rasterization shaders.

Each :class:`Mutant` is a copy of ``shaders/raster.vert`` / ``raster.frag`` with one fault
(files in ``shaders/mutants/``), possibly with a host-side change that a shader cannot
express (half-float render targets, the depth test switched off, a uniform). ``glraster
check --mutants`` renders the catalog with every mutant and expects each one to be caught
(some scene fails its comparison with the reference); the real shaders, run through the
same path, must pass everywhere.

Mutants that need no host change render through :func:`glraster.gpu.rasterize.rasterize` with
``shader_files``; the others go through :func:`render`, which mirrors that function with
the host changes applied to its own framebuffer and restores the context state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from glraster.gpu import rasterize as _raster
from glraster import validate
from glraster.errors import GLError
from glraster.types import OUTPUTS
from glraster.gpu.shaders import shader_dir

REAL_SHADERS = ("raster/raster.vert", "raster/raster.frag")


@dataclass(frozen=True)
class Mutant:
    """One deliberate fault.

    name        : identifier (used by ``--mutants NAME``)
    fault       : what is wrong, in one sentence
    vert, frag  : shader file names relative to ``shaders/`` (``raster.*`` when unchanged)
    target_dtype: color target dtype for the barycentric outputs ("f4" real, "f2" = half)
    depth_test  : False switches GL_DEPTH_TEST off (which also stops depth writes)
    rotate_180  : the vertex shader renders the image rotated by 180 degrees; the host
                  rotates the read-back arrays back
    viewport_uniform : set ``uniform vec2 u_viewport = (width, height)``
    """

    name: str
    fault: str
    vert: str = REAL_SHADERS[0]
    frag: str = REAL_SHADERS[1]
    target_dtype: str = "f4"
    depth_test: bool = True
    rotate_180: bool = False
    viewport_uniform: bool = False
    expected: tuple = field(default_factory=tuple)  # scenes that should catch it (documentation)

    @property
    def needs_host_changes(self) -> bool:
        return (self.target_dtype != "f4" or not self.depth_test or self.rotate_180
                or self.viewport_uniform)

    def shader_files(self) -> tuple:
        d = shader_dir()
        return (str(d / self.vert), str(d / self.frag))


MUTANTS: tuple[Mutant, ...] = (
    Mutant("swap_interpolation", "smooth and noperspective qualifiers swapped",
           vert="mutants/swap_interpolation.vert", frag="mutants/swap_interpolation.frag"),
    Mutant("flat_persp", "perspective barycentrics declared flat (provoking vertex value)",
           vert="mutants/flat_persp.vert", frag="mutants/flat_persp.frag"),
    Mutant("pixel_corner_sampling", "varyings sampled at the pixel corner instead of the center",
           frag="mutants/pixel_corner_sampling.frag"),
    Mutant("no_half_pixel_center", "geometry shifted by half a pixel (corners taken as centers)",
           vert="mutants/no_half_pixel_center.vert", viewport_uniform=True),
    Mutant("z_for_w", "perspective correction divides by clip z instead of clip w",
           vert="mutants/z_for_w.vert", frag="mutants/z_for_w.frag"),
    Mutant("vertex_order_rotated", "barycentrics assigned to the vertices in rotated order",
           vert="mutants/vertex_order_rotated.vert"),
    Mutant("tri_id_off_by_one", "triangle id written one too high",
           frag="mutants/tri_id_off_by_one.frag"),
    Mutant("edge_discard", "fragments centered exactly on an edge are discarded "
                           "(missing pixels on shared edges)",
           vert="mutants/edge_discard.vert", frag="mutants/edge_discard.frag"),
    Mutant("fill_rule_top_right", "top-right tie rule instead of the driver's bottom-left "
                                  "(pixels on shared edges go to the other triangle)",
           vert="mutants/fill_rule_top_right.vert", rotate_180=True),
    Mutant("half_float_targets", "barycentric targets are 16-bit floats instead of 32-bit",
           target_dtype="f2"),
    Mutant("depth_test_dropped", "depth test disabled: the last triangle drawn wins",
           depth_test=False),
)


def get(name: str) -> Mutant:
    """The mutant called ``name``."""
    for m in MUTANTS:
        if m.name == name:
            return m
    raise ValueError(f"unknown mutant {name!r}; known: {', '.join(m.name for m in MUTANTS)}")


def select(pattern: str | None) -> list[Mutant]:
    """Mutants whose names match a comma-separated list of fnmatch patterns (all if None)."""
    import fnmatch

    if not pattern or pattern == "all":
        return list(MUTANTS)
    pats = [p.strip() for p in pattern.split(",") if p.strip()]
    chosen = [m for m in MUTANTS if any(fnmatch.fnmatchcase(m.name, p) for p in pats)]
    if not chosen:
        raise ValueError(f"no mutant matches {pattern!r}; known: {', '.join(m.name for m in MUTANTS)}")
    return chosen


def render(mutant: Mutant | None, pos, tri, resolution, *, ctx, outputs=OUTPUTS):
    """Rasterize with a mutant's shaders and host changes; ``mutant=None`` renders the real
    shaders through this same path (the control for false alarms).

    Same arguments and result as :func:`glraster.rasterize` (a :class:`glraster.Raster`,
    arrays indexed [y, x] with row 0 at the bottom, float32 barycentrics/depth, int32 ids).
    """
    if mutant is not None and not mutant.needs_host_changes:
        return _raster.rasterize(pos, tri, resolution, ctx=ctx, outputs=outputs,
                                 shader_files=mutant.shader_files())
    m = mutant or Mutant("control", "none")
    names = validate.outputs(outputs)
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution, ctx.max_texture_size)
    colors = {}
    for n in names:
        if n in _raster.COLOR_FORMATS:
            comps, dtype = _raster.COLOR_FORMATS[n]
            colors[n] = (comps, m.target_dtype if dtype == "f4" else dtype)
    defines = {}
    for location, n in enumerate(colors):
        defines[f"OUT_{n.upper()}"] = 1
        defines[f"{n.upper()}_LOCATION"] = location
    vert, frag = m.shader_files()
    values = {}
    with ctx:
        mgl = ctx.mgl
        program, vao = ctx.program(vert, frag, defines)
        if m.viewport_uniform:
            program["u_viewport"].value = (float(width), float(height))
        targets = ctx.targets((height, width), colors, depth_texture=True)
        fbo = targets.fbo
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if not m.depth_test:
            mgl.disable(mgl.DEPTH_TEST)
        try:
            if len(tri):
                # Same batching as glraster.rasterize: each draw's indices fit one storage
                # block, ``tri_base`` keeps the ids global.
                batch = ctx.max_storage_block_size // tri.itemsize // 3
                ctx.storage_buffer("positions", pos).bind_to_storage_buffer(0)
                for base in range(0, len(tri), batch):
                    part = tri[base:base + batch]
                    ctx.storage_buffer("indices", part).bind_to_storage_buffer(1)
                    if "tri_base" in program:
                        program["tri_base"].value = base
                    vao.render(mgl.TRIANGLES, vertices=3 * len(part))
        finally:
            mgl.enable(mgl.DEPTH_TEST)
        for n, (comps, dtype) in colors.items():
            np_dtype = {"f4": np.float32, "f2": np.float16, "i4": np.int32}[dtype]
            shape = (height, width, comps) if comps > 1 else (height, width)
            out = np.empty(shape, np_dtype)
            fbo.read_into(out, components=comps, attachment=targets.color[n], dtype=dtype)
            values[n] = out.astype(np.float32) if dtype == "f2" else out
        if "depth" in names:
            depth = np.empty((height, width), np.float32)
            fbo.read_into(depth, components=1, attachment=-1, dtype="f4")
            values["depth"] = depth
        error = mgl.error
    if error != "GL_NO_ERROR":
        raise GLError(error, f"rendering mutant {m.name}")
    if "tri_id" in values:
        values["tri_id"] -= 1
    if m.rotate_180:
        values = {k: np.ascontiguousarray(v[::-1, ::-1]) for k, v in values.items()}
    return _raster.Raster(resolution=(height, width), mask=_raster._mask_from(values),
                          info={"backend": ctx.backend, "renderer": ctx.renderer,
                                "method": f"mutant:{m.name}"}, **values)
