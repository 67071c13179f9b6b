"""A module of glraster as it was at an earlier git revision, loaded beside the current one:
what the A/B studies (``metrics-ab``, ``service-parse-ab``) time the current code against.

Needs a git checkout of glraster (the source tree this package is imported from) and
``git`` on PATH.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import ModuleType

from glraster.errors import ArgumentError

# the source tree this package is in: glraster/studies/revision.py -> the checkout's root
TREE = Path(__file__).resolve().parents[2]


def tree_environment(tree) -> dict:
    """``os.environ`` for a Python process that runs the checkout ``tree``: ``tree`` first
    on PYTHONPATH (its glraster is the one imported), then the caller's PYTHONPATH entries
    (where packages installed with ``pip --target`` are found)."""
    rest = os.environ.get("PYTHONPATH", "")
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree)] + ([rest] if rest else [])))


def load_module_at(rev: str, path: str, name: str) -> ModuleType:
    """The file ``path`` (relative to the tree's root, e.g. "glraster/service/metrics.py") of
    git revision ``rev``, imported as module ``name`` (registered in ``sys.modules``, so its
    dataclasses resolve). An :class:`~glraster.errors.ArgumentError` ("REV") when the tree
    is no git checkout or the revision has no such file."""
    try:
        proc = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=TREE,
                              capture_output=True, text=True, timeout=60)
    except FileNotFoundError:
        raise ArgumentError("REV", "REV needs git on PATH to read an earlier revision") \
            from None
    if proc.returncode != 0:
        why = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no checkout"
        raise ArgumentError("REV", f"REV {rev!r}: git cannot show {path} in {TREE} ({why})")
    folder = Path(tempfile.mkdtemp(prefix="glraster-rev-"))
    file = folder / f"{name}.py"
    file.write_text(proc.stdout)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
