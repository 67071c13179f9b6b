"""The layers hold: the import contracts pass, and the CPU side runs without moderngl."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from tests.no_gl import BLOCK_GL

ROOT = Path(__file__).resolve().parents[1]


REFERENCE_WITHOUT_GL = BLOCK_GL + textwrap.dedent("""
    import numpy as np

    import glraster.reference

    pos = np.array([[-0.8, -0.8, 0.0, 1.0], [0.8, -0.8, 0.0, 2.0], [0.0, 0.8, 0.0, 1.0]],
                   np.float32)
    r = glraster.reference.rasterize(pos, [[0, 1, 2]], (16, 16))
    assert r.mask.any() and (r.tri_id[r.mask] == 0).all()
    assert np.allclose(r.persp[r.mask].sum(-1), 1.0)
    assert not any(m.split(".")[0] in ("moderngl", "glcontext") or m.startswith("glraster.gpu")
                   for m in sys.modules), sorted(sys.modules)

    import glraster
    try:
        glraster.rasterize
    except ImportError as exc:
        assert "moderngl" in str(exc), exc
    else:
        raise AssertionError("glraster.rasterize without moderngl")
    print("ok", int(r.mask.sum()))
""")


def test_the_reference_rasterizes_without_moderngl():
    proc = subprocess.run([sys.executable, "-c", REFERENCE_WITHOUT_GL], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("ok ")


def test_import_contracts_are_kept():
    """`lint-imports` (import-linter, the `test` extra) with pyproject.toml's contracts."""
    lint_imports = Path(sys.executable).with_name("lint-imports")
    assert lint_imports.is_file(), "import-linter is not installed: pip install -e '.[test]'"
    proc = subprocess.run([str(lint_imports), "--no-cache", "--no-logo"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 broken" in proc.stdout
