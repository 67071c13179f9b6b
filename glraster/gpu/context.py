"""The headless OpenGL context and the GL objects glraster keeps alive between calls.

A :class:`Context` owns one moderngl context (EGL or OSMesa) and caches, across calls:
compiled programs (one per shader variant), framebuffers (the last few resolutions and
output sets) and storage buffers (grown geometrically, never shrunk). Nothing grows with
the number of calls.
"""

from __future__ import annotations

import ctypes
import os
import re
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from glraster.errors import ArgumentError, BadEnvironment, ForkedProcess, GLVersionError
from glraster.gpu.backends import create_backend
from glraster.gpu.backends.current import MIN_GL, version_text
from glraster.gpu.shaders import compile_compute, compile_program
from glraster.gpu.uploads import UploadCache

# Framebuffers of one size and format drawn before any is read back (pipeline.draw_many),
# and at most as many pixels in all (larger ones go one at a time: no memory to gain).
FRAMEBUFFER_SLOTS = 4
SLOT_PIXELS = 1 << 16
# Framebuffers kept alive: enough for a test suite that alternates a few sizes, and for
# the slots of one draw_many.
FRAMEBUFFER_CACHE_SIZE = 4 + FRAMEBUFFER_SLOTS

# GL versions (major * 10 + minor): shader storage buffers (and their limits) exist from
# 4.3; glraster's storage-buffer and compute shaders are GLSL 4.50.
STORAGE_GL = 43
GLSL450_GL = 45

# glGetIntegerv / glGetMultisamplefv enums (GL 4.5 core, tables 23.x)
GL_SAMPLES = 0x80A9
GL_SAMPLE_POSITION = 0x8E50
# the limits a multisample render target must respect, all of them (GL 4.5 section 9.2.4,
# 8.8: a texture of an integer format takes at most MAX_INTEGER_SAMPLES)
SAMPLE_LIMITS = ("GL_MAX_SAMPLES", "GL_MAX_COLOR_TEXTURE_SAMPLES",
                 "GL_MAX_DEPTH_TEXTURE_SAMPLES", "GL_MAX_INTEGER_SAMPLES")


def parse_gl_version(value, what: str = "max_gl") -> int:
    """33, 330, "3.3" or "33" -> 33 (major * 10 + minor); ValueError naming ``what``."""
    text = str(value).strip()
    match = re.fullmatch(r"(\d)\.(\d)|(\d)(\d)0?", text)
    if isinstance(value, bool) or match is None:
        raise ArgumentError(what, f"{what} must be an OpenGL version such as 33, 45 or '3.3', "
                                  f"got {value!r}")
    major, minor = (match.group(1), match.group(2)) if match.group(1) else (match.group(3),
                                                                          match.group(4))
    number = 10 * int(major) + int(minor)
    if number < MIN_GL // 10:
        raise ArgumentError(what, f"{what} must be at least {version_text(MIN_GL)} (glraster's "
                                  f"least OpenGL), got {value!r}")
    return number


@dataclass
class Targets:
    """A framebuffer and its attachments for one resolution and one set of outputs.

    ``color`` maps output name ("persp", "screen", "tri_id") to its color attachment
    index; ``depth`` is the DEPTH_COMPONENT32F attachment (texture or renderbuffer).
    ``samples`` > 1: multisample textures (depth too), ``sample_positions`` (S, 2) float64
    as the driver reports them for this framebuffer (GL_SAMPLE_POSITION, pixel units).
    """

    fbo: object
    color: dict
    attachments: list
    depth: object
    samples: int = 1
    sample_positions: np.ndarray | None = None

    def release(self):
        self.fbo.release()
        for attachment in self.attachments:
            attachment.release()
        self.depth.release()


class Context:
    """A headless OpenGL core context: the best of 4.5 and 3.3 the driver makes.

    Parameters
    ----------
    backend : {"auto", "egl", "osmesa"} or None
        "auto" tries EGL, then OSMesa. None (the default) reads ``$GLRASTER_BACKEND``
        ("auto" where it is unset; a bad value raises :class:`~glraster.errors.BadEnvironment`
        naming it).
    max_gl : int or str, optional
        Use no OpenGL feature above this version (33 or "3.3": the GL 3.3 draw path of
        method "hw" even on a 4.5 driver, to test it). None reads ``$GLRASTER_MAX_GL``
        (default: no cap).

    Attributes
    ----------
    backend : str             "egl" or "osmesa", the backend actually in use
    renderer : str            GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
    gl_version : str          GL_VERSION
    gl_version_number : int   the OpenGL version glraster uses, major * 10 + minor (33, 45):
                              the driver's, or ``max_gl`` when that is lower
    driver_gl_version_number : int   the driver's (from GL_VERSION), whatever ``max_gl``
    vendor : str              GL_VENDOR
    max_texture_size : int    largest width or height glraster can render
    subpixel_bits : int       GL_SUBPIXEL_BITS
    mgl : moderngl.Context    the underlying moderngl context; use it inside ``with ctx:``
    released : bool           True after :meth:`release`; then every use raises an
                              ArgumentError naming ``ctx``

    ``with ctx:`` (and every call: rasterize, gl_error, release_targets, release ...) makes
    this context current and afterwards makes current again whatever context was current
    on the thread before, as does construction: a caller's own GL context keeps working.
    A block nested directly in a block of the same context switches nothing.

    Raises :class:`~glraster.errors.BackendUnavailable` (or a subclass: ``LibraryMissing``,
    ``DriverTooOld``, ``BackendCrashed``, ``BadEnvironment``) when no context can be made;
    its message names the library or the environment variable at fault and what to do.
    In a process forked after its parent made a context, making or using one raises
    ``ForkedProcess`` (Mesa's drivers would hang there).
    A context collected without :meth:`release` is released when the next one is made.
    """

    def __init__(self, backend: str | None = None, *, max_gl=None):
        if max_gl is None and os.environ.get("GLRASTER_MAX_GL"):
            try:
                cap = parse_gl_version(os.environ["GLRASTER_MAX_GL"], "GLRASTER_MAX_GL")
            except ValueError as exc:
                raise BadEnvironment(f"{exc}: unset it or correct it",
                                     "GLRASTER_MAX_GL") from None
        else:
            cap = None if max_gl is None else parse_gl_version(max_gl)
        global _gl_process
        _refuse_after_fork()
        _release_dropped()
        self._backend, self.mgl = create_backend(backend)
        _gl_process = _gl_process or os.getpid()
        # a context dropped unreleased is released by the next one made (not by the garbage
        # collector, which may run while another context is current)
        self._dropped = weakref.finalize(self, _dropped.append, (self.mgl, self._backend))
        self._dropped.atexit = False
        self.backend = self._backend.name
        self._lock = threading.RLock()
        self.released = False   # set by release(); a released context does no more GL work
        self._programs: dict = {}
        self._compute: dict = {}
        self._framebuffers: OrderedDict = OrderedDict()
        self._buffers: dict = {}
        self._buffer_sizes: dict = {}   # name -> bytes of self._buffers[name]
        self.uploads = UploadCache()    # which declared array each buffer holds
        self._attribute_arrays: dict = {}  # (program glo, name) -> (buffers..., vao)
        self._gl_functions: dict = {}
        self._sample_counts: tuple | None = None
        self._extensions: frozenset | None = None
        with self:
            info = self.mgl.info
            self.renderer = info["GL_RENDERER"]
            self.gl_version = info["GL_VERSION"]
            self.vendor = info["GL_VENDOR"]
            viewport = info["GL_MAX_VIEWPORT_DIMS"]
            self.max_texture_size = int(
                min(info["GL_MAX_TEXTURE_SIZE"], info["GL_MAX_RENDERBUFFER_SIZE"], *viewport)
            )
            self.subpixel_bits = int(info["GL_SUBPIXEL_BITS"])
            self.driver_gl_version_number = self.mgl.version_code // 10
            self.gl_version_number = min(self.driver_gl_version_number, cap or 99)
            self.max_gl = cap
            # (a GL 3.3 context has no storage blocks: the query is not made there)
            self.max_storage_block_size = int(info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE", 0)) \
                if self.gl_version_number >= STORAGE_GL else 0
            self.mgl.enable(self.mgl.DEPTH_TEST)
            self.mgl.depth_func = "<"
            limits = [int(info.get(name, 0) or 0) for name in SAMPLE_LIMITS]
            self.max_samples = max(1, min(limits))

    def require_gl(self, needed: int, feature: str, why: str = "") -> None:
        """Raise :class:`GLVersionError` (a ValueError) naming ``feature``, the version this
        context offers and ``needed`` (major * 10 + minor; ``why``: what of that version
        the feature uses) when the context is below ``needed``."""
        if self.gl_version_number >= needed:
            return
        offered = f"the driver ({self.renderer}) offers OpenGL " \
            f"{version_text(self.driver_gl_version_number)}"
        if self.gl_version_number < self.driver_gl_version_number:
            offered = (f"this context is capped at OpenGL {version_text(self.gl_version_number)}"
                       f" by max_gl / GLRASTER_MAX_GL ({offered})")
        raise GLVersionError(
            f"{feature} needs OpenGL {version_text(needed)}{f' ({why})' if why else ''}; "
            f"{offered}", feature, self.gl_version_number, needed)

    def gl_function(self, name: str, restype, *argtypes):
        """The OpenGL entry point ``name`` as a ctypes function (cached), for the few calls
        moderngl does not wrap (glGetMultisamplefv). Call it inside ``with ctx:``."""
        function = self._gl_functions.get(name)
        if function is None:
            address = self._backend._loader.load_opengl_function(name)
            if not address:
                raise GLVersionError(f"{name} is missing from the driver ({self.renderer})",
                                     name, self.gl_version_number, self.gl_version_number)
            function = ctypes.CFUNCTYPE(restype, *argtypes)(address)
            self._gl_functions[name] = function
        return function

    @property
    def sample_counts(self) -> tuple[int, ...]:
        """The sample counts glraster can render with here: 1, and each power of two up to
        :attr:`max_samples` for which a framebuffer of float, integer and depth multisample
        textures really has that many samples (GL_SAMPLES; a driver may round a request
        up: llvmpipe offers 4 but not 2). Measured once."""
        if self._sample_counts is None:
            counts = [1]
            k = 2
            while k <= self.max_samples:
                with self:
                    targets = self._new_targets((1, 1), {"f": (3, "f4"), "i": (1, "i4")},
                                                True, k)
                    if targets.samples == k:
                        counts.append(k)
                    # (framebuffer 0 first: see release_targets)
                    self.mgl.detect_framebuffer(0).use()
                    targets.release()
                k *= 2
            self._sample_counts = tuple(counts)
        return self._sample_counts

    @property
    def extensions(self) -> frozenset[str]:
        """The driver's GL extension names (asked once: every accumulating backward asks)."""
        if self._extensions is None:
            with self:
                self._extensions = frozenset(self.mgl.extensions)
        return self._extensions

    @property
    def is_llvmpipe(self) -> bool:
        """True on Mesa's llvmpipe, whose fill rule glraster models exactly."""
        return "llvmpipe" in self.renderer

    # -- making the context current -------------------------------------------------------
    def __enter__(self):
        _refuse_after_fork()
        if self.released:
            raise ArgumentError("ctx", f"{self!r} was released (Context.release()); make a new "
                                       f"glraster.Context")
        self._lock.acquire()
        stack = _entered()
        # directly inside a block of this context: it is current already, nothing to switch
        switch = not stack or stack[-1][0] is not self
        if switch:
            try:
                self.mgl.__enter__()
            except BaseException:
                self._lock.release()
                raise
        stack.append((self, switch))
        return self

    def __exit__(self, *exc):
        try:
            if _entered().pop()[1]:
                self.mgl.__exit__(*exc)
        finally:
            self._lock.release()

    # -- cached GL objects ----------------------------------------------------------------
    def program(self, vert: Path, frag: Path, defines: dict):
        """The linked program for two shader files and a set of defines (cached)."""
        key = (str(vert), str(frag), tuple(sorted(defines.items())))
        program = self._programs.get(key)
        if program is None:
            program = compile_program(self.mgl, vert, frag, defines)
            vao = self.mgl.vertex_array(program, [])
            self._programs[key] = program = (program, vao)
        return program

    def compute_program(self, path: Path, defines: dict):
        """The compute shader of one GLSL file and a set of defines (cached); a compile
        error is a :class:`ShaderCompileError` naming the file and line."""
        key = (str(path), tuple(sorted(defines.items())))
        program = self._compute.get(key)
        if program is None:
            self.require_gl(GLSL450_GL, f"the compute shader {Path(path).name}",
                            "compute shaders, GLSL 4.50")
            program = compile_compute(self.mgl, path, defines)
            self._compute[key] = program
        return program

    def targets(self, resolution: tuple[int, int], color_formats: dict, depth_texture: bool,
                samples: int = 1, slot: int = 0):
        """Framebuffer of ``resolution`` (H, W) with one color attachment per entry of
        ``color_formats`` (name -> (components, dtype)) and a float32 depth attachment
        (a texture when it is read back, else a renderbuffer; always a texture when
        ``samples`` > 1, multisample textures then). Least recently used first out.
        ``slot`` < FRAMEBUFFER_SLOTS: distinct slots are distinct framebuffers.
        """
        key = (resolution, tuple(color_formats.items()), depth_texture, samples, slot)
        targets = self._framebuffers.pop(key, None)
        if targets is None:
            targets = self._new_targets(resolution, color_formats, depth_texture, samples)
            while len(self._framebuffers) >= FRAMEBUFFER_CACHE_SIZE:
                self._framebuffers.popitem(last=False)[1].release()
        self._framebuffers[key] = targets
        return targets

    def _new_targets(self, resolution, color_formats: dict, depth_texture: bool,
                     samples: int = 1) -> Targets:
        """Allocate the framebuffer of :meth:`targets`; a size the driver cannot allocate
        is a ValueError naming the resolution (nothing is left allocated)."""
        height, width = resolution
        attachments, color, depth = [], {}, None
        try:
            for name, (components, dtype) in color_formats.items():
                color[name] = len(attachments)
                attachments.append(self.mgl.texture((width, height), components, dtype=dtype,
                                                    samples=samples if samples > 1 else 0))
            if samples > 1:
                depth = self.mgl.depth_texture((width, height), samples=samples)
            elif depth_texture:
                depth = self.mgl.depth_texture((width, height))
            else:
                depth = self.mgl.depth_renderbuffer((width, height))
            refused = self.mgl.error
            if refused != "GL_NO_ERROR":
                raise moderngl.Error(refused)
            fbo = self.mgl.framebuffer(color_attachments=attachments, depth_attachment=depth)
        except moderngl.Error as exc:
            for obj in attachments + ([depth] if depth is not None else []):
                obj.release()
            biggest = max([4 * c for c, _ in color_formats.values()] + [4])
            raise ArgumentError(
                "resolution",
                f"resolution {height}x{width}: the driver cannot allocate the render targets "
                f"({', '.join(color_formats)}, depth): {exc}. The largest holds "
                f"{biggest * height * width / 2**30:.2f} GiB or more; llvmpipe refuses a texture "
                "over 1.5 GiB (a 10032x10032 RGBA32F one is its largest square). Request "
                "fewer outputs or a smaller resolution.") from None
        targets = Targets(fbo, color, attachments, depth)
        if samples > 1:
            targets.samples, targets.sample_positions = self._query_samples(fbo)
        return targets

    def _query_samples(self, fbo) -> tuple[int, np.ndarray]:
        """(GL_SAMPLES, (S, 2) GL_SAMPLE_POSITION of each sample) of a multisample
        framebuffer, as the driver reports them (GL 4.5 section 14.3.1.1)."""
        get_integer = self.gl_function("glGetIntegerv", None, ctypes.c_uint,
                                       ctypes.POINTER(ctypes.c_int))
        get_position = self.gl_function("glGetMultisamplefv", None, ctypes.c_uint,
                                        ctypes.c_uint, ctypes.POINTER(ctypes.c_float))
        fbo.use()
        count = ctypes.c_int(0)
        get_integer(GL_SAMPLES, ctypes.byref(count))
        positions = np.zeros((count.value, 2), np.float64)
        value = (ctypes.c_float * 2)()
        for k in range(count.value):
            get_position(GL_SAMPLE_POSITION, k, value)
            positions[k] = value[0], value[1]
        return count.value, positions

    def storage_buffer(self, name: str, data):
        """A buffer holding ``data`` (a C-contiguous array) for shaders to read, reused
        between calls under ``name``; grows by doubling when needed. Data a front end
        declared (:mod:`glraster.gpu.uploads`) that a buffer of this context holds already
        is not written again: that buffer is returned (it may be another name's)."""
        uploads = self.uploads
        if isinstance(data, np.ndarray):
            entry, nbytes = uploads.lookup(data), data.nbytes
            if entry is not None:
                held = uploads.held(entry)
                if held is not None:
                    return self._buffers[held]
        else:
            entry, data = None, memoryview(data).cast("B")
            nbytes = data.nbytes
        buffer = self._buffer(name, nbytes)
        if nbytes:
            buffer.write(data)
        uploads.wrote(name, entry)
        return buffer

    def scratch_buffer(self, name: str, nbytes: int):
        """A buffer of at least ``nbytes`` with undefined contents (for shader output),
        reused between calls under ``name``; grows by doubling when needed."""
        self.uploads.forget(name)
        return self._buffer(name, nbytes)

    def _buffer(self, name: str, nbytes: int):
        buffer = self._buffers.get(name)
        if buffer is None or self._buffer_sizes[name] < nbytes:
            if buffer is not None:
                buffer.release()
            size = 1 << (max(int(nbytes), 16) - 1).bit_length()
            buffer = self._buffers[name] = self.mgl.buffer(reserve=size, dynamic=True)
            self._buffer_sizes[name] = size
        return buffer

    def attribute_array(self, program, name: str, corners):
        """A vertex array feeding ``program`` the vertex attributes ``a_position`` =
        ``corners`` ((N, 4) float32, C-contiguous; in :meth:`storage_buffer` ``name``) and
        ``a_vertex`` = 0, 1, ..., N - 1 (int32, a buffer shared by every draw, written only
        when it grows). The vertex array is cached per program and buffer name and remade
        only when a buffer grows."""
        count = len(corners)
        positions = self.storage_buffer(name, corners)
        numbers = self._buffers.get("vertex_numbers")
        if numbers is None or numbers.size < 4 * count:
            size = max(1 << (4 * count - 1).bit_length(), 1 << 15)  # 8k vertices or more
            numbers = self.storage_buffer("vertex_numbers", np.arange(size // 4, dtype=np.int32))
        key = (program.glo, name)
        cached = self._attribute_arrays.get(key)
        if cached is None or cached[0] is not positions or cached[1] is not numbers:
            if cached is not None:
                cached[2].release()
            vao = self.mgl.vertex_array(
                program, [(positions, "4f", "a_position"), (numbers, "1i", "a_vertex")],
                skip_errors=True)  # a_vertex is optimized out when no output needs it
            self._attribute_arrays[key] = cached = (positions, numbers, vao)
        return cached[2]

    def gl_error(self) -> str:
        """The pending GL error ("GL_NO_ERROR" when there is none); reading clears it."""
        with self:
            return self.mgl.error

    def release_targets(self):
        """Free the cached framebuffers (e.g. after rendering a few very large frames: each
        keeps its float targets, up to several GiB, until four other sizes push it out)."""
        with self:
            # Bind framebuffer 0 first: moderngl rebinds the framebuffer it last used after
            # creating the next one, and binding a deleted name is GL_INVALID_OPERATION.
            self.mgl.detect_framebuffer(0).use()
            for targets in self._framebuffers.values():
                targets.release()
        self._framebuffers.clear()

    def cached_object_count(self) -> int:
        """Number of GL objects held in the caches (for leak tests)."""
        return (
            len(self._programs) + len(self._compute) + len(self._buffers)
            + len(self._attribute_arrays)
            + sum(2 + len(t.attachments) for t in self._framebuffers.values())
        )

    def release(self):
        """Release every GL object and the context itself (once: a second call does
        nothing). The default context (:func:`default_context`) is made anew after it."""
        if self.released:
            return
        self._dropped.detach()
        with self:
            for program, vao in self._programs.values():
                vao.release()
                program.release()
            for program in self._compute.values():
                program.release()
            for *_, vao in self._attribute_arrays.values():
                vao.release()
            for targets in self._framebuffers.values():
                targets.release()
            for buffer in self._buffers.values():
                buffer.release()
        self._programs.clear()
        self._compute.clear()
        self._attribute_arrays.clear()
        self._framebuffers.clear()
        self._buffers.clear()
        self._buffer_sizes.clear()
        self.uploads.clear()
        self.mgl.release()
        self._backend.release()
        self.released = True

    def __repr__(self):
        return f"glraster.Context(backend={self.backend!r}, renderer={self.renderer!r})"


_tls = threading.local()


def _entered() -> list:
    """This thread's open ``with`` blocks of Contexts: (context, switched) pairs."""
    stack = getattr(_tls, "stack", None)
    if stack is None:
        stack = _tls.stack = []
    return stack


_default_context: Context | None = None
_default_lock = threading.Lock()
_gl_process: int | None = None   # the pid of the process that made the first context


_dropped: list = []   # (moderngl context, backend) of contexts collected unreleased


def _release_dropped() -> None:
    """Release the GL contexts of Context objects collected without release(), when no
    glraster context is current on this thread (destroying a context frees its objects)."""
    while _dropped and not _entered():
        mgl, backend = _dropped.pop()
        mgl.release()
        backend.release()


def _refuse_after_fork() -> None:
    """ForkedProcess in a child forked after its parent made a context (which would hang)."""
    if _gl_process is not None and _gl_process != os.getpid():
        raise ForkedProcess(_gl_process)


def default_context() -> Context:
    """The process-wide context, made on first use (backend from ``$GLRASTER_BACKEND``)."""
    global _default_context
    with _default_lock:
        if _default_context is None or _default_context.released:
            _default_context = Context(backend=None)
        return _default_context


def context_or_default(ctx) -> Context:
    """``ctx`` when it is a :class:`Context`, the process-wide one (:func:`default_context`)
    when it is None; ArgumentError naming ``ctx`` for anything else (a backend name, say:
    ``Context(backend="egl")`` makes a context)."""
    if ctx is None:
        return default_context()
    if not isinstance(ctx, Context):
        raise ArgumentError("ctx", f"ctx must be a glraster.Context or None, got "
                                   f"{type(ctx).__name__} {ctx!r:.60}")
    return ctx
