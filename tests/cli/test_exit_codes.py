"""Every command keeps README's exit codes: 0 pass, 1 fail, 2 bad input, 3 no GL backend."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from glraster.cli import exit_codes

# EGL with no vendor library finds no device: the backend is unavailable, not broken.
NO_EGL = {**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent"}


def _glraster(*args, env=None):
    return subprocess.run([sys.executable, "-m", "glraster.cli", *args], capture_output=True,
                          text=True, env=env, timeout=300)


@pytest.mark.parametrize("args", [
    ("info", "--backend", "egl"),
    ("render", "basic_triangle", "-o", "{tmp}/x.exr", "--backend", "egl"),
    ("distortion", "--out", "{tmp}/d", "--backend", "egl"),
    ("check", "--scenes", "basic_triangle", "--backend", "egl"),
])
def test_no_backend_is_exit_code_3(tmp_path, args):
    result = _glraster(*(a.format(tmp=tmp_path) for a in args), env=NO_EGL)
    assert result.returncode == exit_codes.NO_BACKEND, result.stderr
    assert not list(tmp_path.iterdir()), "nothing is written without a context"


def test_bad_input_is_exit_code_2(tmp_path):
    result = _glraster("render", "no_such_scene", "-o", str(tmp_path / "x.exr"))
    assert result.returncode == exit_codes.USAGE
    assert "no_such_scene" in result.stderr


def test_no_command_is_exit_code_2():
    assert _glraster().returncode == exit_codes.USAGE


def test_a_missing_optional_extra_is_a_usage_error_naming_it(tmp_path):
    """Without torch (a stub that cannot be imported), `glraster fit` says which extra to
    install instead of a traceback."""
    stub = tmp_path / "stub" / "torch"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'torch'\", "
                                      "name='torch')\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "stub")}
    result = _glraster("fit", "cube", "--out", str(tmp_path / "o"), env=env)
    assert result.returncode == exit_codes.USAGE, result.stderr
    assert "pip install 'glraster[torch]'" in result.stderr
    assert "Traceback" not in result.stderr


def test_python_dash_m_glraster_is_the_command():
    """``python -m glraster`` runs the CLI as ``python -m glraster.cli`` and the
    ``glraster`` script do (a new user's first try when the script is not on PATH)."""
    for module in ("glraster", "glraster.cli"):
        result = subprocess.run([sys.executable, "-m", module, "--version"],
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        assert result.stdout.startswith("glraster "), result.stdout
    assert subprocess.run([sys.executable, "-m", "glraster", "no-such-command"],
                          capture_output=True, timeout=120).returncode == exit_codes.USAGE
