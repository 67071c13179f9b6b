"""atomic_write: the target is replaced whole or not at all, no temporary file is left."""

from __future__ import annotations

import pytest

from glraster.io.atomic import atomic_write


def test_success_replaces_the_target_with_shared_permissions(tmp_path):
    target = tmp_path / "sub" / "out.txt"
    with atomic_write(target) as tmp:
        with open(tmp, "w") as f:
            f.write("new")
    assert target.read_text() == "new"
    assert target.stat().st_mode & 0o777 == 0o644
    assert [p.name for p in target.parent.iterdir()] == ["out.txt"]


def test_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "out.exr"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(target) as tmp:
            assert tmp.endswith(".exr")          # writers pick the format from the name
            with open(tmp, "w") as f:
                f.write("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM"])
def test_a_signal_just_after_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch,
                                                                       name):
    """SIGINT, or SIGTERM with glraster's handler (glraster.cli.main), between mkstemp and
    the code that removes the temporary file (the race a real Ctrl-C hit): held back, then
    raised inside atomic_write, which cleans up."""
    import os
    import signal
    import tempfile

    from glraster.cli import Terminated, _terminated

    signum = getattr(signal, name)
    raised = KeyboardInterrupt if name == "SIGINT" else Terminated
    previous = signal.signal(signal.SIGTERM, _terminated) if name == "SIGTERM" else None
    real_mkstemp = tempfile.mkstemp

    def mkstemp_then_signal(*args, **kwargs):
        made = real_mkstemp(*args, **kwargs)
        os.kill(os.getpid(), signum)
        return made

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_signal)
    body_ran = []
    try:
        with pytest.raises(raised):
            with atomic_write(tmp_path / "x.txt"):
                body_ran.append(True)
        assert body_ran == [], "the signal comes before the body"
        assert list(tmp_path.iterdir()) == []
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        if name == "SIGTERM":
            assert signal.getsignal(signal.SIGTERM) is _terminated
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def test_write_text_is_atomic_and_names_a_blocked_target(tmp_path):
    from glraster.io.atomic import write_text

    assert write_text(tmp_path / "a" / "b.txt", "hi").read_text() == "hi"
    (tmp_path / "f").write_text("")
    with pytest.raises(OSError, match=r"cannot create a file there \(.*/f is a file, not a "
                                      r"folder\): '.*/f/b.txt'"):
        write_text(tmp_path / "f" / "b.txt", "hi")


# A child process whose files cannot grow past FILE_LIMIT bytes (RLIMIT_FSIZE, SIGXFSZ
# ignored: a write past it fails with EFBIG, as a full disk fails with ENOSPC). Each
# writer writes more than that into FOLDER; the child prints what each raised.
FILE_LIMIT = 4096
_WRITERS = r"""
import json, resource, signal, sys
import numpy as np
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
folder, limit = sys.argv[1], int(sys.argv[2])
old = folder + "/old.png"
from glraster.io.png import write_png
write_png(old, np.zeros((4, 4, 3)))            # a file that is there before, under the limit
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from glraster.io.atomic import write_text
from glraster.io.exr import write_raster
noise = np.random.default_rng(0).random((200, 200, 3))
writers = {
    "old.png": lambda p: write_png(p, noise),
    "new.png": lambda p: write_png(p, noise),
    "new.exr": lambda p: write_raster(p, persp=noise.astype(np.float32), window="full"),
    "new.txt": lambda p: write_text(p, "x" * 3 * limit),
}
raised = {}
for name, write in writers.items():
    try:
        write(folder + "/" + name)
        raised[name] = None
    except OSError as exc:
        raised[name] = [exc.errno, exc.filename, str(exc)]
print(json.dumps(raised))
"""


def test_a_write_that_fails_for_lack_of_room_is_an_error_naming_the_file(tmp_path):
    """OpenImageIO's PNG writer returns success from open, write and close when the file
    system refuses bytes (only its error text says so): every writer raises an OSError
    naming the target, the old file stays whole and nothing partial is left."""
    import errno
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _WRITERS, str(tmp_path), str(FILE_LIMIT)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    raised = json.loads(out.stdout)
    old_bytes = (tmp_path / "old.png").read_bytes()
    for name, error in raised.items():
        assert error is not None, f"writing {name} past the limit raised nothing"
        code, filename, text = error
        assert filename == str(tmp_path / name), text    # the target, not a temporary file
        assert code in (errno.EFBIG, errno.EIO), text
    assert "OpenImageIO cannot write it" in raised["new.png"][2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.png"]
    assert (tmp_path / "old.png").read_bytes() == old_bytes


def test_an_image_write_short_of_room_is_enospc(tmp_path, monkeypatch):
    """The OSError of a failed OpenImageIO write: ENOSPC when the folder's file system has
    less room than the image's bytes, else EIO with OpenImageIO's first line, in which
    the file is 'it' (the error names it already)."""
    import errno
    import shutil

    from glraster.io import atomic

    target = tmp_path / "x.png"
    text = f'could not write "{target}"\nsecond line'
    error = atomic.image_write_error(target, text, 1 << 10)
    assert (error.errno, error.filename) == (errno.EIO, str(target))
    assert error.strerror == "OpenImageIO cannot write it: could not write it"
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(atomic.shutil, "disk_usage", lambda path: usage._replace(free=100))
    error = atomic.image_write_error(target, text, 1 << 10)
    assert (error.errno, error.strerror) == (errno.ENOSPC, "No space left on device")


def test_a_staged_set_of_files_lands_whole_or_not_at_all(tmp_path):
    """staged_folder: the files of a run replace the last run's together; a run that fails
    midway leaves the old set (not a mix), no staged file, and names the file where it
    goes; a folder made for a run that wrote nothing is removed again."""
    import errno

    from glraster.io.atomic import staged_folder, write_text

    out = tmp_path / "out"
    with staged_folder(out) as stage:
        for name in ("a.txt", "b.txt"):
            write_text(stage / name, f"old {name}")
    (out / "mine.txt").write_text("not glraster's")
    assert sorted(p.name for p in out.iterdir()) == ["a.txt", "b.txt", "mine.txt"]

    with pytest.raises(OSError) as caught:
        with staged_folder(out) as stage:
            write_text(stage / "a.txt", "new a.txt")
            raise OSError(errno.ENOSPC, "No space left on device", str(stage / "b.txt"))
    assert caught.value.filename == str(out / "b.txt")
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "a.txt": "old a.txt", "b.txt": "old b.txt", "mine.txt": "not glraster's"}

    with staged_folder(out) as stage:
        write_text(stage / "a.txt", "new a.txt")
    assert (out / "a.txt").read_text() == "new a.txt" and (out / "b.txt").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]

    with pytest.raises(RuntimeError):
        with staged_folder(tmp_path / "new" / "out"):
            raise RuntimeError("the run failed")
    assert not (tmp_path / "new" / "out").exists()
