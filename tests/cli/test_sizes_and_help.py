"""Small CLI promises: `render` prints sizes as HxW (the API's (H, W) order), the
texture benchmark module answers --help instead of starting the benchmark, and a mistyped
option is refused by the command it was given to."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from glraster.cli import main

REPO = Path(__file__).resolve().parents[2]


def test_render_prints_height_then_width(tmp_path, capsys):
    """A 24 (H) x 40 (W) scene: the API's (H, W), printed as 24x40 (HxW) (it said 40x24)."""
    pos = np.array([[-0.5, -0.5, 0, 1], [0.5, -0.5, 0, 1], [0, 0.5, 0, 1]], np.float32)
    np.savez(tmp_path / "wide.npz", pos=pos, tri=np.array([[0, 1, 2]]),
             resolution=np.array([24, 40]))
    assert main(["render", str(tmp_path / "wide.npz"), "--reference",
                 "-o", str(tmp_path / "wide.exr")]) == 0
    assert capsys.readouterr().out.startswith("wide: 24x40 (HxW), 1 triangle, ")


def test_texture_baseline_help_does_not_run_the_benchmark():
    import pytest

    pytest.importorskip("torch")  # the module is part of the [torch] extra
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO),
                                                        os.environ.get("PYTHONPATH", "")])}
    for args, code in ((["--help"], 0), (["--sizes", "3"], 2)):
        result = subprocess.run([sys.executable, "-m", "glraster.cli", "study",
                                 "texture-baseline", *args],
                                capture_output=True, text=True, env=env, timeout=120)
        assert result.returncode == code, result.stderr
        assert "| image and texture |" not in result.stdout, "the benchmark ran"
    assert "usage: glraster study texture-baseline" in result.stderr
    assert "--sizes must be powers of two >= 2, got 3" in result.stderr


def test_an_unknown_argument_is_refused_by_the_command_it_was_given_to(capsys):
    """A mistyped option gets the usage and error of the (sub)command it was given to, not
    the top level's ("usage: glraster [-h] [--version] COMMAND ..." told nothing)."""
    import pytest

    for argv, prog, unknown in ((["fit", "cube", "--itrations", "5"], "glraster fit cube",
                                 "--itrations 5"),
                                (["golden", "check", "--bogus"], "glraster golden check",
                                 "--bogus"),
                                (["info", "extra"], "glraster info", "extra"),
                                (["--bogus"], "glraster", "--bogus")):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith(f"usage: {prog} "), err
        assert err.rstrip().endswith(f"{prog}: error: unrecognized arguments: {unknown}"), err
