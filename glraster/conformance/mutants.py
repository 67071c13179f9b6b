"""Fault injection: deliberately wrong variants of the rasterization shaders.

Each :class:`Mutant` is the real ``shaders/raster/raster.vert`` / ``raster.frag`` with one
fault, written as a few :class:`Patch` replacements (old text -> new text) that are applied
to the current real shader text whenever the mutant is rendered, so a mutant cannot drift
from the shaders it mutates. On a GL 3.3 context the real shaders of method "hw" are
``shaders/raster33/raster.vert`` / ``raster.frag``, whose text is the same where the patches
apply: the same patches make the same faults there (a patch names the file by its role,
``raster/raster.vert`` or ``raster/raster.frag``). Each replacement must match exactly
once (else a ValueError names the mutant, the file and the text) and keep the number of
lines, so that the mutated source has the real file's line numbers. A mutant may also carry a host-side change that a
shader cannot express (half-float render targets, the depth test switched off, a uniform).
``glraster check --mutants`` renders the catalog with every mutant and expects each one to be
caught (some scene fails its comparison with the reference); the real shaders, run through
the same path, must pass everywhere.

The mutated sources are written to a per-process temporary folder
(``<tmp>/glraster-mutants-*/<mutant>/raster.vert``, ``.../<mutant>/raster33/raster.vert``
for the GL 3.3 shaders, ending with a comment that names the mutant) because the draw
paths compile shader files; a compile error names that file, whose line N is line N of
the real shader. Mutants that need no host change render through
:func:`glraster.gpu.rasterize.rasterize` with ``shader_files``; the others go through
:func:`render`, which draws through the same pipeline (:mod:`glraster.gpu.pipeline`)
with the host changes applied (target dtype, depth test, uniforms, read-back rotation).
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError
from glraster.gpu import methods as _methods
from glraster.gpu import pipeline as _pipeline
from glraster.gpu import rasterize as _raster
from glraster.types import OUTPUTS, Raster
from glraster.gpu.shaders import shader_dir

REAL_SHADERS = ("raster/raster.vert", "raster/raster.frag")
VERT, FRAG = REAL_SHADERS


def real_shaders(ctx=None) -> tuple[str, str]:
    """The real (vert, frag) of method "hw" on ``ctx`` (relative to ``shaders/``), in the
    order of REAL_SHADERS: ``raster/`` on GL 4.5 (or ``ctx=None``), ``raster33/`` below."""
    hw = _methods.for_context("hw", ctx)
    return hw.vert, hw.frag


@dataclass(frozen=True)
class Patch:
    """Replace ``old`` by ``new`` in the real shader ``file`` (relative to ``shaders/``).

    ``old`` must occur exactly once in the file's text (as left by the mutant's earlier
    patches of the same file) and ``new`` must have as many line breaks as ``old``.
    """

    file: str
    old: str
    new: str


@dataclass(frozen=True)
class Mutant:
    """One deliberate fault.

    name        : identifier (used by ``--mutants NAME``)
    fault       : what is wrong, in one sentence
    patches     : :class:`Patch` replacements on ``raster/raster.vert`` / ``raster.frag``,
                  applied in order (none: the real shaders)
    target_dtype: color target dtype for the barycentric outputs ("f4" real, "f2" = half)
    depth_test  : False switches GL_DEPTH_TEST off (which also stops depth writes)
    rotate_180  : the vertex shader renders the image rotated by 180 degrees; the host
                  rotates the read-back arrays back
    viewport_uniform : set ``uniform vec2 u_viewport = (width, height)``
    coverage_per_pixel : the fragments are rasterized at the pixel center and written to
                  every sample of the pixel (the per-sample coverage mask ignored): the
                  host draws single-sample and copies each pixel to its samples
    depth_clear, depth_func : the depth buffer's clear value and test ("<", 1.0: real)
    multisample_only : the fault shows only when multisampling (not run where the driver
                  offers no multisampling)
    """

    name: str
    fault: str
    patches: tuple[Patch, ...] = ()
    target_dtype: str = "f4"
    depth_test: bool = True
    rotate_180: bool = False
    viewport_uniform: bool = False
    coverage_per_pixel: bool = False
    multisample_only: bool = False
    depth_clear: float = 1.0
    depth_func: str = "<"
    expected: tuple = field(default_factory=tuple)  # scenes that should catch it (documentation)

    def __post_init__(self):
        for p in self.patches:
            where = f"mutant {self.name!r}, {p.file}, replacing {p.old!r}"
            if p.file not in REAL_SHADERS:
                raise ValueError(f"{where}: can only patch {' or '.join(REAL_SHADERS)}")
            if not p.old or p.old == p.new:
                raise ValueError(f"{where}: the old text must be non-empty and differ from the new")
            if p.old.count("\n") != p.new.count("\n"):
                raise ValueError(f"{where}: the new text must have as many lines as the old "
                                 f"(so that compile errors keep the real file's line numbers)")

    @property
    def needs_host_changes(self) -> bool:
        return (self.target_dtype != "f4" or not self.depth_test or self.rotate_180
                or self.viewport_uniform or self.coverage_per_pixel or self.depth_clear != 1.0
                or self.depth_func != "<")

    @property
    def patched_files(self) -> tuple[str, ...]:
        """The real shader files this mutant changes, in REAL_SHADERS order."""
        return tuple(f for f in REAL_SHADERS if any(p.file == f for p in self.patches))

    def source(self, file: str, ctx=None) -> str:
        """The current text of the real shader ``file`` (a REAL_SHADERS role; on a GL 3.3
        ``ctx`` the file of :func:`real_shaders` in that role) with this mutant's patches
        applied.

        Raises ValueError naming the mutant, the file and the text when a replacement does
        not match exactly once.
        """
        real = dict(zip(REAL_SHADERS, real_shaders(ctx)))[file]
        text = (shader_dir() / real).read_text()
        return apply_patches(self.name, real, text,
                             [p for p in self.patches if p.file == file])

    def shader_files(self, ctx=None) -> tuple:
        """(vert, frag) paths to compile on ``ctx`` (None: the GL 4.5 shaders): the real
        file for an unpatched stage, else the mutated source written to this process's
        temporary mutant folder."""
        d = shader_dir()
        return tuple(str(_write_generated(self, f, real, ctx) if f in self.patched_files
                         else d / real)
                     for f, real in zip(REAL_SHADERS, real_shaders(ctx)))


def apply_patches(name: str, file: str, text: str, patches) -> str:
    """``text`` (of shader ``file``) with ``patches`` applied in order, each of whose old
    text must occur exactly once; the error names mutant ``name``, the file and the text."""
    for p in patches:
        count = text.count(p.old)
        if count != 1:
            found = "does not occur" if count == 0 else f"occurs {count} times"
            raise ValueError(f"mutant {name!r}: the text to replace {p.old!r} {found} in "
                             f"{file} (it must occur exactly once); update the patch to the "
                             f"current shader")
        text = text.replace(p.old, p.new)
    return text


_generated: dict[Path, str] = {}  # path -> text written there by this process
_generated_root: list[Path] = []


def _write_generated(mutant: Mutant, file: str, real: str | None = None, ctx=None) -> Path:
    """Write ``mutant``'s version of ``file`` (role), whose real shader on ``ctx`` is
    ``real`` (unchanged lines, then a trailing comment that names the mutant), and return
    its path; rewritten only when the text changes."""
    real = real or file
    if not _generated_root:
        root = Path(tempfile.mkdtemp(prefix="glraster-mutants-"))
        atexit.register(shutil.rmtree, root, ignore_errors=True)
        _generated_root.append(root)
    text = mutant.source(file, ctx)
    text += ("" if text.endswith("\n") else "\n") + (
        f"// MUTANT {mutant.name}: {mutant.fault}.\n"
        f"// Generated by glraster.conformance.mutants from shaders/{real}; every line above "
        f"has the line number it has there.\n")
    folder = _generated_root[0] / mutant.name
    if Path(real).parent != Path(file).parent:
        folder = folder / Path(real).parent.name  # raster33/: the GL 3.3 shaders
    path = folder / Path(real).name
    if _generated.get(path) != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        _generated[path] = text
    return path


# Declarations the mutants add share a line with ``void main() {`` or an existing statement,
# so that no line is added.
_MAIN = "void main() {"
_POSITION = "gl_Position = CORNER_POSITION;"
_PERSP_OUT, _PERSP_IN = "smooth out vec3 v_persp;", "smooth in vec3 v_persp;"
_SCREEN_OUT, _SCREEN_IN = "noperspective out vec3 v_screen;", "noperspective in vec3 v_screen;"

MUTANTS: tuple[Mutant, ...] = (
    Mutant("swap_interpolation", "smooth and noperspective qualifiers swapped", patches=(
        Patch(VERT, _PERSP_OUT, "noperspective out vec3 v_persp;"),
        Patch(VERT, _SCREEN_OUT, "smooth out vec3 v_screen;"),
        Patch(FRAG, _PERSP_IN, "noperspective in vec3 v_persp;"),
        Patch(FRAG, _SCREEN_IN, "smooth in vec3 v_screen;"),
    )),
    Mutant("flat_persp", "perspective barycentrics declared flat (provoking vertex value)",
           patches=(
        Patch(VERT, _PERSP_OUT, "flat out vec3 v_persp;"),
        Patch(FRAG, _PERSP_IN, "flat in vec3 v_persp;"),
    )),
    Mutant("pixel_corner_sampling", "varyings sampled at the pixel corner instead of the center",
           patches=(
        Patch(FRAG, "out_persp = v_persp;", "out_persp = interpolateAtOffset(v_persp, vec2(-0.5));"),
        Patch(FRAG, "out_screen = v_screen;",
              "out_screen = interpolateAtOffset(v_screen, vec2(-0.5));"),
    )),
    Mutant("no_half_pixel_center", "geometry shifted by half a pixel (corners taken as centers)",
           viewport_uniform=True, patches=(
        Patch(VERT, _MAIN, "uniform vec2 u_viewport;  " + _MAIN),  # (width, height) in pixels
        Patch(VERT, _POSITION,
              _POSITION + " gl_Position.xy += gl_Position.w / u_viewport;  // +0.5 px"),
    )),
    Mutant("z_for_w", "perspective correction divides by clip z instead of clip w", patches=(
        Patch(VERT, _PERSP_OUT,
              "noperspective out vec3 v_persp_num; noperspective out float v_persp_den;"),
        Patch(VERT, "v_persp = unit;",
              "v_persp_num = unit / gl_Position.z; v_persp_den = 1.0 / gl_Position.z;"),
        Patch(FRAG, _PERSP_IN,
              "noperspective in vec3 v_persp_num; noperspective in float v_persp_den;"),
        Patch(FRAG, "out_persp = v_persp;", "out_persp = v_persp_num / v_persp_den;"),
    )),
    Mutant("vertex_order_rotated", "barycentrics assigned to the vertices in rotated order",
           patches=(
        Patch(VERT, "vec3(corner == 0, corner == 1, corner == 2)",
              "vec3(corner == 1, corner == 2, corner == 0)"),
    )),
    Mutant("tri_id_off_by_one", "triangle id written one too high", patches=(
        Patch(FRAG, "tri_base + PRIMITIVE_ID + 1;", "tri_base + PRIMITIVE_ID + 2;"),
    )),
    Mutant("edge_discard", "fragments centered exactly on an edge are discarded "
                           "(missing pixels on shared edges)", patches=(
        # v_edge: window-space barycentrics, always; dist: distance of the center to the
        # nearest edge in pixels, b / |grad b|
        Patch(VERT, _MAIN, "noperspective out vec3 v_edge;  " + _MAIN),
        Patch(VERT, _POSITION, _POSITION + " v_edge = unit;"),
        Patch(FRAG, _MAIN, "noperspective in vec3 v_edge;  " + _MAIN
              + " vec3 dist = v_edge / max(fwidth(v_edge), vec3(1e-30));"
                " if (min(dist.x, min(dist.y, dist.z)) < 1e-3) discard;"),
    )),
    Mutant("fill_rule_top_right", "top-right tie rule instead of the driver's bottom-left "
                                  "(pixels on shared edges go to the other triangle)",
           rotate_180=True, patches=(
        # rotate the image 180 degrees; the runner rotates it back
        Patch(VERT, _POSITION, _POSITION + " gl_Position.xy = -gl_Position.xy;"),
    )),
    Mutant("half_float_targets", "barycentric targets are 16-bit floats instead of 32-bit",
           target_dtype="f2"),
    Mutant("depth_test_dropped", "depth test disabled: the last triangle drawn wins",
           depth_test=False),
    # multisampling (caught by the multisample scenes)
    Mutant("wrong_sample_position", "per-sample values all interpolated at sample 1's "
                                    "position instead of their own", multisample_only=True,
           patches=(
        Patch(FRAG, "out_persp = v_persp;", "out_persp = interpolateAtSample(v_persp, 1);"),
        Patch(FRAG, "out_screen = v_screen;", "out_screen = interpolateAtSample(v_screen, 1);"),
    )),
    Mutant("centroid_as_center", "centroid (and per-sample) values taken at the pixel "
                                 "center, also where the center is outside the triangle",
           multisample_only=True, patches=(
        Patch(FRAG, "out_persp = v_persp;", "out_persp = interpolateAtOffset(v_persp, vec2(0.0));"),
        Patch(FRAG, "out_screen = v_screen;",
              "out_screen = interpolateAtOffset(v_screen, vec2(0.0));"),
    )),
    Mutant("sample_mask_ignored", "the per-sample coverage mask ignored: a fragment covers "
                                  "every sample of a pixel whose center it covers",
           coverage_per_pixel=True, multisample_only=True),
    Mutant("reversed_occlusion", "depth buffer cleared to 0 and the test reversed "
                                 "(GREATER): the farthest triangle wins",
           depth_clear=0.0, depth_func=">"),
)


def get(name: str) -> Mutant:
    """The mutant called ``name``."""
    for m in MUTANTS:
        if m.name == name:
            return m
    raise ArgumentError(
        "name", f"unknown mutant {name!r}; known: {', '.join(m.name for m in MUTANTS)}")


def select(pattern: str | None) -> list[Mutant]:
    """Mutants whose names match a comma-separated list of fnmatch patterns (all if None)."""
    import fnmatch

    if not pattern or pattern == "all":
        return list(MUTANTS)
    pats = [p.strip() for p in pattern.split(",") if p.strip()]
    chosen = [m for m in MUTANTS if any(fnmatch.fnmatchcase(m.name, p) for p in pats)]
    if not chosen:
        raise ArgumentError(
            "pattern", f"no mutant matches {pattern!r}; "
                       f"known: {', '.join(m.name for m in MUTANTS)}")
    return chosen


def render(mutant: Mutant | None, pos, tri, resolution, *, ctx, outputs=OUTPUTS,
           samples: int = 1, interpolation: str = "center"):
    """Rasterize with a mutant's shaders and host changes; ``mutant=None`` renders the real
    shaders through this same path (the control for false alarms).

    Same arguments and result as :func:`glraster.rasterize` (a :class:`glraster.Raster`,
    arrays indexed [y, x] with row 0 at the bottom, float32 barycentrics/depth, int32 ids;
    per-sample arrays when ``samples`` > 1).
    """
    samples = validate.samples(samples)
    interpolation = validate.interpolation(interpolation)
    if mutant is not None and not mutant.needs_host_changes:
        return _raster.rasterize(pos, tri, resolution, ctx=ctx, outputs=outputs,
                                 shader_files=mutant.shader_files(ctx), samples=samples,
                                 interpolation=interpolation)
    m = mutant or Mutant("control", "none")
    names = validate.outputs(outputs)
    pos = validate.positions(pos)
    tri = validate.triangles(tri, len(pos))
    height, width = validate.resolution(resolution, ctx.max_texture_size)
    hw = _methods.for_context("hw", ctx)
    colors = {n: (c, m.target_dtype if dtype == "f4" else dtype)
              for n, (c, dtype) in _raster.color_targets(names, hw).items()}
    vert, frag = m.shader_files(ctx)
    defines = _pipeline.output_defines(colors)
    drawn = samples
    if samples > 1:
        _raster._check_multisampling(ctx, hw, samples, interpolation)
        if m.coverage_per_pixel:
            drawn = 1
        elif interpolation != "center" and ("persp" in names or "screen" in names):
            defines["INTERPOLATION"] = interpolation
            if hw.vertex_input:
                defines["AUX_QUALIFIERS"] = 1
    with ctx:
        program, vao = ctx.program(vert, frag, defines)
    spec = _pipeline.Draw(
        program, vao, colors, read_depth="depth" in names, depth_test=m.depth_test,
        vertex_input=hw.vertex_input, samples=drawn,
        depth_clear=m.depth_clear, depth_func=m.depth_func,
        uniforms={"u_viewport": (float(width), float(height))} if m.viewport_uniform else {})
    values = _pipeline.draw(ctx, spec, pos, tri, (height, width),
                            during=f"rendering mutant {m.name}")
    positions = values.pop("sample_positions", None)
    if drawn != samples:                         # each pixel's fragment on all its samples
        with ctx:
            positions = ctx.targets((1, 1), colors, True, samples).sample_positions.copy()
        values = {n: np.repeat(v[:, :, None], samples, axis=2) for n, v in values.items()}
    values = {n: v.astype(np.float32) if v.dtype == np.float16 else v for n, v in values.items()}
    if "tri_id" in values:
        _pipeline.decode_ids(values["tri_id"])
    if m.rotate_180:
        values = {k: np.ascontiguousarray(v[::-1, ::-1]) for k, v in values.items()}
    info = {"backend": ctx.backend, "renderer": ctx.renderer, "method": f"mutant:{m.name}"}
    mask = _pipeline.coverage(values)
    if samples > 1:
        return _raster.multisampled(values, mask, positions, interpolation, (height, width),
                                    info)
    return Raster(resolution=(height, width), mask=mask, info=info, **values)
