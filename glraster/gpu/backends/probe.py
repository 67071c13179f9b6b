"""Creating a backend's first context in a subprocess, so a crashing driver cannot kill us.

Some driver libraries do not fail, they crash: with ``GALLIUM_DRIVER=nosuchdriver`` (or
``llvmpip``, ``zink``) Mesa 22.3's ``OSMesaCreateContextAttribs`` dies of SIGSEGV, and with
``GALLIUM_DRIVER=virpipe`` and no virgl server EGL aborts (SIGABRT). Before a backend makes
its first context in this process, :func:`verdict` runs :func:`main` in a child
Python process, which creates the backend's context, reads GL_VERSION and GL_RENDERER and
reports what happened. A crash kills only the child; the
parent raises :class:`~glraster.errors.BackendCrashed` naming the signal, the driver
variables that are set and Mesa's own last words (the child's stderr).

Verdicts are cached per environment: the driver variables
(:func:`~glraster.gpu.backends.environment.environment_key`), the device nodes under
/dev/dri, the Python interpreter and glraster's backend code.

* In memory, per process: every verdict (a second Context() costs a dictionary look-up).
* On disk, ``$XDG_CACHE_HOME/glraster/backend-probe/`` (``~/.cache/...``; the newest 64):
  verdicts that a context *can* be made, each with the driver library files the child had loaded
  (path, size, modification time); one whose files changed is probed again. A failure is
  never stored on disk, so fixing the environment takes effect at once. Where the folder
  cannot be written, memory alone is used.

Cost, measured with ``glraster study backend-probe`` (docs/drivers.md has the
figures): the probe is one Python start plus one context creation, paid by the first
Context() of an environment on this machine and then read from disk.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from glraster.errors import BackendCrashed, BackendUnavailable, DriverTooOld, LibraryMissing
from glraster.gpu.backends.environment import dri_devices, environment_key

# How long a child may take (a first llvmpipe context takes about 0.3 s; a driver that
# waits for a device that never answers must not hang the caller).
PROBE_TIMEOUT_S = 60.0
MARKER = "glraster-probe-verdict "
# The child's program (argv: package folder, backend). It registers glraster as a bare
# package, so that importing the backends skips glraster/__init__.py (NumPy and the
# geometry layer: 0.3 s of the child's 0.6 s).
CHILD = ("import sys, types; package = types.ModuleType('glraster'); "
         "package.__path__ = [sys.argv.pop(1)]; sys.modules['glraster'] = package; "
         "from glraster.gpu.backends.probe import main; sys.exit(main())")
# Mesa's messages kept in an error: distinct lines, each shortened.
MESA_LINES = 3
MESA_LINE_CHARS = 160
# Libraries whose files the child had loaded, recorded with a disk verdict.
LIBRARY_PATTERN = re.compile(r"(libEGL|libOSMesa|libGLX|libGLdispatch|libglapi|libgallium"
                             r"|_dri\.so|libLLVM|libvulkan|libGL\.so)")
# Verdicts kept on disk (the newest).
DISK_VERDICTS = 64
ERRORS = {cls.__name__: cls for cls in (BackendUnavailable, LibraryMissing, DriverTooOld)}

_verdicts: dict = {}
_lock = threading.Lock()


def cache_folder() -> Path:
    """Where verdicts that a context can be made are kept between processes."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "glraster" / "backend-probe"


def _code_stamp() -> list:
    """(name, size, mtime) of the backend modules: new code gets new verdicts."""
    here = Path(__file__).parent
    stamps = []
    for path in sorted(here.glob("*.py")):
        stat = path.stat()
        stamps.append((path.name, stat.st_size, stat.st_mtime_ns))
    return stamps


def memory_key(backend: str) -> tuple:
    """What ``backend``'s verdict in this process depends on: the driver variables and the
    device nodes (a GPU that appears)."""
    return backend, environment_key(), tuple(dri_devices())


def disk_key(key: tuple) -> str:
    """The file name (hex digest) of a verdict on disk: :func:`memory_key`'s ``key``, the
    Python interpreter and the backend code's files."""
    material = json.dumps([key, sys.executable, _code_stamp()])
    return hashlib.sha256(material.encode()).hexdigest()[:32]


def _files_unchanged(libraries) -> bool:
    for path, size, mtime in libraries:
        try:
            stat = os.stat(path)
        except OSError:
            return False
        if (stat.st_size, stat.st_mtime_ns) != (size, mtime):
            return False
    return True


def _read_disk(key: str) -> dict | None:
    try:
        verdict = json.loads((cache_folder() / f"{key}.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(verdict, dict) or verdict.get("ok") is not True:
        return None
    return verdict if _files_unchanged(verdict.get("libraries", [])) else None


def _write_disk(key: str, verdict: dict) -> None:
    """Store a working verdict; the oldest beyond :data:`DISK_VERDICTS` are removed (every
    change of environment or of glraster's backend code adds one)."""
    from glraster.io.atomic import atomic_write

    folder = cache_folder()
    try:
        with atomic_write(folder / f"{key}.json") as tmp:
            Path(tmp).write_text(json.dumps(verdict))
        stored = sorted(folder.glob("*.json"), key=lambda f: f.stat().st_mtime_ns)
        for old in stored[:-DISK_VERDICTS]:
            old.unlink(missing_ok=True)
    except OSError:
        pass  # a read-only home (the verdict stays in memory), or a race with another process


def verdict(backend: str) -> dict:
    """What creating ``backend``'s context does in this environment: a dict with ``ok``
    (bool) and, on success, ``renderer``, ``gl_version``; on failure ``error`` (the class
    name), ``message``, ``offered``/``needed`` (DriverTooOld), ``signal`` (a crash) and
    ``mesa`` (the child's last distinct stderr lines). Probes at most once per process and
    environment (see the module docstring for the disk cache)."""
    key = memory_key(backend)
    with _lock:
        found = _verdicts.get(key)
        if found is None:
            name = disk_key(key)
            found = _read_disk(name)
            if found is None:
                found = run_probe(backend)
                if found["ok"] and "unprobed" not in found:
                    _write_disk(name, found)
            _verdicts[key] = found
        return found


def require(backend: str) -> dict:
    """:func:`verdict`, raising the error it reports (a :class:`BackendUnavailable`)."""
    found = verdict(backend)
    if not found["ok"]:
        raise error_from(backend, found)
    return found


def error_from(backend: str, found: dict) -> BackendUnavailable:
    """The exception a failed verdict stands for, with Mesa's lines appended."""
    message = found["message"]
    if found.get("mesa"):
        message += "; Mesa said: " + " | ".join(found["mesa"])
    if found.get("signal"):
        return BackendCrashed(message, backend, found["signal"])
    cls = ERRORS.get(found.get("error"), BackendUnavailable)
    if cls is DriverTooOld:
        return DriverTooOld(message, found.get("offered"), found.get("needed", "3.3"))
    return cls(message)


def _mesa_lines(stderr: str) -> list[str]:
    lines = []
    for line in stderr.splitlines():
        line = line.strip()
        if line and line not in lines and not line.startswith(("Traceback", "File ")):
            lines.append(line if len(line) <= MESA_LINE_CHARS
                         else line[:MESA_LINE_CHARS - 3] + "...")
    return lines[-MESA_LINES:]


def run_probe(backend: str) -> dict:
    """Run the child for ``backend`` now (no cache) and return its verdict.

    Where ``sys.executable`` is not a Python interpreter (Python embedded in another
    program) no child can be started: the verdict is ``ok`` with ``unprobed`` saying why,
    and the context is made in this process as it was before probes existed."""
    interpreter = os.path.basename(sys.executable or "").lower()
    if "python" not in interpreter and "pypy" not in interpreter:
        return {"ok": True, "unprobed": f"sys.executable {sys.executable!r} is not a Python "
                                        "interpreter"}
    library = {"egl": "libEGL", "osmesa": "libOSMesa"}.get(backend, backend)
    try:
        package = str(Path(__file__).resolve().parents[2])
        # (no Python fault handler: its report of a crash is not Mesa's words)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONFAULTHANDLER"}
        proc = subprocess.run([sys.executable, "-c", CHILD, package, backend],
                              stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              errors="replace", env=env, timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": "BackendUnavailable",
                "message": f"{backend}: creating a context did not finish in "
                           f"{PROBE_TIMEOUT_S:g} s (a driver waiting for a device?)"}
    except OSError as exc:
        return {"ok": False, "error": "BackendUnavailable",
                "message": f"{backend}: the probe process could not start: {exc}"}
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(MARKER):
            found = json.loads(line[len(MARKER):])
            if not found["ok"]:
                found["mesa"] = _mesa_lines(proc.stderr)
            return found
    mesa = _mesa_lines(proc.stderr)
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        return {"ok": False, "error": "BackendCrashed", "signal": name, "mesa": mesa,
                "message": f"{library} crashed ({name}) creating a context "
                           "(in a probe process; this one is unharmed)"}
    return {"ok": False, "error": "BackendUnavailable", "mesa": mesa,
            "message": f"{backend}: the probe process ended with exit status "
                       f"{proc.returncode} and no verdict"}


def _loaded_libraries() -> list:
    """(path, size, mtime) of the driver libraries this process has mapped."""
    paths = set()
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.split(maxsplit=5)[-1].strip() if line.count(" ") >= 5 else ""
                if path.startswith("/") and LIBRARY_PATTERN.search(path):
                    paths.add(path)
    except OSError:
        return []
    files = []
    for path in sorted(paths):
        try:
            stat = os.stat(path)
        except OSError:
            continue
        files.append((path, stat.st_size, stat.st_mtime_ns))
    return files


def child(backend: str) -> dict:
    """In the probe process: create ``backend``'s context and describe the outcome."""
    from glraster.gpu.backends import BACKENDS

    instance = BACKENDS[backend]()
    try:
        mgl = instance.create()
    except BackendUnavailable as exc:
        found = {"ok": False, "error": type(exc).__name__, "message": str(exc)}
        if isinstance(exc, DriverTooOld):
            found.update(offered=exc.offered, needed=exc.needed)
        return found
    except Exception as exc:  # noqa: BLE001 - a broken library raises anything
        return {"ok": False, "error": "BackendUnavailable",
                "message": f"{backend}: {type(exc).__name__}: {exc}"}
    try:
        with mgl:
            info = mgl.info
            found = {"ok": True, "renderer": info["GL_RENDERER"],
                     "gl_version": info["GL_VERSION"], "libraries": _loaded_libraries()}
    finally:
        mgl.release()
        instance.release()
    return found


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    print(MARKER + json.dumps(child(argv[0])), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
