"""Compute-shader dispatch shared by the GPU cores: pixel chunks, buffers, accumulations.

Every GPU backward (and interpolate's forward) runs over the pixels of the flattened
(B, H, W) grid (one invocation per pixel; :data:`RUN_PIXELS` consecutive pixels per
invocation in the rasterize and interpolate backward), in chunks whose per-pixel buffers
stay under :data:`MAX_CHUNK_BYTES`. Per-pixel outputs are written in place; per-vertex
gradients are sums over the pixels of each vertex's triangles, formed by one of these
accumulations (the rasterize and interpolate backward first sum the terms of an
invocation's run of pixels on one triangle locally, then add each sum with one atomic):

``"atomic_float"``
    ``atomicAdd`` on float members of a storage buffer (``GL_NV_shader_atomic_float``,
    which Mesa's llvmpipe offers). Fastest; the order of the additions is the order in
    which invocations reach them, so the float32 result may change in its last bits from
    run to run.
``"cas"``
    The fallback where the extension is missing: an ``atomicCompSwap`` loop on the float's
    bit pattern (core GL 4.3). Same result model as ``"atomic_float"``, slower.
``"fixed_point"`` (``deterministic=True`` for rasterize, interpolate, antialias)
    Each term is rounded to a multiple of 2^-k and added as a 64-bit integer with 32-bit
    integer atomics on the GPU, one a term as a rule (:class:`FixedPointSum`: range and
    rounding). Integer
    addition is associative, so the same inputs give bit-identical results on every run,
    whatever the order in which the invocations add (or the chunking of the pixels).
``"per_pixel"`` (``deterministic=True`` for texture)
    Texture's name for the same fixed-point sum (its accumulate argument keeps the name
    it had when the terms were summed on the host): shaders/diff/texture.comp adds the
    words with the shared ``fixed_point.glsl``.
"""

from __future__ import annotations

import ctypes

import numpy as np

from glraster.errors import ArgumentError
from glraster.diff.ids import decode_ids
from glraster.gpu.context import Context

__all__ = [
    "ACCUMULATIONS", "DEFINES", "FIXED_BIAS", "FIXED_POINT_ACCUMULATIONS", "FixedPointSum",
    "LOCAL_SIZE", "RUN_PIXELS", "MAX_CHUNK_BYTES", "accumulation", "chunks", "corner_vertices",
    "fixed_point_clear", "fixed_point_exponent",
    "has_atomic_float", "read", "run", "set_uniform", "zeroed",
]

# the accumulations texture offers, and those rasterize, interpolate and antialias offer
ACCUMULATIONS = ("atomic_float", "cas", "per_pixel")
FIXED_POINT_ACCUMULATIONS = ("atomic_float", "cas", "fixed_point")
# the shader define that selects each accumulation
DEFINES = {"atomic_float": "ACCUM_ATOMIC_FLOAT", "cas": "ACCUM_CAS",
           "per_pixel": "ACCUM_PER_PIXEL", "fixed_point": "ACCUM_FIXED_POINT"}
LOCAL_SIZE = 64
# Largest storage buffer glraster fills in one dispatch (llvmpipe allows 128 MiB); bigger
# inputs are processed in chunks of pixels.
MAX_CHUNK_BYTES = 1 << 26
# Consecutive pixels one invocation of an accumulating backward pass (rasterize,
# interpolate) handles, in every accumulation: the terms of the pixels it finds on one
# triangle are summed locally and added with one atomic per value (fixed point: one pair
# of word atomics), instead of one per pixel. Few triangles over many pixels otherwise
# put every invocation on the same few addresses (measured in docs/differentiable.md,
# "Backward accumulation"). 1 adds every term on its own (tests compare the two).
RUN_PIXELS = 16


def has_atomic_float(ctx: Context) -> bool:
    """The driver offers atomicAdd on floats in storage buffers (GL_NV_shader_atomic_float)."""
    return "GL_NV_shader_atomic_float" in ctx.extensions


def accumulation(ctx: Context, deterministic: bool = False, accumulate: str | None = None,
                 offered: tuple[str, ...] = ACCUMULATIONS) -> str:
    """The accumulation a pass uses: ``accumulate`` when given (one of ``offered``, the
    op's), else the op's deterministic one (``"fixed_point"`` where offered, else
    ``"per_pixel"``) when ``deterministic``, else ``"atomic_float"`` where the driver has
    it, else ``"cas"``."""
    if accumulate is not None:
        if accumulate not in offered:
            raise ArgumentError("accumulate", f"accumulate must be one of "
                                f"{', '.join(offered)}, got {accumulate!r}")
        if accumulate == "atomic_float" and not has_atomic_float(ctx):
            raise ArgumentError("accumulate", "accumulate='atomic_float' needs "
                                "GL_NV_shader_atomic_float, which "
                                f"{ctx.renderer} does not offer")
        return accumulate
    if deterministic:
        return "fixed_point" if "fixed_point" in offered else "per_pixel"
    return "atomic_float" if has_atomic_float(ctx) else "cas"


def set_uniform(program, name: str, value) -> None:
    """Set a uniform the shader uses (the compiler drops unused ones). The handles are
    looked up once per program, and a value equal to the one last set here is not written
    again (a program keeps its uniforms' values, GL 4.5 section 7.6): set a program's
    uniforms through this function only."""
    cache = program.__dict__.get("_uniforms")
    if cache is None:
        cache = program._uniforms = {}
    held = cache.get(name)
    if held is None:
        held = cache[name] = [program.get(name, None), None]
    if held[0] is not None and held[1] != value:
        held[0].value = held[1] = value


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
    """The first ``count`` values of ``buffer`` as a 1-D array of ``dtype`` (none: no read,
    GL cannot map 0 bytes)."""
    if count == 0:
        return np.empty(0, dtype)
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


# --------------------------------------------------------------------------- fixed point


# FixedPointSum: the bias of every value's low word, and B with every |q| < 2^B
FIXED_BIAS = 1 << 31
FIXED_TERM_BITS = 31
# glClearNamedBufferSubData (GL 4.5, section 6.3.1) with (2^31, 0) as the pattern
_GL_RG32UI, _GL_RG_INTEGER, _GL_UNSIGNED_INT = 0x823C, 0x8228, 0x1405


def fixed_point_exponent(largest: float, terms: int = 1) -> int:
    """The exponent k of fixed-point sums whose largest term magnitude is ``largest``
    (> 0, finite): the largest k with ``largest * 2^k < 2^31``, clipped to [-126, 127]
    (2^k a normal float32; the upper clip only coarsens the rounding, the lower one is
    never reached by float32 terms). ``terms``, a bound on the number of terms of one
    value, must stay below 2^32 - 1 (then no sum of them reaches 2^63)."""
    if not 0 < int(terms) < (1 << 32) - 1:
        raise ValueError(f"fixed-point sums take 1 .. 2^32 - 2 terms per value, got {terms}")
    _, e = np.frexp(np.float64(largest))                         # largest < 2^e
    return int(np.clip(FIXED_TERM_BITS - int(e), -126, 127))


def fixed_point_clear(ctx: Context, buffer, nbytes: int) -> None:
    """Set the first ``nbytes`` (a multiple of 8) of ``buffer`` to (low, high) word pairs
    (2^31, 0): fixed-point sums of 0 with the bias of include/fixed_point.glsl, written
    by the driver where the buffer lives. Inside ``with ctx``."""
    clear = ctx.gl_function("glClearNamedBufferSubData", None, ctypes.c_uint, ctypes.c_uint,
                            ctypes.c_ssize_t, ctypes.c_ssize_t, ctypes.c_uint, ctypes.c_uint,
                            ctypes.c_void_p)
    pattern = (ctypes.c_uint32 * 2)(FIXED_BIAS, 0)
    clear(buffer.glo, _GL_RG32UI, 0, int(nbytes), _GL_RG_INTEGER, _GL_UNSIGNED_INT,
          ctypes.byref(pattern))


class FixedPointSum:
    """Bit-reproducible sums of float32 terms on the GPU, in 64-bit fixed point
    (``ACCUM_FIXED_POINT``, shaders/include/fixed_point.glsl).

    The summed values form ``groups`` groups of ``size`` values (the images of a batched
    input, or one group); group g has its own exponent k_g. A term t of group g is added
    as the integer ``q = roundEven(t * 2^k_g)`` to a 64-bit two's-complement sum held in
    two 32-bit words (``atomicAdd`` on uint, core GL 4.3: no 64-bit atomics needed), the
    low word biased by 2^31: the high word takes an atomic only when the low one carries,
    i.e. when a running sum crosses +-2^31 (+ a multiple of 2^32), so a term costs one
    atomic as a rule (where an unbiased sum near zero would carry at every sign change).

    Range: ``k_g = fixed_point_exponent(M_g, terms)``, M_g the largest |t| added to group
    g in this call: every |q| <= 2^31, so a value of n terms stays below n 2^31 in
    magnitude, and ``terms`` (a bound on n, 3 per pixel for a triangle's corners) below
    2^32 - 1 keeps every sum, bias included, inside the 64 bits. The dispatch records M_g
    itself (``atomicMax`` on the float bits). The first pass uses the exponents of the
    previous call under the same ``name`` as a guess; where one differs from the one M_g
    gives, the sums are discarded and the pass is repeated with the right exponents. So
    k_g depends on this call's terms only, never on the history; in a fitting loop, where
    M_g rarely changes its power of two, one pass is the rule.

    Rounding: each term is off by at most 2^-(k_g + 1) <= M_g 2^-31 (2^-8 of a float32
    ulp of M_g; a term of M_g / 2^7 or more, 24 significant bits, is exact), so a value of
    n terms differs from the exact sum of its float32 terms by at most
    ``n * 2^-(k_g + 1) <= n * M_g * 2^-31`` (for n >= 2 terms of M_g / 2 or more, at most
    2^-6 of the float accumulations' bound (n - 1) u sum|t|, u = 2^-24), before the
    conversion to float32 (through float64), which adds at most one float32 ulp of the
    result. Huge terms only lower k_g (down to 2^-97 for float32's largest); non-finite
    terms raise :class:`~glraster.errors.ArgumentError` naming ``argument``.

    Use::

        acc = FixedPointSum(ctx, "op.grad", groups, size, terms, "grad_out")
        for _ in acc.passes(program, binding):
            ...dispatch every chunk...
        total = acc.result()          # (groups * size,) float32
    """

    _guesses: dict = {}       # name -> the exponents of the last call (a guess only)

    def __init__(self, ctx: Context, name: str, groups: int, size: int, terms: int,
                 argument: str):
        self.ctx, self.name, self.groups, self.size = ctx, name, int(groups), int(size)
        self.terms, self.argument = max(int(terms), 1), argument
        guess = self._guesses.get(name)
        if guess is None or len(guess) != self.groups:
            guess = [fixed_point_exponent(1.0, self.terms)] * self.groups
        self.exponents = list(guess)
        self.passes_run = 0
        self._result = None

    def passes(self, program, binding: int):
        """Yield once per pass, with the accumulator cleared and bound to ``binding`` and
        the uniform ``fixed_groups`` set; the caller dispatches all its pixels each time."""
        head = 2 * self.groups
        words = head + 2 * self.groups * self.size
        buffer = self.buffer = self.ctx.scratch_buffer(self.name, 4 * words)
        set_uniform(program, "fixed_groups", self.groups)
        for _ in range(2):
            header = np.zeros(head, np.uint32)
            header[self.groups:] = np.ldexp(np.float32(1), self.exponents
                                            ).astype(np.float32).view(np.uint32)
            fixed_point_clear(self.ctx, buffer, 4 * words)     # then the header
            buffer.write(header.tobytes())
            buffer.bind_to_storage_buffer(binding)
            self.passes_run += 1
            yield
            data = read(buffer, words, np.uint32)
            largest = data[:self.groups].view(np.float32)
            if not np.isfinite(largest).all():
                raise ArgumentError(self.argument, "deterministic sums need finite terms; "
                                    f"{self.argument} gives a non-finite gradient term")
            needed = [k if m == 0 else fixed_point_exponent(m, self.terms)
                      for k, m in zip(self.exponents, largest)]
            if needed == self.exponents:
                self._result = self._decode(data[head:])
                self._guesses[self.name] = needed
                return
            self.exponents = needed
        raise AssertionError("fixed-point exponents changed between passes")

    def bind(self, binding: int) -> None:
        """Bind the accumulator again (after another pass used ``binding``)."""
        self.buffer.bind_to_storage_buffer(binding)

    def _decode(self, words: np.ndarray) -> np.ndarray:
        # (low, high) word pairs in memory order are little-endian int64 two's complement
        # (GL and NumPy share the host's byte order; |exact| < 2^63)
        exact = np.ascontiguousarray(words).view("<i8").reshape(self.groups, self.size)
        exact = exact - FIXED_BIAS          # the bias off (|sum| < 2^63 - 2^31: no wrap)
        # 2^-k is exact in float64 (k in [-126, 127]), so the product is ldexp's
        scale = np.ldexp(1.0, -np.asarray(self.exponents, np.int64))[:, None]
        return (exact * scale).astype(np.float32).reshape(-1)

    def result(self) -> np.ndarray:
        """(groups * size,) float32: the sums of the last :meth:`passes`."""
        return self._result
