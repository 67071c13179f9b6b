"""Exceptions raised by glraster."""


class BackendUnavailable(RuntimeError):
    """No headless OpenGL context could be created with the requested backend."""


class LibraryMissing(BackendUnavailable):
    """The backend's library (libEGL, libOSMesa) is not installed: an install hint helps."""


class BadEnvironment(BackendUnavailable, ValueError):
    """An environment variable that glraster reads has a value it cannot use.

    ``variable`` names it (``GLRASTER_BACKEND``, ``GLRASTER_MAX_GL``); the message says the
    value and the accepted ones. Both a :class:`BackendUnavailable` (no context can be made
    in this environment: ``glraster`` exits 3) and a ValueError (a bad value).
    """

    def __init__(self, message: str, variable: str):
        super().__init__(message)
        self.variable = variable


class BackendCrashed(BackendUnavailable):
    """Creating a context killed the probe process (a signal inside the driver library).

    glraster creates each backend's first context of an environment in a subprocess
    (:mod:`glraster.gpu.backends.probe`), so a driver that crashes takes down that process
    only. ``signal`` is the signal's name ("SIGSEGV"), ``backend`` the backend's.
    """

    def __init__(self, message: str, backend: str, signal: str):
        super().__init__(message)
        self.backend = backend
        self.signal = signal


class DriverTooOld(BackendUnavailable):
    """The driver makes OpenGL contexts, but none of the version glraster needs.

    ``offered`` is the driver's best OpenGL version as text ("3.1") or None when even that
    could not be read; ``needed`` the version glraster asked for ("3.3").
    """

    def __init__(self, message: str, offered: str | None = None, needed: str = "3.3"):
        super().__init__(message)
        self.offered = offered
        self.needed = needed


class ForkedProcess(BackendUnavailable):
    """This process was forked from one that had set up OpenGL: Mesa's drivers do not render
    in such a child (the threads they started in the parent are not in it; they wait for
    them for ever), so glraster refuses here instead of hanging. ``parent`` is the pid of
    the process that set OpenGL up."""

    def __init__(self, parent: int):
        super().__init__(
            f"OpenGL was set up in process {parent} before this process was forked from it, "
            f"and Mesa's drivers cannot render in a forked child: start workers with the "
            f"'spawn' or 'forkserver' method (multiprocessing.get_context('spawn'), "
            f"DataLoader(multiprocessing_context='spawn')), or make the first glraster "
            f"context only in the workers")
        self.parent = parent

    def __reduce__(self):   # (pickled as its pid: a worker pool sends it to the parent)
        return ForkedProcess, (self.parent,)


class GLVersionError(ValueError):
    """A feature needs a newer OpenGL than the context offers; the message names the
    feature, the version the context offers and the one needed."""

    def __init__(self, message: str, feature: str, offered: int, needed: int):
        super().__init__(message)
        self.feature = feature
        self.offered = offered
        self.needed = needed


class ShaderCompileError(RuntimeError):
    """A GLSL file failed to compile or link; the message names the file and line."""


class GLError(RuntimeError):
    """OpenGL reported an error (``glGetError``) during an operation; the message names the
    error and the operation."""

    def __init__(self, error: str, during: str):
        super().__init__(f"OpenGL reported {error} while {during}")
        self.error = error
        self.during = during


class ArgumentError(ValueError):
    """Bad user input: ``.argument`` names the argument (or request field) that was wrong,
    and the message says what was wrong with it. Front ends, the service and the CLI read
    ``.argument``, never the message's wording."""

    def __init__(self, argument: str, message: str):
        super().__init__(message)
        self.argument = argument


# The pip extra (pyproject.toml, optional-dependencies) that installs each optional
# top-level module glraster imports.
EXTRA_OF_MODULE = {"torch": "torch", "jax": "jax", "jaxlib": "jax", "optax": "jax",
                   "ray": "ray", "trimesh": "mesh", "pyrender": "mesh",
                   "starlette": "service", "uvicorn": "service", "httptools": "service",
                   "uvloop": "service", "msgspec": "service", "prometheus_client": "service"}


def needs_extra(user: str, exc: ModuleNotFoundError) -> ModuleNotFoundError:
    """A ModuleNotFoundError for ``user`` (a module or command of glraster) saying which
    pip extra installs the module ``exc`` found missing (by its top-level package);
    ``exc`` itself when no extra does. ``.name`` stays the missing module's."""
    extra = EXTRA_OF_MODULE.get((exc.name or "").split(".")[0])
    if extra is None:
        return exc
    return ModuleNotFoundError(f"{user} needs {exc.name}: pip install 'glraster[{extra}]'",
                               name=exc.name)


def require_extra(module: str, user: str) -> None:
    """Import ``module`` for ``user`` (a front end of glraster), or raise
    :func:`needs_extra`'s error naming the pip extra that installs it."""
    import importlib

    try:
        importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise needs_extra(user, exc) from None
