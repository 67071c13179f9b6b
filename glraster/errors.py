"""Exceptions raised by glraster."""


class BackendUnavailable(RuntimeError):
    """No headless OpenGL context could be created with the requested backend."""


class ShaderCompileError(RuntimeError):
    """A GLSL file failed to compile or link; the message names the file and line."""


class GLError(RuntimeError):
    """OpenGL reported an error (``glGetError``) during an operation; the message names the
    error and the operation."""

    def __init__(self, error: str, during: str):
        super().__init__(f"OpenGL reported {error} while {during}")
        self.error = error
        self.during = during
