"""Record the OpenGL calls of a block of code, then replay them bare: the floor of its GL work.

A :class:`Recorder` patches the moderngl methods through which glraster talks to the
driver (buffer uploads, clears, bindings and readbacks; compute dispatches and memory
barriers; framebuffer use, clear and readback; draws; texture uploads and bindings to
texture and image units; uniform writes; enable/disable) for as long as it is active, and
appends every call, with the very objects and arguments it got, to the current *segment*
(named with :meth:`Recorder.segment`; calls outside any segment go to ``"(outside)"``).

:meth:`Trace.replay` runs a segment's calls again without anything around them: no
Python wrappers, no validation, no allocation, the same programs and buffers (compiled
and allocated by the recorded run), the same dispatch sizes, draws and readbacks. Uploads
(``Buffer.write``, ``Texture.write``) are replayed first and outside the timing: the
floor assumes its inputs are on the GPU already. Readbacks go into arrays allocated once
per replay (``Buffer.read`` becomes ``Buffer.read_into`` a preallocated bytearray).

Limits: a replay is valid while the recorded buffers and programs live; the context's
buffer cache releases a buffer when it grows, so record and replay in the same state
(record right before replaying). Uploads inside a segment all happen before its
dispatches: a segment that uploads the same buffer twice (several pixel chunks) is
replayed on its last contents, which changes only data-dependent timing.
"""

from __future__ import annotations

import functools
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import moderngl

__all__ = ["Call", "Recorder", "Trace"]

# (class, method, kind): "upload" calls are replayed untimed before the others
_PATCHED = (
    (moderngl.Buffer, "write", "upload"),
    (moderngl.Buffer, "read", "readback"),
    (moderngl.Buffer, "read_into", "readback"),
    (moderngl.Buffer, "clear", "gl"),
    (moderngl.Buffer, "bind_to_storage_buffer", "gl"),
    (moderngl.ComputeShader, "run", "gl"),
    (moderngl.Context, "memory_barrier", "gl"),
    (moderngl.Context, "enable", "gl"),
    (moderngl.Context, "disable", "gl"),
    (moderngl.Framebuffer, "use", "gl"),
    (moderngl.Framebuffer, "clear", "gl"),
    (moderngl.Framebuffer, "read", "readback"),
    (moderngl.Framebuffer, "read_into", "readback"),
    (moderngl.VertexArray, "render", "gl"),
    (moderngl.Texture, "use", "gl"),
    (moderngl.Texture, "bind_to_image", "gl"),
    (moderngl.Texture, "write", "upload"),
)


@dataclass
class Call:
    """One recorded call: ``function(target, *args, **kwargs)`` (the unpatched method)."""

    kind: str
    function: object
    target: object
    args: tuple
    kwargs: dict


@dataclass
class Trace:
    """Recorded calls per segment, in order: ``segments`` is a list of (name, [Call])."""

    segments: list = field(default_factory=list)

    def names(self) -> list[str]:
        """The segment names, first appearance order, without repeats."""
        return list(dict.fromkeys(name for name, _ in self.segments))

    def counts(self) -> dict[str, int]:
        """name -> how many calls of the op (segments opened by name, continuations not
        counted)."""
        out: dict[str, int] = {}
        for name, calls in self.segments:
            if calls and calls[0] is _OPENED:
                out[name] = out.get(name, 0) + 1
        return out

    def replay(self, ctx, only: str | None = None) -> dict[str, float]:
        """Replay every segment (or those named ``only``) once: name -> seconds of its GL
        work (dispatches, draws, clears, bindings and readbacks, ending with glFinish),
        summed over the segments of that name. Uploads run first, untimed."""
        out: dict[str, float] = {}
        with ctx:
            mgl = ctx.mgl
            for name, calls in self.segments:
                if only is not None and name != only:
                    continue
                work = [_bare(c) for c in calls if c is not _OPENED and c.kind != "upload"]
                for c in calls:
                    if c is not _OPENED and c.kind == "upload":
                        c.function(c.target, *c.args, **c.kwargs)
                mgl.finish()
                start = time.perf_counter()
                for function, target, args, kwargs in work:
                    function(target, *args, **kwargs)
                mgl.finish()
                out[name] = out.get(name, 0.0) + time.perf_counter() - start
        return out


_OPENED = object()   # first element of a segment opened by Recorder.segment


def _bare(call: Call):
    """(function, target, args, kwargs) to replay ``call``; a Buffer.read becomes a
    read_into a bytearray allocated here, once."""
    if call.function is _ORIGINAL[(moderngl.Buffer, "read")]:
        size = call.kwargs.get("size", call.args[0] if call.args else -1)
        offset = call.kwargs.get("offset", call.args[1] if len(call.args) > 1 else 0)
        nbytes = call.target.size - offset if size < 0 else size
        return (_ORIGINAL[(moderngl.Buffer, "read_into")], call.target,
                (bytearray(nbytes),), {"size": nbytes, "offset": offset})
    return call.function, call.target, call.args, call.kwargs


_ORIGINAL = {(cls, name): getattr(cls, name) for cls, name, _ in _PATCHED}
_UNIFORM_VALUE = moderngl.Uniform.value


class Recorder:
    """Records moderngl calls while active (``with recorder:``); not reentrant, one at a
    time per process. ``recorder.trace`` holds what was recorded."""

    _active: "Recorder | None" = None

    def __init__(self):
        self.trace = Trace()
        self._stack = ["(outside)"]
        self._current: list | None = None

    # -- segments
    @property
    def current(self) -> str:
        """The name of the innermost open segment ("(outside)" when none is)."""
        return self._stack[-1]

    @contextmanager
    def segment(self, name: str):
        """Calls inside go to a new segment ``name`` (nested segments split their parent:
        its calls after the nested one go to a continuation of the same name)."""
        self._stack.append(name)
        self._current = [_OPENED]
        self.trace.segments.append((name, self._current))
        try:
            yield
        finally:
            self._stack.pop()
            self._current = None

    def _append(self, call: Call) -> None:
        if self._current is None:
            self._current = []
            self.trace.segments.append((self._stack[-1], self._current))
        self._current.append(call)

    # -- patching
    def __enter__(self):
        if Recorder._active is not None:
            raise RuntimeError("a gl_trace.Recorder is active already")
        Recorder._active = self
        for cls, name, kind in _PATCHED:
            setattr(cls, name, _recording(_ORIGINAL[(cls, name)], kind))
        setter = _UNIFORM_VALUE.fset

        def set_value(uniform, value):
            setter(uniform, value)
            rec = Recorder._active
            if rec is not None:
                rec._append(Call("gl", setter, uniform, (value,), {}))

        moderngl.Uniform.value = property(_UNIFORM_VALUE.fget, set_value)
        return self

    def __exit__(self, *exc):
        for cls, name, _ in _PATCHED:
            setattr(cls, name, _ORIGINAL[(cls, name)])
        moderngl.Uniform.value = _UNIFORM_VALUE
        Recorder._active = None


def _recording(function, kind: str):
    @functools.wraps(function)
    def wrapper(self, *args, **kwargs):
        result = function(self, *args, **kwargs)
        rec = Recorder._active
        if rec is not None:
            rec._append(Call(kind, function, self, args, kwargs))
        return result
    return wrapper
