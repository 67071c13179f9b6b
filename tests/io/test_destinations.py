"""Destinations judged before a command runs (glraster.io.destinations); the CLI's use of
them: tests/cli/test_cli_errors.py."""

from __future__ import annotations

import os

from glraster.io.destinations import unwritable_reason


def test_unwritable_reason_judges_a_destination_without_making_anything(tmp_path):
    (tmp_path / "f").write_text("")
    (tmp_path / "d").mkdir()
    assert unwritable_reason(tmp_path / "new" / "deeper" / "x.json") is None
    assert unwritable_reason(tmp_path / "new" / "deeper", folder=True) is None
    assert unwritable_reason(tmp_path / "d", folder=True) is None
    assert unwritable_reason(tmp_path / "f") is None, "a file is replaced"
    file_there = f"{tmp_path / 'f'} is a file, not a folder"
    assert unwritable_reason(tmp_path / "f" / "x.json") == file_there
    assert unwritable_reason(tmp_path / "f", folder=True) == file_there
    assert unwritable_reason(tmp_path / "d") == f"{tmp_path / 'd'} is a folder, not a file"
    assert sorted(os.listdir(tmp_path)) == ["d", "f"], "nothing was made"
    if os.geteuid() != 0:   # root writes anywhere
        (tmp_path / "d").chmod(0o500)
        try:
            assert unwritable_reason(tmp_path / "d" / "x") == f"{tmp_path / 'd'} is not writable"
        finally:
            (tmp_path / "d").chmod(0o700)
