"""Token files of ``glraster serve --token-file``: the 16-character minimum is stated in
the error, which names the file and line, and the command exits 2 (no GL, no server)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from glraster.service.config import MIN_TOKEN_LENGTH, read_token_file


def _token_file(tmp_path, text):
    path = tmp_path / "tokens"
    path.write_text(text)
    path.chmod(0o600)
    return path


@pytest.mark.parametrize("token,problem", [
    ("short-token", "it has 11 characters"),
    ("x" * (MIN_TOKEN_LENGTH - 1), f"it has {MIN_TOKEN_LENGTH - 1} characters"),
    ("a-long-token with-space", "it holds a space"),
    ("a-long-token-\x07-bell", "it holds a character that is not printable"),
])
def test_bad_token_is_refused_with_the_minimum_in_the_message(tmp_path, token, problem):
    path = _token_file(tmp_path, f"# rotated weekly\n{'y' * 20}\n{token}\n")
    with pytest.raises(ValueError) as err:
        read_token_file(path)
    assert str(err.value).startswith(f"token file {str(path)!r} line 3: {problem}; a token "
                                     f"must be at least {MIN_TOKEN_LENGTH} printable "
                                     "characters without spaces")


def test_token_of_exactly_the_minimum_is_accepted(tmp_path):
    token = "z" * MIN_TOKEN_LENGTH
    assert read_token_file(_token_file(tmp_path, token + "\n")) == (token,)


def test_serve_with_a_short_token_exits_2_with_one_line(tmp_path):
    path = _token_file(tmp_path, "too-short\n")
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "serve", "--port", "0",
                          "--token-file", str(path)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "at least 16 printable characters" in lines[0], run.stderr
