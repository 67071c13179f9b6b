"""Exceptions raised by glraster."""


class BackendUnavailable(RuntimeError):
    """No headless OpenGL context could be created with the requested backend."""


class ShaderCompileError(RuntimeError):
    """A GLSL file failed to compile or link; the message names the file and line."""
