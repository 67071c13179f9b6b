"""A hostile environment gives an error naming the variable or library, never a signal.

Each bad value runs through the CLI (``glraster info``, exit 3) and through the API
(``glraster.Context()`` in a fresh interpreter: a glraster error class, no crash), in
subprocesses because Mesa reads its variables when it loads. Values Mesa tolerates
(it ignores them or falls back) must keep working.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from glraster.cli import exit_codes

REPO = Path(__file__).resolve().parents[2]

# The variables these tests set, removed from the inherited environment first (the test
# suite's own GLRASTER_BACKEND among them).
CONTROLLED = ("GALLIUM_DRIVER", "MESA_LOADER_DRIVER_OVERRIDE", "LIBGL_ALWAYS_SOFTWARE",
              "MESA_GL_VERSION_OVERRIDE", "MESA_GLSL_VERSION_OVERRIDE", "GLRASTER_BACKEND",
              "GLRASTER_MAX_GL", "GLCONTEXT_DEVICE_INDEX", "LD_LIBRARY_PATH")

API_SCRIPT = """
import glraster as gr
try:
    ctx = gr.Context()
except gr.BackendUnavailable as exc:
    print("ERROR", type(exc).__name__, exc)
else:
    print("OK", ctx.backend, ctx.renderer)
"""

# (variables, words the error must contain); every error also names the first variable.
FAILING = {
    "nosuchdriver": ({"GALLIUM_DRIVER": "nosuchdriver"}, ["no Gallium driver 'nosuchdriver'",
                                                          "llvmpipe or softpipe"]),
    "typo": ({"GALLIUM_DRIVER": "llvmpip"}, ["did you mean 'llvmpipe'?"]),
    "zink": ({"GALLIUM_DRIVER": "zink"}, ["OSMesa cannot run zink"]),
    "virpipe": ({"GALLIUM_DRIVER": "virpipe"}, ["'virpipe' needs its GPU or host"]),
    "gl_2.1": ({"MESA_GL_VERSION_OVERRIDE": "2.1"}, ["offers OpenGL 2.1",
                                                     "below the OpenGL 3.3 glraster needs"]),
    "glsl_110": ({"MESA_GLSL_VERSION_OVERRIDE": "110"}, ["no OpenGL 3.3 core context",
                                                         "need GLSL 3.30"]),
    "backend": ({"GLRASTER_BACKEND": "vulkan"}, ["backend must be one of 'auto', 'egl', "
                                                 "'osmesa', got 'vulkan'"]),
    "max_gl": ({"GLRASTER_MAX_GL": "2.0"}, ["must be at least 3.3"]),
    "device": ({"GLCONTEXT_DEVICE_INDEX": "7", "GLRASTER_BACKEND": "egl"},
               ["requested device index 7"]),
}

# Values Mesa accepts or ignores: a context is made (the variable is listed by info).
WORKING = {
    "loader_unknown": {"MESA_LOADER_DRIVER_OVERRIDE": "nosuchdriver"},
    "always_software_garbage": {"LIBGL_ALWAYS_SOFTWARE": "garbage"},
    "gl_version_garbage": {"MESA_GL_VERSION_OVERRIDE": "garbage"},
}


@pytest.fixture(scope="module")
def cache_home(tmp_path_factory):
    """One verdict cache for this module's subprocesses (not the user's ~/.cache)."""
    return str(tmp_path_factory.mktemp("xdg-cache"))


def environment(cache_home, variables, **extra):
    env = {k: v for k, v in os.environ.items() if k not in CONTROLLED}
    env.update(variables, XDG_CACHE_HOME=cache_home, **extra)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return env


def glraster(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "glraster.cli", *args], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def api(env):
    return subprocess.run([sys.executable, "-c", API_SCRIPT], env=env, capture_output=True,
                          text=True, timeout=300)


def assert_clear(text, variables, words):
    name, value = next(iter(variables.items()))
    assert name in text and repr(value) in text, text
    for word in words:
        assert word in text, text
    assert "apt-get" not in text, "the libraries are installed: no install hint"


@pytest.mark.gl
@pytest.mark.parametrize("case", list(FAILING))
def test_bad_driver_environment_is_exit_3_and_an_error_naming_the_variable(cache_home, case):
    variables, words = FAILING[case]
    env = environment(cache_home, variables)
    cli = glraster(env, "info")
    assert cli.returncode == exit_codes.NO_BACKEND, (cli.returncode, cli.stderr)
    # one line: Mesa's own warnings went to the probe process, not to this one
    assert len(cli.stderr.strip().splitlines()) == 1, cli.stderr
    assert cli.stderr.startswith("glraster info: ")
    assert_clear(cli.stderr, variables, words)

    call = api(env)
    assert call.returncode == 0, ("the API must raise, not crash", call.returncode, call.stderr)
    assert call.stdout.startswith("ERROR "), call.stdout
    kind = call.stdout.split()[1]
    assert kind in {"BackendUnavailable", "BackendCrashed", "DriverTooOld", "BadEnvironment"}
    assert_clear(call.stdout, variables, words)


@pytest.mark.gl
def test_must_show_nosuchdriver_in_info_render_and_context(cache_home, tmp_path):
    """The issue's cases word for word: info and render exit 3 with one line, nothing is
    written, and Context() raises (before: SIGSEGV inside OSMesaCreateContextAttribs)."""
    env = environment(cache_home, {"GALLIUM_DRIVER": "nosuchdriver"})
    info = glraster(env, "info")
    assert info.returncode == 3 and "GALLIUM_DRIVER='nosuchdriver'" in info.stderr
    render = glraster(env, "render", "basic_triangle", "-o", "x.exr", cwd=tmp_path)
    assert render.returncode == 3, render.stderr
    assert render.stderr.count("\n") == 1 and "GALLIUM_DRIVER='nosuchdriver'" in render.stderr
    assert not list(tmp_path.iterdir())
    call = subprocess.run([sys.executable, "-c", "import glraster as gr; gr.Context()"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert call.returncode == 1, "a Python exception (exit 1), not a signal (negative)"
    last = call.stderr.strip().splitlines()[-1]
    assert last.startswith("glraster.errors.Backend"), last
    assert "GALLIUM_DRIVER='nosuchdriver'" in last


@pytest.mark.gl
@pytest.mark.parametrize("case", list(WORKING))
def test_driver_variables_mesa_tolerates_keep_working(cache_home, case):
    variables = WORKING[case]
    env = environment(cache_home, variables)
    cli = glraster(env, "info")
    assert cli.returncode == exit_codes.OK, cli.stderr
    name, value = next(iter(variables.items()))
    assert f"{name}={value}" in cli.stdout  # "driver variables set:" lists it
    call = api(env)
    assert call.stdout.startswith("OK "), (call.stdout, call.stderr)


def _fake_library(folder: Path, names, content: bytes):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(content)
    return str(folder)


@pytest.mark.gl
@pytest.mark.parametrize("kind", ["not_elf", "wrong_library"])
def test_broken_library_is_named(cache_home, tmp_path, kind):
    """A libEGL / libOSMesa that does not load (garbage, or another library under that
    name, put first by LD_LIBRARY_PATH) is named with the loader's reason, exit 3."""
    content = (b"\x00not an ELF file" * 64 if kind == "not_elf"
               else Path("/lib/x86_64-linux-gnu/libm.so.6").read_bytes())
    if kind == "wrong_library" and not content:
        pytest.skip("no libm.so.6 to stand in for a wrong library")
    folder = _fake_library(tmp_path / "lib", ["libEGL.so.1", "libOSMesa.so.8",
                                              "libOSMesa.so.6", "libOSMesa.so"], content)
    env = environment(cache_home, {"LD_LIBRARY_PATH": folder})
    for backend in ("egl", "osmesa"):
        cli = glraster(env, "info", "--backend", backend)
        assert cli.returncode == exit_codes.NO_BACKEND, cli.stderr
        assert len(cli.stderr.strip().splitlines()) == 1, cli.stderr
        library = {"egl": "libEGL", "osmesa": "libOSMesa"}[backend]
        reason = "invalid ELF header" if kind == "not_elf" else "undefined symbol"
        assert f"{folder}/{library}" in cli.stderr and reason in cli.stderr, cli.stderr
        assert "LD_LIBRARY_PATH=" in cli.stderr


MISSING = """
import ctypes, ctypes.util
_find, _cdll = ctypes.util.find_library, ctypes.CDLL.__init__
def find_library(name):
    return None if name in ("EGL", "OSMesa") else _find(name)
def cdll(self, name, *args, **kwargs):
    if name and ("libEGL" in name or "libOSMesa" in name):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")
    _cdll(self, name, *args, **kwargs)
ctypes.util.find_library, ctypes.CDLL.__init__ = find_library, cdll
"""


@pytest.mark.gl
def test_missing_libraries_give_the_install_hint(cache_home, tmp_path):
    """No libEGL and no libOSMesa (simulated by a sitecustomize that hides them from
    ctypes in this process and in the probe): exit 3 with the apt-get line."""
    (tmp_path / "sitecustomize.py").write_text(MISSING)
    env = environment(cache_home, {})
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env["PYTHONPATH"]])
    cli = glraster(env, "info")
    assert cli.returncode == exit_codes.NO_BACKEND, cli.stderr
    assert len(cli.stderr.strip().splitlines()) == 1, cli.stderr
    assert "libEGL.so.1 not found (Debian package libegl1)" in cli.stderr
    assert "libOSMesa not found (Debian package libosmesa6)" in cli.stderr
    assert "apt-get install" in cli.stderr
    call = api(env)
    assert call.stdout.startswith("ERROR LibraryMissing"), (call.stdout, call.stderr)
