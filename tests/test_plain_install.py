"""A plain ``pip install .`` (no extras) runs the documented figure commands.

Slow but real: it makes a fresh virtual environment (a plain venv: no system or project
site-packages), installs this source tree into it with no extras, exactly as a user
would (pip uses the machine's configuration, the same indexes as ``make setup``), and
runs ``glraster check --html`` and ``glraster distortion`` there, from an empty folder so
that the source tree cannot be imported instead of the installed package. About a minute
with a warm pip cache (the fresh numba cache is part of it); it runs in ``make test``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENES = "basic_perspective_triangle,torus"


def _env(venv: Path) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP")}
    env["VIRTUAL_ENV"] = str(venv)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env.pop("GLRASTER_GOLDEN_DIR", None)
    return env


def _run(cmd, cwd, env, timeout):
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, (f"{' '.join(map(str, cmd))} exited {proc.returncode}\n"
                                  f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n"
                                  f"{proc.stderr[-3000:]}")
    return proc


def _decodable_png(path: Path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, f"{path}: {oiio.geterror()}"
    try:
        img = inp.read_image("uint8")
        assert inp.format_name() == "png"
    finally:
        inp.close()
    assert img is not None and img.size > 0
    return img


@pytest.fixture(scope="module")
def plain_install(tmp_path_factory):
    """(venv, env): a fresh plain venv with this tree installed, no extras (made once)."""
    root = tmp_path_factory.mktemp("plain")
    venv = root / "venv"
    _run([sys.executable, "-m", "venv", venv], root, None, 300)
    py = venv / "bin" / "python"
    env = _env(venv)
    _run([py, "-m", "pip", "install", "--quiet", ROOT], root, env, 1200)
    # The installed package is used, without any extra: no trimesh, pyrender or pytest.
    probe = _run([py, "-c", "import importlib.util as u, glraster; print(glraster.__file__); "
                  "print(*[m for m in ('trimesh', 'pyrender', 'pytest') if u.find_spec(m)])"],
                 root, env, 300)
    where, extras = (probe.stdout.splitlines() + [""])[:2]
    assert Path(where).is_relative_to(venv), where
    assert extras.strip() == "", f"extras present in a plain install: {extras}"
    return venv, env


@pytest.mark.gl
@pytest.mark.slow
def test_plain_pip_install_runs_check_html_and_distortion(plain_install, tmp_path, gl_backend):
    venv, env = plain_install
    work = tmp_path / "work"
    work.mkdir()
    glraster = venv / "bin" / "glraster"
    _run([glraster, "check", "--backend", gl_backend, "--scenes", SCENES, "--html", "out/r"],
         work, env, 900)
    report = work / "out" / "r"
    html = (report / "index.html").read_text(encoding="utf-8")
    assert "basic_perspective_triangle" in html and "torus" in html
    assert html.count("<td>bit-exact</td>") == 2     # the goldens shipped in the wheel match
    for name in SCENES.split(","):
        for kind in ("gpu", "ref", "error", "coverage"):
            _decodable_png(report / "img" / f"{name}_{kind}.png")
    assert _decodable_png(report / "img" / "summary.png").shape[2] >= 3

    _run([glraster, "distortion", "--backend", gl_backend, "--out", "out/d"], work, env, 900)
    out = work / "out" / "d"
    for name in ("plane", "cube"):
        for kind in ("affine", "correct"):
            img = _decodable_png(out / f"{name}_{kind}.png")
            assert img.shape[:2] == (360, 480)
        _decodable_png(out / f"{name}_diff.png")
    fig = _decodable_png(out / "distortion_figure.png")
    assert fig.shape[1] > 1000 and np.ptp(fig) > 100
    assert (out / "distortion.exr").stat().st_size > 0
    assert "9/2 = 4.5" in (out / "segment_example.txt").read_text()
    # atomic writes leave no temporary files behind
    assert not [p for p in out.rglob(".*")] and not [p for p in report.rglob(".*")]
