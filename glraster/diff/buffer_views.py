"""Buffer textures over the compute passes' input buffers (GL 4.6 section 8.9).

On llvmpipe a storage-buffer load at a per-invocation address is one scalar load per SIMD
lane, while ``texelFetch`` from a buffer texture over the same buffer gathers as a vector:
several times faster, and the same bits (no copy, no conversion). The texture and
interpolate passes read every gathered input this way; :func:`bind` keeps one texture
object per context and unit and points it at the buffer on every call.
"""

from __future__ import annotations

import ctypes
import weakref

from glraster.gpu.context import Context

__all__ = ["FLOATS", "GL_RGB32I", "GL_RGBA32I", "GL_RGBA32UI", "bind", "float_vec",
           "texel_bytes"]

FLOATS = {4: 0x8814, 3: 0x8815, 2: 0x8230, 1: 0x822E}  # GL_RGBA32F .. GL_R32F, by floats
GL_RGB32I, GL_RGBA32I, GL_RGBA32UI = 0x8D83, 0x8D82, 0x8D70
_TEXEL_BYTES = {**{fmt: 4 * n for n, fmt in FLOATS.items()}, GL_RGB32I: 12, GL_RGBA32I: 16,
                GL_RGBA32UI: 16}
_GL_TEXTURE_BUFFER, _GL_MAX_TEXTURE_BUFFER_SIZE = 0x8C2A, 0x8C2B
# context -> ({unit: buffer texture name}, GL_MAX_TEXTURE_BUFFER_SIZE)
_VIEWS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def texel_bytes(fmt: int) -> int:
    """Bytes a texel of the sized format ``fmt`` (one of this module's) holds."""
    return _TEXEL_BYTES[fmt]


def float_vec(count: int) -> int:
    """Floats per fetch of rows of ``count`` floats: 4, 2 or 1, whichever divides it."""
    return 4 if count % 4 == 0 else (2 if count % 2 == 0 else 1)


def bind(ctx: Context, unit: int, buffer, nbytes: int, fmt: int, what: str,
         remedy: str) -> None:
    """Bind the first ``nbytes`` of ``buffer`` (a moderngl buffer) as a buffer texture of
    the sized format ``fmt`` on texture unit ``unit``; a ValueError naming ``what`` and
    ``remedy`` when its texels exceed the driver's GL_MAX_TEXTURE_BUFFER_SIZE. Inside
    ``with ctx``."""
    views = _VIEWS.get(ctx)
    if views is None:
        limit = ctypes.c_int(0)
        ctx.gl_function("glGetIntegerv", None, ctypes.c_uint, ctypes.POINTER(ctypes.c_int))(
            _GL_MAX_TEXTURE_BUFFER_SIZE, ctypes.byref(limit))
        views = _VIEWS[ctx] = ({}, limit.value)
    name = views[0].get(unit)
    if name is None:
        names = (ctypes.c_uint * 1)()
        ctx.gl_function("glCreateTextures", None, ctypes.c_uint, ctypes.c_int,
                        ctypes.POINTER(ctypes.c_uint))(_GL_TEXTURE_BUFFER, 1, names)
        name = views[0][unit] = names[0]
    size = _TEXEL_BYTES[fmt]
    texels = int(nbytes) // size
    if texels > views[1]:
        raise ValueError(f"{what} needs {texels} texels of {size} bytes in one buffer "
                         f"texture, more than the {views[1]} {ctx.renderer} allows: {remedy}")
    ctx.gl_function("glTextureBufferRange", None, ctypes.c_uint, ctypes.c_uint, ctypes.c_uint,
                    ctypes.c_ssize_t, ctypes.c_ssize_t)(
        name, fmt, buffer.glo, 0, max(texels, 1) * size)
    ctx.gl_function("glBindTextureUnit", None, ctypes.c_uint, ctypes.c_uint)(unit, name)
