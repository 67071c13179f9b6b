"""Filtered, mipmapped texture lookups on the GPU, forward and backward: the texture op's
GPU core (NumPy arrays in and out), with the float64 reference's signature
(:mod:`glraster.diff.texture_reference`; :data:`glraster.diff.ops.TEXTURE` checks the
arguments and picks the core).

nvdiffrast's ``texture`` semantics (layouts in :mod:`glraster.diff.texture_args`,
derivations in docs/differentiable.md, "Texture"), in compute shaders
(``shaders/diff/texture.comp``, ``shaders/diff/texture_mip.comp``):

* the mip pyramid is built on the GPU (a box filter over each texel's footprint: 2 x 2 for
  even extents, 3 taps per axis with weights (m - j, m, j + 1)/(2m + 1) for an odd 2m + 1),
  down to 1 x 1, or taken from the caller (``mip``);
* the shaders read their inputs (the levels, uv, uv_da, the bias, dL/d out, the level
  table) through buffer textures over the storage buffers they are uploaded to
  (:mod:`glraster.diff.buffer_views`): on llvmpipe several times faster than
  storage-buffer loads, the same bits;
* each pixel computes its level itself (level = 0.5 log2 of the largest
  eigenvalue of J^T J, J the texel-space Jacobian from ``uv_da``, plus ``mip_level_bias``,
  clamped to the pyramid) and filters with texel fetches at texel centres (no GL sampler:
  see :func:`sampler_probe` for why);
* the backward (on the levels its forward left on the GPU, :data:`BACKWARD_RUN` pixels per
  invocation, whose terms for a texel they share are summed first) sends gradients to
  every texel read (float atomics or a compare-and-swap loop, as
  :mod:`glraster.diff.compute`; deterministic, integer atomics on 64-bit fixed point,
  :func:`fixed_point_shift`, rounded to float32 on the GPU, :func:`fixed_point_values`),
  then pulls a built pyramid's level gradients back into
  the base through the transpose of its box filter (a gather, one pass per level); to uv
  (through the bilinear weights and, for cube maps, the face projection and the level), to
  uv_da (through the level) and to the bias.
"""

from __future__ import annotations

import ctypes
import weakref

import numpy as np

from glraster import validate
from glraster.diff import buffer_views
from glraster.diff.compute import LOCAL_SIZE, accumulation, fixed_point_clear
from glraster.diff.compute import chunks as _chunks
from glraster.diff.compute import read as _read
from glraster.diff.compute import run as _run
from glraster.diff.compute import set_uniform as _set
from glraster.diff.texture_args import (
    BOUNDARY_CODE,
    FILTER_CODE,
    TextureArgs,
    TextureSaved,
    check,
    wanted,
)
from glraster.gpu.context import Context, context_or_default
from glraster.gpu.shaders import shader_path

__all__ = ["backward", "build_mips", "forward", "sampler_probe"]

_SHADER = "diff/texture.comp"
_MIP_SHADER = "diff/texture_mip.comp"
_RESOLVE_SHADER = "diff/texture_resolve.comp"
_MAX_GROUPS = 65535   # GL_MAX_COMPUTE_WORK_GROUP_COUNT's least value (GL 4.6, table 23.75)
# the texture shader's accumulation defines: deterministic (per_pixel) is its fixed point
_ACCUM_DEFINES = {"atomic_float": "ACCUM_ATOMIC_FLOAT", "cas": "ACCUM_CAS",
                  "per_pixel": "ACCUM_FIXED_POINT"}


def _geometry(args: TextureArgs):
    """(info (L, 4) int32 rows (first texel, H, W, 0), first texel per level, total texels)."""
    faces = 6 if args.cube else 1
    images = args.tex.shape[0] * faces
    first, rows, firsts = 0, [], []
    for h, w in args.shapes:
        rows.append((first, h, w, 0))
        firsts.append(first)
        first += images * h * w
    return np.array(rows, np.int32), firsts, first, images


# glClearNamedBufferSubData (GL 4.5, section 6.3.1) with a null pattern: zeros written by the
# driver where the buffer lives, no host upload of zeros
_GL_R32UI, _GL_RED_INTEGER, _GL_UNSIGNED_INT = 0x8236, 0x8D94, 0x1405


def _cleared(ctx: Context, name: str, nbytes: int):
    """The context's scratch buffer ``name`` of at least ``nbytes``, its first ``nbytes``
    (a multiple of 4) set to 0 by the driver. Inside ``with ctx``."""
    buffer = ctx.scratch_buffer(name, nbytes)
    clear = ctx.gl_function("glClearNamedBufferSubData", None, ctypes.c_uint, ctypes.c_uint,
                            ctypes.c_ssize_t, ctypes.c_ssize_t, ctypes.c_uint, ctypes.c_uint,
                            ctypes.c_void_p)
    clear(buffer.glo, _GL_R32UI, 0, max(int(nbytes), 4), _GL_RED_INTEGER, _GL_UNSIGNED_INT,
          None)
    return buffer


# Every buffer the texture shader reads (the levels, the per-pixel inputs) is read through a
# buffer texture over it (glraster.diff.buffer_views, texelFetch in texture.comp). Units
# from _TEXEL_UNIT on (texels, uv, uv_da, bias, dL/d out, the level table, the pyramid
# passes' levels), which no other glraster pass samples from.
_TEXEL_UNIT = 8
_UNIT_TEXELS, _UNIT_UV, _UNIT_UV_DA, _UNIT_BIAS, _UNIT_GRAD_OUT, _UNIT_INFO, _UNIT_LEVELS = \
    range(7)


def _texel_vec(channels: int) -> int:  # floats per fetch of a texel or of dL/d out
    return buffer_views.float_vec(channels)


def _bind_view(ctx: Context, unit: int, buffer, nbytes: int, vec: int, what: str,
               words: int = 0) -> None:
    """Bind the first ``nbytes`` of ``buffer`` as a buffer texture of ``vec`` floats a
    texel (``words``: of 4 integers, GL_RGBA32UI or GL_RGBA32I) on unit _TEXEL_UNIT +
    ``unit``. Inside ``with ctx``."""
    buffer_views.bind(ctx, _TEXEL_UNIT + unit, buffer, nbytes, words or buffer_views.FLOATS[vec],
                      what, "use a smaller texture, fewer pixels or max_mip_level")


def _storage_limit(ctx: Context, nbytes: int, what: str) -> None:
    limit = getattr(ctx, "max_storage_block_size", 0) or (1 << 27)
    if nbytes > limit:
        raise ValueError(f"{what} needs {nbytes / 2**20:.1f} MiB in one storage buffer, more than "
                         f"the {limit / 2**20:.0f} MiB {ctx.renderer} allows: use a smaller "
                         "texture, fewer channels or max_mip_level")


# context -> (mark, buffer, sources): the levels its buffer "texture.levels" holds
# (_upload_levels)
_HELD: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


# levels this small are known by their bytes (front ends key only larger arrays)
_BY_BYTES = 4096


def _sources(ctx: Context, args: TextureArgs):
    """What the levels are made of, when a front end declared every array they come from
    (:mod:`glraster.gpu.uploads`: equal keys, equal bytes) or it is at most _BY_BYTES long:
    the geometry, whether the pyramid is built here, and each array's (key, owner
    reference) (a small one's: its bytes, no owner); else None."""
    arrays = (args.tex, *((args.mip or ()) if args.levels > 1 else ()))
    entries = []
    for a in arrays:
        a = np.ascontiguousarray(a, np.float32)
        entry = ctx.uploads.lookup(a)
        if entry is None and a.nbytes <= _BY_BYTES:
            entry = (a.tobytes(), _ALIVE)
        if entry is None:
            return None
        entries.append(entry)
    return (args.tex.shape, args.shapes, args.mip is None), tuple(entries)


def _ALIVE():  # the owner of bytes held by value: never collected
    return True


def _same_sources(held, sources) -> bool:
    """``held`` and ``sources`` (:func:`_sources`) are the same arrays, all still alive."""
    return (held is not None and sources is not None and held[0] == sources[0]
            and all(h[0] == s[0] and h[1]() is not None
                    for h, s in zip(held[1], sources[1], strict=True)))


def _upload_levels(ctx: Context, args: TextureArgs, mark=None):
    """Every level in the context's storage buffer "texture.levels" (base uploaded; mips
    uploaded or built on the GPU), unless it still holds them: those of ``mark`` (a mark
    this function returned, for the same ``args``: no texture call has filled the buffer
    since), or those of the same declared arrays (a constant texture and its pyramid are
    neither uploaded nor built again). Inside ``with ctx``. Returns (buffer, info, firsts,
    total texels, images, mark)."""
    info, firsts, total, images = _geometry(args)
    channels = args.channels
    _storage_limit(ctx, total * channels * 4, "the texture and its mip levels")
    buffer = ctx.scratch_buffer("texture.levels", total * channels * 4)
    held = _HELD.get(ctx)
    sources = _sources(ctx, args)
    if held is not None and held[1] is buffer and (
            (mark is not None and held[0] is mark) or _same_sources(held[2], sources)):
        return buffer, info, firsts, total, images, held[0]
    mark = object()
    _HELD[ctx] = (mark, buffer, sources)
    buffer.write(np.ascontiguousarray(args.tex, np.float32), offset=0)  # no bytes copy
    if args.levels > 1 and args.mip is not None:
        for k in range(1, args.levels):
            level = np.ascontiguousarray(args.mip[k - 1], np.float32)
            buffer.write(level, offset=firsts[k] * channels * 4)
    elif args.levels > 1:
        _pyramid_passes(ctx, buffer, args, firsts, images, backward=False)
    return buffer, info, firsts, total, images, mark


def _pyramid_passes(ctx: Context, buffer, args: TextureArgs, firsts, images: int,
                    backward: bool, top: int | None = None) -> None:
    """The box filter between neighbouring levels of ``buffer`` (every level, base first),
    one pass per level: forward, each coarser level from the finer one, finest first (one
    invocation per coarse texel); backward, each level's gradient added into the finer one
    through the transpose of the filter, coarsest first (a gather: one per fine texel),
    from level ``top`` down (None: the coarsest; the levels above it hold zeros)."""
    channels = args.channels
    defines = {"CHANNELS": channels, "LEVELS_UNIT": _TEXEL_UNIT + _UNIT_LEVELS,
               **({"BACKWARD": None} if backward else {})}
    program = ctx.compute_program(shader_path(_MIP_SHADER), defines)
    buffer.bind_to_storage_buffer(0)
    _bind_view(ctx, _UNIT_LEVELS, buffer, buffer.size, 1, "the mip levels")
    _set(program, "images", images)
    top = args.levels - 1 if top is None else min(top, args.levels - 1)
    steps = range(top, 0, -1) if backward else range(1, args.levels)
    for k in steps:
        (h0, w0), (h1, w1) = args.shapes[k - 1], args.shapes[k]
        _set(program, "fine_first", firsts[k - 1] * channels)
        _set(program, "coarse_first", firsts[k] * channels)
        _set(program, "fine_size", (w0, h0))
        _set(program, "coarse_size", (w1, h1))
        _run(ctx, program, images * (h0 * w0 if backward else h1 * w1))


def _defines(args: TextureArgs) -> dict:
    defines = {"FILTER": FILTER_CODE[args.filter_mode],
               "BOUNDARY": BOUNDARY_CODE[args.boundary_mode], "CHANNELS": args.channels,
               "TEXEL_VEC": _texel_vec(args.channels), "TEXEL_UNIT": _TEXEL_UNIT}
    if args.mipmapped and args.uv_da is not None:
        defines["HAS_DA"] = None
    if args.mipmapped and args.bias is not None:
        defines["HAS_BIAS"] = None
    return defines


def _pixel_inputs(args: TextureArgs):
    n = int(np.prod(args.uv.shape[:3]))
    uv = args.uv.reshape(n, -1)
    da = args.uv_da.reshape(n, -1) if args.uv_da is not None else None
    bias = args.bias.reshape(n) if args.bias is not None else None
    return n, uv, da, bias


def _bind_input(ctx, unit: int, name: str, values: np.ndarray, vec: int) -> None:
    """Upload a chunk's per-pixel input ``values`` (count, k) float32 and bind it as a
    buffer texture of ``vec`` floats a texel (:mod:`glraster.diff.buffer_views`)."""
    _bind_view(ctx, unit, ctx.storage_buffer(name, values), values.nbytes, vec, name)


def _bind_common(ctx, program, args, defines, part, uv, da, bias, info, count, first):
    _bind_view(ctx, _UNIT_INFO, ctx.storage_buffer("texture.info", info), info.nbytes, 4,
               "the level table", words=buffer_views.GL_RGBA32I)
    _bind_input(ctx, _UNIT_UV, "texture.uv", uv[part], uv.shape[1])
    if "HAS_DA" in defines:
        _bind_input(ctx, _UNIT_UV_DA, "texture.uv_da", da[part], 1)
    if "HAS_BIAS" in defines:
        _bind_input(ctx, _UNIT_BIAS, "texture.bias", bias[part], 1)
    _set(program, "n_pixels", count)
    _set(program, "first_pixel", first)
    _set(program, "pixels_per_image", int(args.uv.shape[1] * args.uv.shape[2]))
    _set(program, "tex_batch", int(args.tex.shape[0]))
    _set(program, "n_levels", args.levels)


def forward(tex, uv, uv_da=None, mip_level_bias=None, *mip, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None, own_mips=False,
            ctx: Context | None = None):
    """Filtered texture lookups on the GPU (nvdiffrast's ``texture``), on float32 arrays
    checked by :func:`glraster.diff.texture_args.check` (layouts there).

    Args:
        tex, uv, uv_da, mip_level_bias: the texture, coordinates, their screen derivatives
            (None: no level from them) and the level bias (None: 0).
        mip: levels 1, 2, ... (none: the pyramid is built on the GPU); each gets its own
            gradient, or, with ``own_mips``, they are tex's own pyramid built earlier
            (uploaded instead of built; their gradients are pulled back into tex).
        filter_mode: "nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear" or
            "auto" (linear-mipmap-linear with uv_da or mip_level_bias, else linear).
        boundary_mode: "wrap", "clamp", "zero" or "cube".
        max_mip_level: None (down to 1 x 1) or the number of levels after the base.
        ctx: the context (default: the process-wide one).

    Returns:
        ``((out,), saved)``: out (B, H, W, C) float32; saved a
        :class:`~glraster.diff.texture_args.TextureSaved`.
    """
    ctx = context_or_default(ctx)
    args = TextureArgs.of(tex, uv, uv_da, mip_level_bias, mip, filter_mode, boundary_mode,
                          max_mip_level, own_mips)
    n, uv_f, da, bias = _pixel_inputs(args)
    channels = args.channels
    out = np.empty((n, channels), np.float32)
    defines = _defines(args)
    coords = uv_f.shape[1]
    with ctx:
        program = ctx.compute_program(shader_path(_SHADER), defines)
        levels, info, _, total, _, mark = _upload_levels(ctx, args)
        _bind_view(ctx, _UNIT_TEXELS, levels, total * channels * 4, _texel_vec(channels),
                   "the texture and its mip levels")
        for first, count in _chunks(n, 4 * (3 * coords + 1 + channels)):
            part = slice(first, first + count)
            _bind_common(ctx, program, args, defines, part, uv_f, da, bias, info, count, first)
            result = ctx.scratch_buffer("texture.out", count * channels * 4)
            result.bind_to_storage_buffer(5)
            _run(ctx, program, count)
            result.read_into(out[part], size=count * channels * 4)   # no bytes, no copy
    return (out.reshape(args.uv.shape[:3] + (channels,)),), TextureSaved(args, None, ctx, mark)


# pixels per backward invocation: consecutive pixels add their terms for a texel they both
# read in the invocation, and send each texel's sum once (texture.comp, "Held")
BACKWARD_RUN = 16

def fixed_point_shift(max_abs_g: float, pixels: int) -> int:
    """k such that the deterministic backward adds a contribution v = w g (|w| <= 1) as
    round(v 2^k): the largest with max |g| 2^k < 2^28. The texel sums' low words are
    biased by 2^31 (:func:`glraster.diff.compute.fixed_point_clear`, as
    :class:`glraster.diff.compute.FixedPointSum`'s), so a contribution costs one atomic
    until a texel's running sum crosses +-2^31, after at least 8 max |g| of them (several
    pixels' w = 1 taps of nearest or magnified filtering sum on one texel: the 3 bits of
    headroom keep those carries rare); a texel's sum of at most 8 a pixel stays below
    2^63 for fewer than 2^28 pixels. Each contribution is off by at most
    2^-(k+1) <= 2^-28 max |g| (2^-5 of a float32 ulp of max |g|)."""
    if pixels >= 1 << 28:
        raise ValueError(f"deterministic texture sums take fewer than 2^28 pixels, got {pixels}")
    top = int(np.frexp(max_abs_g)[1]) if max_abs_g > 0 else 0   # max |g| < 2^top
    return 28 - top


def fixed_point_values(ctx: Context, words, count: int, shift: int):
    """The first ``count`` 64-bit fixed-point sums of the uint buffer ``words`` (low word,
    high word, two's complement; include/fixed_point.glsl; it holds a whole number of
    groups of 4 values, ``-(-count // 4) * 32`` bytes or more) as float32 round(q 2^-shift),
    in the context's float scratch buffer ``texture.grad_tex_float`` (returned), converted
    on the GPU (``shaders/diff/texture_resolve.comp``): the float NumPy's int64 -> float64
    -> ldexp -> float32 gives, with half the bytes to read back and the pyramid's pull-back
    run where the values are. Inside ``with ctx``."""
    quads = -(-count // 4)
    program = ctx.compute_program(shader_path(_RESOLVE_SHADER), {"WORDS_UNIT": _TEXEL_UNIT})
    out = ctx.scratch_buffer("texture.grad_tex_float", max(quads, 1) * 16)
    _bind_view(ctx, _UNIT_TEXELS, words, max(quads, 1) * 32, 4, "the texel gradients",
               words=buffer_views.GL_RGBA32UI)
    out.bind_to_storage_buffer(1)
    _set(program, "unit", float(np.ldexp(1.0, -shift)))
    step = _MAX_GROUPS * LOCAL_SIZE
    for first in range(0, quads, step):      # at most 65535 work groups a dispatch
        _set(program, "first_quad", first)
        _set(program, "n_quads", min(step, quads - first))
        _run(ctx, program, min(step, quads - first))
    return out


class _TexelGradients:
    """Where the backward sums the texel gradients (inside ``with ctx``; made only when tex
    or a mip level wants one): a zeroed storage buffer the shader adds into, float32 with
    float atomics or a compare-and-swap loop, or (``per_pixel``, deterministic) signed
    64-bit fixed-point integers (:func:`fixed_point_shift`, biased by 2^31) with integer atomics, whose sum
    does not depend on the order of the additions."""

    def __init__(self, ctx: Context, mode: str, total: int, channels: int, program,
                 g_flat: np.ndarray, mipmapped: bool):
        self.ctx, self.mode, self.total, self.channels = ctx, mode, total, channels
        # per_pixel: two words a value, whole groups of 4 values (fixed_point_values)
        nbytes = -(-total * channels // 4) * 32 if mode == "per_pixel" else total * channels * 4
        _storage_limit(ctx, nbytes, "the texel gradients")
        if mode == "per_pixel":      # sums of 0 with the fixed-point bias
            self.buffer = ctx.scratch_buffer("texture.grad_tex", nbytes)
            fixed_point_clear(ctx, self.buffer, nbytes)
        else:
            self.buffer = _cleared(ctx, "texture.grad_tex", nbytes)
        self.buffer.bind_to_storage_buffer(9)
        self.top = None
        if mipmapped:
            self.top = _cleared(ctx, "texture.top_level", 4)
            self.top.bind_to_storage_buffer(10)
        if mode == "per_pixel":
            max_abs = float(max(g_flat.max(), -g_flat.min())) if g_flat.size else 0.0
            self.shift = fixed_point_shift(max_abs, len(g_flat))
            half = self.shift // 2
            _set(program, "fixed_scale_a", float(2.0 ** half))
            _set(program, "fixed_scale_b", float(2.0 ** (self.shift - half)))

    def levels(self, args: TextureArgs, firsts, images) -> np.ndarray:
        """(texels, C) float32: every level's texel gradients, base first, a built (or own)
        pyramid's pulled back into the base (then only the base's rows are read back)."""
        if self.mode == "per_pixel":
            self.buffer = fixed_point_values(self.ctx, self.buffer, self.total * self.channels,
                                             self.shift)
        if not args.pulls_pyramid:
            return _rows(self.buffer, self.total, self.channels)
        top = None if self.top is None else int(_read(self.top, 1, np.int32)[0])
        _pyramid_passes(self.ctx, self.buffer, args, firsts, images, backward=True, top=top)
        return _rows(self.buffer, firsts[1], self.channels)


def _rows(buffer, rows: int, channels: int) -> np.ndarray:
    """The first ``rows`` x ``channels`` floats of ``buffer`` read straight into a new,
    writable (rows, channels) array (no bytes object, no copy)."""
    out = np.empty((rows, channels), np.float32)
    buffer.read_into(out, size=out.nbytes)
    return out


def _split_levels(args: TextureArgs, flat: np.ndarray, firsts, total: int, want):
    """(grad_tex, [grad of each mip input]) from :meth:`_TexelGradients.levels`' rows
    (views of ``flat``)."""
    grad_tex = None
    if want[0]:
        stop = firsts[1] if args.levels > 1 else total
        grad_tex = flat[:stop].reshape(args.tex.shape)   # views of one fresh array
    grad_mip = [None] * len(args.mip or ())
    if args.mipmapped:
        for k, m in enumerate(args.user_mips):
            if not want[4 + k]:
                continue
            if k + 1 < args.levels:
                start, stop = firsts[k + 1], (firsts[k + 2] if k + 2 < args.levels else total)
                grad_mip[k] = flat[start:stop].reshape(m.shape)
            else:
                grad_mip[k] = np.zeros(m.shape, np.float32)
    return grad_tex, grad_mip


def backward(saved: TextureSaved, grad_out, *, needs=None, deterministic: bool = False,
             accumulate: str | None = None):
    """Gradients of :func:`forward`, on the GPU.

    Args:
        saved: the second value :func:`forward` returned.
        grad_out: (B, H, W, C) dL/d out, or None (zero).
        needs: None (all) or one bool per input (tex, uv, uv_da, mip_level_bias, *mip).
            Without tex or mip levels wanted the shader is compiled without the texel sums
            (nothing spread, read back or pulled through the pyramid); without uv, uv_da
            and the bias, without their gradients (no texel reads for them, nothing written);
            each is read back only where wanted; nothing runs when nothing is wanted.
            "nearest" has zero coordinate gradients: they are filled with zeros on the
            host, never computed (no pass at all when only they are wanted).
        deterministic: bit-identical results from run to run (accumulation "per_pixel":
            the texel gradients summed on the GPU as 64-bit fixed-point integers, whose sum
            does not depend on the order of the additions, rounded once to float32; the
            pyramid pass is a gather).
        accumulate: force one of :data:`glraster.diff.compute.ACCUMULATIONS`.

    Returns:
        ``(grad_tex, grad_uv, grad_uv_da, grad_mip_level_bias, *grad_mip)``, float32, None
        where not wanted or not given, as the reference's
        (:func:`glraster.diff.texture_reference.backward`).
    """
    args, ctx = saved.args, saved.ctx
    mips = len(args.mip or ())
    want = wanted(needs, 4 + mips)
    want[2] &= args.uv_da is not None
    want[3] &= args.bias is not None
    # nearest is piecewise constant in uv (and reads no level): its coordinate gradients
    # are zeros, filled here without a pass for them
    coord = any(want[1:4]) and args.filter_mode != "nearest"
    texels = want[0] or (args.mipmapped and any(want[4:4 + len(args.user_mips)]))
    mode = accumulation(ctx, deterministic, accumulate)
    shape = args.uv.shape[:3] + (args.channels,)
    grad_out = (np.zeros(shape, np.float32) if grad_out is None
                else validate.image("grad_out", grad_out, shape=shape, dtype=np.float32))
    if not (texels or coord):
        zeros = [np.zeros(a.shape, np.float32) if w else None
                 for a, w in zip((args.uv, args.uv_da, args.bias), want[1:4])]
        return (None, *zeros, *(None,) * mips)
    n, uv_f, da, bias = _pixel_inputs(args)
    channels, coords = args.channels, uv_f.shape[1]
    g_flat = grad_out.reshape(n, channels)
    defines = dict(_defines(args), BACKWARD=None, RUN=BACKWARD_RUN)
    if texels:   # else the shader spreads nothing (no texel buffer, no accumulation)
        defines.update({"TEX_GRAD": None, _ACCUM_DEFINES[mode]: None})
    if coord:   # else no texel reads for them and no per-pixel outputs
        defines["COORD_GRAD"] = None
    grad_uv = np.empty((n, coords), np.float32) if want[1] and coord else (
        np.zeros((n, coords), np.float32) if want[1] else None)
    grad_da = np.zeros((n, 2 * coords), np.float32) if want[2] else None
    grad_bias = np.zeros(n, np.float32) if want[3] else None
    per_pixel = 4 * (3 * coords + 1 + 2 * channels + 3 * coords + 1)
    with ctx:
        program = ctx.compute_program(shader_path(_SHADER), defines)
        levels, info, firsts, total, images, _ = _upload_levels(ctx, args, saved.uploaded)
        _bind_view(ctx, _UNIT_TEXELS, levels, total * channels * 4, _texel_vec(channels),
                   "the texture and its mip levels")
        sums = (_TexelGradients(ctx, mode, total, channels, program, g_flat,
                                args.mipmapped) if texels else None)
        for first, count in _chunks(n, per_pixel):
            part = slice(first, first + count)
            _bind_common(ctx, program, args, defines, part, uv_f, da, bias, info, count, first)
            _bind_input(ctx, _UNIT_GRAD_OUT, "texture.grad_out", g_flat[part],
                        _texel_vec(channels))
            outs = (_bind_coordinate_outputs(ctx, defines, count, coords)
                    if "COORD_GRAD" in defines else ())
            _run(ctx, program, -(-count // BACKWARD_RUN))
            for target, (buffer, width) in zip((grad_uv, grad_da, grad_bias), outs):
                if target is not None and buffer is not None:   # straight into its rows
                    buffer.read_into(target[part], size=count * width * 4)
        flat = sums.levels(args, firsts, images) if texels else None
    grad_tex, grad_mip = (_split_levels(args, flat, firsts, total, want) if texels
                          else (None, [None] * mips))
    shape3 = args.uv.shape[:3]
    return (grad_tex, None if grad_uv is None else grad_uv.reshape(args.uv.shape),
            None if grad_da is None else grad_da.reshape(shape3 + (2 * coords,)),
            None if grad_bias is None else grad_bias.reshape(shape3), *grad_mip)


def _bind_coordinate_outputs(ctx: Context, defines, count: int, coords: int):
    """Bind a chunk's gradient outputs for uv (6), uv_da (7) and the bias (8); returns
    ((buffer, values per pixel) or (None, 0)) for each."""
    out_uv = ctx.scratch_buffer("texture.grad_uv", count * coords * 4)
    out_uv.bind_to_storage_buffer(6)
    outs = [(out_uv, coords), (None, 0), (None, 0)]
    if "HAS_DA" in defines:
        outs[1] = (ctx.scratch_buffer("texture.grad_uv_da", count * 2 * coords * 4), 2 * coords)
        outs[1][0].bind_to_storage_buffer(7)
    if "HAS_BIAS" in defines:
        outs[2] = (ctx.scratch_buffer("texture.grad_bias", count * 4), 1)
        outs[2][0].bind_to_storage_buffer(8)
    return outs


def build_mips(tex, max_mip_level=None, *, boundary_mode="wrap", ctx: Context | None = None):
    """The GPU's mip pyramid of ``tex`` (levels 1, 2, ..., float32), as :func:`forward`
    builds it (for checks and for passing as ``mip``)."""
    ctx = context_or_default(ctx)
    coords = 3 if boundary_mode == "cube" else 2
    tex_arr = np.asarray(tex)
    batch = tex_arr.shape[0] if tex_arr.ndim in (4, 5) else 1
    dummy = np.zeros((batch, 1, 1, coords), np.float32)
    bias = np.zeros((batch, 1, 1), np.float32)
    args = check(tex_arr, dummy, None, bias, filter_mode="linear-mipmap-linear",
                 boundary_mode=boundary_mode, max_mip_level=max_mip_level, dtype=np.float32)
    channels = args.channels
    with ctx:
        buffer, _, firsts, total, _, _ = _upload_levels(ctx, args)
        flat = _read(buffer, total * channels).reshape(-1, channels)
    lead = args.tex.shape[:-3]
    out = []
    for k in range(1, args.levels):
        stop = firsts[k + 1] if k + 1 < args.levels else total
        h, w = args.shapes[k]
        out.append(np.array(flat[firsts[k]:stop].reshape(lead + (h, w, channels))))
    return out


# the driver's sampler at an explicit level, one invocation per pixel (sampler_probe)
_PROBE_SOURCE = """#version 450
layout(local_size_x = 64) in;
layout(std430, binding = 2) readonly buffer Uv { vec2 uv[]; };
layout(std430, binding = 3) readonly buffer Lod { float lod[]; };
layout(std430, binding = 4) writeonly buffer Out { vec4 result[]; };
uniform sampler2D tex;
uniform uint n_pixels;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pixels) return;
    result[i] = textureLod(tex, uv[i], lod[i]);
}
"""


def sampler_probe(tex, uv, level, *, boundary_mode="wrap", ctx: Context | None = None):
    """The driver's own sampler against glraster's fetches, at the same explicit level.

    Uploads ``tex`` (1, Ht, Wt, C <= 4) with the GPU-built pyramid as the levels of a GL
    texture (RGBA32F), samples it with ``textureLod(sampler, uv, level)`` (LINEAR_MIPMAP_
    LINEAR, the wrap mode as a GL wrap: REPEAT, CLAMP_TO_EDGE, CLAMP_TO_BORDER with a zero
    border) in a compute shader, and returns ``(sampler_out, fetch_out)``, both (1, H, W, C)
    float32; fetch_out is :func:`forward` with mip_level_bias = level.
    """
    ctx = context_or_default(ctx)
    tex = np.ascontiguousarray(tex, np.float32)
    uv = np.ascontiguousarray(uv, np.float32)
    level = np.ascontiguousarray(level, np.float32)
    if tex.ndim != 4 or tex.shape[0] != 1 or not 1 <= tex.shape[-1] <= 4:
        raise ValueError(f"tex must have shape (1, Ht, Wt, C) with C <= 4, got {tex.shape}")
    if boundary_mode not in ("wrap", "clamp", "zero"):
        raise ValueError(f"boundary_mode must be 'wrap', 'clamp' or 'zero', got {boundary_mode!r}")
    args = check(tex, uv, None, level, filter_mode="linear-mipmap-linear",
                 boundary_mode=boundary_mode, dtype=np.float32)
    (fetch,), _ = forward(args.tex, args.uv, None, args.bias, filter_mode=args.filter_mode,
                          boundary_mode=boundary_mode, ctx=ctx)
    mips = build_mips(tex, ctx=ctx)
    channels = tex.shape[-1]
    levels = [tex[0], *[m[0] for m in mips]]
    n = int(np.prod(uv.shape[:3]))
    with ctx:
        mgl = ctx.mgl
        h, w = levels[0].shape[:2]
        texture = mgl.texture((w, h), 4, dtype="f4")
        sampler = program = None
        try:
            texture.build_mipmaps(0, len(levels) - 1)   # allocates the levels
            for k, lv in enumerate(levels):
                rgba = np.zeros(lv.shape[:2] + (4,), np.float32)
                rgba[..., :channels] = lv
                texture.write(rgba.tobytes(), level=k)
            repeat = boundary_mode == "wrap"        # False: CLAMP_TO_EDGE
            sampler = mgl.sampler(repeat_x=repeat, repeat_y=repeat, texture=texture,
                                  filter=(mgl.LINEAR_MIPMAP_LINEAR, mgl.LINEAR))
            if boundary_mode == "zero":           # CLAMP_TO_BORDER, border (0, 0, 0, 0)
                sampler.border_color = (0.0, 0.0, 0.0, 0.0)
            program = mgl.compute_shader(_PROBE_SOURCE)
            sampler.use(location=0)
            program["tex"].value = 0
            program["n_pixels"].value = n
            ctx.storage_buffer("texture.probe_uv", uv.reshape(n, 2)).bind_to_storage_buffer(2)
            ctx.storage_buffer("texture.probe_lod", level.reshape(n)).bind_to_storage_buffer(3)
            out = ctx.scratch_buffer("texture.probe_out", n * 16)
            out.bind_to_storage_buffer(4)
            _run(ctx, program, n)
            result = _read(out, n * 4).reshape(n, 4)[:, :channels]
        finally:
            for obj in (program, sampler, texture):
                if obj is not None:
                    obj.release()
    return result.reshape(uv.shape[:3] + (channels,)), fetch
