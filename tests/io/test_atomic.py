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


def test_ctrl_c_just_after_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch):
    """SIGINT between mkstemp and the code that removes the temporary file (the race a
    real Ctrl-C hit): held back, then raised inside atomic_write, which cleans up."""
    import os
    import signal
    import tempfile

    real_mkstemp = tempfile.mkstemp

    def mkstemp_then_ctrl_c(*args, **kwargs):
        made = real_mkstemp(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return made

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_ctrl_c)
    body_ran = []
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(tmp_path / "x.txt"):
            body_ran.append(True)
    assert body_ran == [], "the interrupt comes before the body"
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_write_text_is_atomic_and_names_a_blocked_target(tmp_path):
    from glraster.io.atomic import write_text

    assert write_text(tmp_path / "a" / "b.txt", "hi").read_text() == "hi"
    (tmp_path / "f").write_text("")
    with pytest.raises(OSError, match=r"cannot create a file there \(.*/f is a file, not a "
                                      r"folder\): '.*/f/b.txt'"):
        write_text(tmp_path / "f" / "b.txt", "hi")
