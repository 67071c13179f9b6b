"""The docs harness itself, on a Markdown file made here (no GL): order, one interpreter
and one empty folder per file, console commands, skips, failures naming file and line, and
nothing left running."""

from __future__ import annotations

import os
import textwrap
import unittest

import pytest

from tests.docs import markdown_blocks as mb

PAGE = textwrap.dedent('''\
    # A page

    ```python
    import os
    first_folder = os.getcwd()
    assert os.listdir(".") == []          # an empty folder
    x = 41
    ```

    ```console
    $ echo "made by a command" > note.txt
    $ test "$(cat note.txt)" = \\
      "made by a command"
    $ command -v glraster > /dev/null
    shown output, not run
    ```

    <!-- skip: next "takes an hour; tests/docs/test_harness.py runs a short form" -->
    ```python
    raise SystemExit("a skipped block must not run")
    ```

    ```python
    assert os.getcwd() == first_folder and open("note.txt").read() == "made by a command\\n"
    x += 1                                # the earlier block's namespace
    ```

    ```python
    assert x == 43, x
    ```

    ```console
    $ sleep 600 > /dev/null 2>&1 & echo $! > sleeper.pid
    $ false
    ```
    ''')


@pytest.fixture
def page(tmp_path):
    path = tmp_path / "page.md"
    path.write_text(PAGE)
    run = mb.open_run(path)
    yield run
    mb.close_runs()


def outcomes(run):
    blocks = [i for i, e in enumerate(run.examples) if not mb.is_skip(e)]
    return [(mb.block_of(run.examples[i]).line, run.outcome(i)) for i in blocks]


def test_blocks_run_in_order_in_one_folder_and_interpreter(page):
    folder = page.folder
    results = outcomes(page)
    lines = [line for line, _ in results]
    assert lines == [3, 10, 19, 23, 28, 32]
    python, console, skipped, reuse, wrong, last = (outcome for _, outcome in results)
    assert python is None and console is None and reuse is None
    assert isinstance(skipped, unittest.SkipTest)
    assert str(skipped) == "takes an hour; tests/docs/test_harness.py runs a short form"
    # A failure names the file and the line of the block, and the line in the block.
    assert isinstance(wrong, mb.BlockFailed)
    assert f"{page.path}:28: the python block failed" in str(wrong)
    assert f'File "{page.path}", line 29' in str(wrong) and "AssertionError: 42" in str(wrong)
    assert isinstance(last, mb.BlockFailed)
    assert f"{page.path}:34: `false` exited 1" in str(last)
    # The file is done: its folder is gone and nothing it started is running.
    assert not folder.exists() and page.worker is None


def test_a_background_process_a_command_leaves_is_stopped(page, tmp_path):
    # (page: only for its teardown, which closes every run.)
    path = tmp_path / "bg.md"
    path.write_text("```console\n$ sleep 600 > /dev/null 2>&1 & echo $! > ../sleeper.pid\n```\n")
    run = mb.open_run(path)
    assert run.outcome(0) is None
    pid = int((run.folder.parent / "sleeper.pid").read_text())
    (run.folder.parent / "sleeper.pid").unlink()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_console_commands_and_continuations_are_parsed_with_their_lines():
    source = "$ a \\\n  b\nshown\n$ c\n"
    assert mb.console_commands(source, 10) == [(10, "a \\\n  b"), (13, "c")]
