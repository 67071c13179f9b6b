"""Where the golden EXRs live, and when ``glraster golden update`` may write there.

Light on purpose (paths only): the CLI shows the folder in its help without importing the
reference rasterizer.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent  # the glraster package in use


def golden_dir(directory=None) -> Path:
    """The golden folder: ``directory``, else ``$GLRASTER_GOLDEN_DIR``, else ``golden/`` at
    the top of the source tree, else the copy the wheel ships as ``glraster/golden``."""
    if directory is not None:
        return Path(directory)
    env = os.environ.get("GLRASTER_GOLDEN_DIR")
    if env:
        return Path(env)
    source_tree = PACKAGE.parent / "golden"
    return source_tree if source_tree.is_dir() else PACKAGE / "golden"


def unsafe_default(directory=None, cwd=None) -> str | None:
    """Why ``update`` must not write to the default folder without being told, or None.

    Only a default is judged (``directory`` and ``$GLRASTER_GOLDEN_DIR`` are the user's
    word): the copy inside an installed package, or the ``golden/`` of a source tree that
    the current directory (``cwd``) is not in (another checkout's goldens).
    """
    if directory is not None or os.environ.get("GLRASTER_GOLDEN_DIR"):
        return None
    target = golden_dir()
    if target == PACKAGE / "golden":
        return f"the copy installed inside the glraster package ({target})"
    here = Path(cwd or os.getcwd()).resolve()
    tree = target.parent
    if here != tree and tree not in here.parents:
        return (f"the golden folder of the glraster source tree at {tree} (the one Python "
                f"imports), and the current directory {here} is not in that tree")
    return None
