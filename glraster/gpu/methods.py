"""The method registry: how a covered pixel's barycentrics are computed on the GPU.

Coverage, depth and triangle ids always come from the driver's rasterizer; a method decides
only how ``persp`` and ``screen`` are obtained. One :class:`Method` record per method holds
everything that differs between them (shader files, defines, host-side setup, culling
default, read-back format, error-model traits and waivers), so adding a method touches
this file and its shader only.

Each record says the OpenGL version its shaders need (``min_gl``: 4.5 for the GLSL 4.50
shaders with storage buffers). A method may have a variant for older contexts: ``hw``
draws from storage buffers on GL 4.5 and from a de-indexed vertex buffer
(``shaders/raster33/``) below, down to GL 3.3; :func:`for_context` picks the
record for a context, or raises a :class:`GLVersionError` naming the method, the version
the context offers and the one needed.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable


from glraster.errors import ArgumentError, GLVersionError
from glraster.types import INTERPOLATIONS
from glraster.gpu import homogeneous as _homogeneous
from glraster.verify.tolerance import ErrorModel


@dataclass(frozen=True)
class Method:
    """One way to compute barycentrics.

    name, note      : identifier and one-line description
    vert, frag      : shader files relative to ``shaders/``
    defines         : ``#define``s the method always sets
    setup           : host-side per-triangle setup ``setup(clip (T, 3, 4) float32,
                      (H, W)) -> (T, STRIDE) array`` bound as storage buffer 2, or None
    cull_by_default : ``cull="auto"`` culls before upload (worth it when ``setup`` does
                      per-triangle host work)
    remaps_ids      : the shader writes caller triangle ids from a storage buffer of kept
                      indices (binding 3) when triangles were culled; else the host remaps
    varies_screen   : the vertex shader passes the noperspective unit vectors (divw)
    value_dtype     : dtype of the returned persp / screen ("f4" float32, "f8" float64,
                      read back exactly as two uint32 halves per value)
    uniforms        : ``uniforms(height, width) -> {name: value}`` set before drawing
    compensated, persp_from_screen : error-model traits (see ErrorModel)
    clip_defect_outputs : outputs computed from the driver's noperspective varyings, which
                      a driver with Mesa's clipper defect gets wrong (waived there)
    min_gl          : least OpenGL version (major * 10 + minor) the shaders need
    needs           : what needs ``min_gl``, for the error message
    vertex_input    : positions come as the vertex attribute ``a_position`` of a de-indexed
                      vertex buffer (:class:`pipeline.Draw`), not from storage buffers
    fallback        : the variant used on contexts below ``min_gl`` (None: the method
                      is unavailable there)
    interpolations  : the ``interpolation`` modes the method offers when multisampling
                      (the ones that read the driver's varyings take the GLSL ``centroid``
                      and ``sample`` qualifiers; those computing from gl_FragCoord evaluate
                      at the pixel center only)
    """

    name: str
    note: str
    vert: str
    frag: str
    defines: dict = field(default_factory=dict)
    setup: Callable | None = None
    cull_by_default: bool = False
    remaps_ids: bool = True
    varies_screen: bool = False
    value_dtype: str = "f4"
    uniforms: Callable | None = None
    compensated: bool = False
    persp_from_screen: bool = False
    clip_defect_outputs: tuple[str, ...] = ()
    min_gl: int = 45
    needs: str = "shader storage buffers, GLSL 4.50"
    vertex_input: bool = False
    fallback: Method | None = None
    interpolations: tuple[str, ...] = ("center",)

    def error_model(self, ctx=None, clip_defect: bool | None = None,
                    sample_persp_defect: bool | None = None) -> ErrorModel:
        """The per-pixel error model for this method on a context (None: llvmpipe).

        The driver model (:meth:`ErrorModel.for_context`) bounds every method that
        interpolates or solves in float32 from the driver's float32 window-space data;
        the compensated methods shrink its position terms; outputs built on the driver's
        noperspective varyings are waived where the driver has Mesa's clipper defect:
        ``clip_defect`` says whether it has (the conformance probe ``noperspective_clip``
        measures it); None assumes it on llvmpipe only. ``sample_persp_defect``: whether
        the driver divides by the pixel center's 1 / w at samples and centroids (the probe
        ``sample_perspective`` measures it; None: assumed on llvmpipe only), for the
        methods that read the driver's smooth varyings ("hw").
        """
        base = ErrorModel.for_context(ctx)
        has_defect = bool(base.waived_outputs) if clip_defect is None else clip_defect
        waived = self.clip_defect_outputs if has_defect else ()
        llvmpipe = ctx is None or ctx.is_llvmpipe
        persp_defect = llvmpipe if sample_persp_defect is None else sample_persp_defect
        return replace(base, waived_outputs=waived, compensated=self.compensated,
                       persp_from_screen=self.persp_from_screen,
                       center_one_over_w=bool(persp_defect) and not self.persp_from_screen)


def _homogeneous_setup(fp64: bool):
    def setup(clip, resolution):
        return _homogeneous.setup(clip, resolution, fp64=fp64)
    return setup


def _solve4_uniforms(height, width):
    return {"u_ndc_scale": (2.0 / width, 2.0 / height)}


# hw on GL 3.3: the same interpolation, positions from a de-indexed vertex buffer and the
# triangle index as a flat varying (shaders/raster33/, whose text is raster/'s where the
# fault-injection mutants patch it).
HW_GL33 = Method("hw", "the driver's smooth / noperspective interpolation (GL 3.3 path: "
                       "vertex attributes)",
                 "raster33/raster.vert", "raster33/raster.frag", remaps_ids=False,
                 clip_defect_outputs=("screen",), min_gl=33, needs="", vertex_input=True,
                 interpolations=INTERPOLATIONS)

METHODS: dict[str, Method] = {m.name: m for m in (
    Method("hw", "the driver's smooth / noperspective interpolation",
           "raster/raster.vert", "raster/raster.frag",
           remaps_ids=False, clip_defect_outputs=("screen",), fallback=HW_GL33,
           interpolations=INTERPOLATIONS),
    Method("divw", "noperspective barycentrics divided by per-vertex w in the shader "
                   "(GL 4.5 eq. 14.9)",
           "raster/pull.vert", "methods/divw.frag", varies_screen=True,
           persp_from_screen=True, clip_defect_outputs=("screen", "persp"),
           interpolations=INTERPOLATIONS),
    Method("homogeneous", "2D homogeneous edge functions per pixel, relative to a vertex, "
                          "compensated float32",
           "raster/pull.vert", "methods/homogeneous.frag", setup=_homogeneous_setup(False),
           cull_by_default=True, compensated=True),
    Method("homogeneous64", "the same in float64 (GL 4.0 fp64), returned as float64",
           "raster/pull.vert", "methods/homogeneous.frag", defines={"FP64": 1},
           setup=_homogeneous_setup(True), cull_by_default=True, value_dtype="f8",
           compensated=True, needs="shader storage buffers and float64, GLSL 4.50"),
    Method("solve4", "a 4x4 linear system per pixel for (b, w), float32 Gaussian elimination",
           "raster/pull.vert", "methods/solve4.frag", uniforms=_solve4_uniforms),
)}


def get(name) -> Method:
    """The registered method called ``name`` (ValueError naming the choices otherwise)."""
    method = METHODS.get(name) if isinstance(name, str) else None
    if method is None:
        raise ArgumentError("method", f"method must be one of {sorted(METHODS)}, got {name!r}")
    return method


def for_context(method, ctx) -> Method:
    """The record of ``method`` (a name or a :class:`Method`) to draw with on ``ctx``: the
    method itself when the context offers its ``min_gl``, else the first fallback that
    fits (``hw`` on GL 3.3). Raises :class:`GLVersionError` (a ValueError) naming the
    method, the version the context offers and the one needed. ``ctx=None``: the method."""
    m = get(method) if isinstance(method, str) else method
    if ctx is None:
        return m
    candidate = m
    while candidate is not None:
        if ctx.gl_version_number >= candidate.min_gl:
            return candidate
        candidate = candidate.fallback
    ctx.require_gl(m.min_gl, f"method {m.name!r}", m.needs)
    return m  # pragma: no cover - require_gl raised


def available(ctx) -> dict[str, Method | None]:
    """Method name -> the record drawn on ``ctx``, or None where the context's OpenGL is
    too old for it."""
    out = {}
    for name, m in METHODS.items():
        try:
            out[name] = for_context(m, ctx)
        except GLVersionError:
            out[name] = None
    return out


def error_model(method: str, ctx=None, clip_defect: bool | None = None,
                sample_persp_defect: bool | None = None) -> ErrorModel:
    """:meth:`Method.error_model` of the method called ``method``."""
    return get(method).error_model(ctx, clip_defect, sample_persp_defect)
