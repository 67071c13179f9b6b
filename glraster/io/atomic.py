"""Writing a file so that nothing partial is ever left behind.

Every writer in glraster (EXR, PNG, figures) writes to a temporary file in the target's
folder and renames it over the target only when the write succeeded, so a failure (or an
interrupt) leaves the previous file, or none, and no temporary file. An OSError of the write
names the target, not the temporary file (a full disk reads "out.exr: No space left on
device").
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path


# Ctrl-C, and SIGTERM where a handler makes it an exception (glraster.cli.main)
_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _hold_interrupts():
    """Defer Ctrl-C and SIGTERM: their handlers are replaced by one that only records them
    (SIGTERM's only when it has a handler of its own: by default it ends the process, which
    nothing here can undo). Returns what :func:`_release` needs (None off the main thread,
    where no KeyboardInterrupt is ever raised and handlers cannot be set). A signal mask
    would not do: a signal goes to any thread that does not block it (driver and
    OpenImageIO threads), and Python runs its handler in the main thread anyway."""
    if threading.current_thread() is not threading.main_thread():
        return None
    caught = []
    previous = {}
    for number in _HELD_SIGNALS:
        if number == signal.SIGINT or callable(signal.getsignal(number)):
            previous[number] = signal.signal(
                number, lambda signum, frame: caught.append((signum, frame)))
    return previous, caught


def _release(held) -> None:
    """Put the handlers back; a signal that came meanwhile is handed to its handler now
    (SIGINT's default raises KeyboardInterrupt here)."""
    if held is None:
        return
    previous, caught = held
    for number, handler in previous.items():
        signal.signal(number, handler)
    if caught:
        number, frame = caught[0]
        handler = previous[number]
        if callable(handler):
            handler(number, frame)
        elif handler == signal.SIG_DFL:
            signal.raise_signal(number)


def _temporary_beside(path: Path, suffix: str | None) -> str:
    """Create an empty temporary file in ``path``'s folder (made if missing); an OSError
    names ``path``, not the temporary file."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix,
                                   dir=path.parent)
    except OSError as exc:
        blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
        reason = f"{blocking} is a file, not a folder" if blocking else exc.strerror
        raise type(exc)(exc.errno, f"cannot create a file there ({reason})",
                        str(path)) from None
    os.close(fd)
    return tmp


@contextmanager
def atomic_write(path, suffix: str | None = None, mode: int = 0o644):
    """Context manager yielding a temporary path (str) beside ``path`` to write to.

    On normal exit the temporary file gets ``mode`` (mkstemp creates 0600; output files
    are shared) and replaces ``path`` in one rename; on any exception it is removed and
    the exception propagates. The parent folder is created. ``suffix`` (default: the
    target's) matters to writers that choose a format from the file name.

    Ctrl-C (and SIGTERM under ``glraster``) is held back from creating the temporary file
    until the code that removes it is in place (an interrupt between the two would leave
    it behind).
    """
    path = Path(path)
    tmp = None
    held = _hold_interrupts()
    try:
        tmp = _temporary_beside(path, suffix)
        held, holding = None, held
        _release(holding)
        yield tmp
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno is not None and exc.filename in (None, tmp):
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    finally:
        _release(held)


def staged_error(exc: OSError, stage: Path, folder: Path) -> OSError:
    """``exc``, naming the file in ``folder`` where it names its staged copy in ``stage``."""
    if exc.errno is None or not exc.filename or Path(exc.filename).parent != stage:
        return exc
    return OSError(exc.errno, exc.strerror, str(folder / Path(exc.filename).name))


@contextmanager
def staged_folder(folder):
    """Context manager yielding a hidden folder (a Path) inside ``folder`` (made if missing)
    to write a set of files into. On normal exit every file written there replaces its
    namesake in ``folder``, all of them after the last write succeeded (Ctrl-C held back
    meanwhile), so a run that fails leaves the set that was there, not a mix of old and new
    files; on any exception the staged files are removed (an OSError names the file in
    ``folder``, not its staged copy), and ``folder`` too when it was made for them.
    ``folder``'s other files stay."""
    folder = Path(folder)
    stage, made = None, not folder.exists()
    held = _hold_interrupts()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=".staged.", dir=folder))
        held, holding = None, held
        _release(holding)
        try:
            yield stage
        except OSError as exc:
            error = staged_error(exc, stage, folder)
            if error is exc:
                raise
            raise error from exc
        held = _hold_interrupts()
        for item in sorted(stage.iterdir()):
            os.replace(item, folder / item.name)
    finally:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
            if made and not any(folder.iterdir()):   # (made for a run that wrote nothing)
                folder.rmdir()
        _release(held)


def write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (the parent folder is created)."""
    path = Path(path)
    with atomic_write(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path


def image_write_error(path, message: str, nbytes: int) -> OSError:
    """The OSError of an OpenImageIO write of about ``nbytes`` to ``path`` that failed with
    ``message``. OpenImageIO's writers report a full disk only in their error text, and
    their open, write and close may all return success (PNG): the error is ENOSPC when
    ``path``'s file system has less than ``nbytes`` free, else EIO with the first line of
    ``message`` (the file named as "it": the error names ``path`` already)."""
    try:
        free = shutil.disk_usage(Path(path).parent).free
    except OSError:
        free = None
    if free is not None and free < nbytes:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    first = (message.strip().splitlines() or ["no reason given"])[0]
    first = first.replace(f'"{path}"', "it").replace(str(path), "it")
    return OSError(errno.EIO, f"OpenImageIO cannot write it: {first}", str(path))


def write_image(path, spec, pixels, suffix: str) -> Path:
    """Write one OpenImageIO image (``spec``, ``pixels``) to ``path`` atomically; the format
    follows ``suffix`` (".png", ".exr"). OSError naming the file when OpenImageIO fails,
    including a failure it reports only in its error text."""
    import OpenImageIO as oiio

    path = Path(path)
    with atomic_write(path, suffix=suffix) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"OpenImageIO cannot write {suffix} files: {oiio.geterror()}")
        ok = out.open(tmp, spec) and out.write_image(pixels)
        ok = out.close() and ok
        message = out.geterror()
        if not ok or message:
            raise image_write_error(tmp, message or oiio.geterror(), pixels.nbytes)
    return path
