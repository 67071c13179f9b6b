"""Writing a file so that nothing partial is ever left behind.

Every writer in glraster (EXR, PNG, figures) writes to a temporary file in the target's
folder and renames it over the target only when the write succeeded, so a failure (or an
interrupt) leaves the previous file, or none, and no temporary file.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_write(path, suffix: str | None = None, mode: int = 0o644):
    """Context manager yielding a temporary path (str) beside ``path`` to write to.

    On normal exit the temporary file gets ``mode`` (mkstemp creates 0600; output files
    are shared) and replaces ``path`` in one rename; on any exception it is removed and
    the exception propagates. The parent folder is created. ``suffix`` (default: the
    target's) matters to writers that choose a format from the file name.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix,
                                   dir=path.parent)
    except OSError as exc:  # name the target, not the temporary file
        blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
        reason = f"{blocking} is a file, not a folder" if blocking else exc.strerror
        raise type(exc)(exc.errno, f"cannot create a file there ({reason})",
                        str(path)) from None
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (the parent folder is created)."""
    path = Path(path)
    with atomic_write(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path


def write_image(path, spec, pixels, suffix: str) -> Path:
    """Write one OpenImageIO image (``spec``, ``pixels``) to ``path`` atomically; the format
    follows ``suffix`` (".png", ".exr"). OSError naming the file when OpenImageIO fails."""
    import OpenImageIO as oiio

    path = Path(path)
    with atomic_write(path, suffix=suffix) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"OpenImageIO cannot write {suffix} files: {oiio.geterror()}")
        try:
            if not out.open(tmp, spec) or not out.write_image(pixels):
                raise OSError(f"cannot write {path}: {out.geterror() or oiio.geterror()}")
        finally:
            out.close()
    return path
