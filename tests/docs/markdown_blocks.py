"""Run the examples of README.md and docs/*.md as the docs promise (docs/ci.md, "Docs are tests").

The convention every page follows:

* every ```python block of one Markdown file runs, in order, in ONE fresh interpreter per
  file (a subprocess, :mod:`tests.docs.block_worker`), with an empty temporary folder as its
  working directory: a block defines its own inputs;
* every line of a ```console block that starts with ``$ `` is a command, run with bash in
  that same folder with this interpreter's ``bin/`` (so ``glraster``) first on PATH; it must
  exit 0. Other lines are shown output, not checked; a command whose line ends in ``\\``
  goes on on the next line (bash reads the two lines as one command);
* ``<!-- skip: next "reason" -->`` right before a block skips it, and pytest reports the
  reason.

Markdown is read with sybil (its fenced-code-block and skip-directive lexers); sybil's own
evaluators would run Python in the pytest process, so the evaluators here send each block
to the file's interpreter instead. A failure names the file and line of the block.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from sybil import Document, Example
from sybil.evaluators.skip import Skipper
from sybil.parsers.markdown import CodeBlockParser, SkipParser

REPO = Path(__file__).resolve().parents[2]
WORKER = Path(__file__).with_name("block_worker.py")

# A block must run in seconds (docs/ci.md); these limits only stop a hang.
PYTHON_BLOCK_TIMEOUT_S = 180
CONSOLE_COMMAND_TIMEOUT_S = 300
# How much of a failing command's output the failure shows.
OUTPUT_TAIL_CHARS = 4000


def end_process_group(pgid: int, grace_s: float = 5.0) -> None:
    """Stop whatever a block left running in its process group (a server it started)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline:
            try:
                os.killpg(pgid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.05)


def documented_files() -> list[Path]:
    """README.md and every Markdown page under docs/, in a fixed order (new pages included)."""
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def relative(path: Path | str) -> str:
    """The path as the docs and failures name it: relative to the repository if inside."""
    path = Path(path).resolve()
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


@dataclass
class Block:
    """One ```python or ```console block of a Markdown file."""

    path: Path
    line: int          # 1-based line of the opening fence
    language: str      # "python" | "console"
    source: str        # the block's text, without the fences

    @property
    def where(self) -> str:
        return f"{relative(self.path)}:{self.line}"


class PythonBlocks(CodeBlockParser):
    def __init__(self) -> None:
        super().__init__(language="python")

    def evaluate(self, example: Example) -> None:
        run_of(example.document).run_python(example)


class ConsoleBlocks(CodeBlockParser):
    def __init__(self) -> None:
        super().__init__(language="console")

    def evaluate(self, example: Example) -> None:
        run_of(example.document).run_console(example)


PARSERS = (PythonBlocks(), ConsoleBlocks(), SkipParser())


def parse(path: Path) -> Document:
    """The sybil Document of one Markdown file, its examples in file order."""
    return Document.parse(str(path), *PARSERS)


def is_skip(example: Example) -> bool:
    return isinstance(example.region.evaluator, Skipper)


def block_of(example: Example) -> Block:
    parser = getattr(example.region.evaluator, "__self__", None)
    language = "python" if isinstance(parser, PythonBlocks) else "console"
    return Block(Path(example.path), example.line, language, str(example.parsed))


def console_commands(source: str, first_line: int) -> list[tuple[int, str]]:
    """The ``$ `` commands of a console block as (line in the file, command) pairs.

    ``first_line`` is the line of the block's first source line. A command whose line ends
    in a backslash continues on the next line.
    """
    commands: list[tuple[int, str]] = []
    lines = source.splitlines()
    i = 0
    while i < len(lines):
        text = lines[i]
        if text.startswith("$ "):
            start, command = first_line + i, text[2:]
            while command.endswith("\\") and i + 1 < len(lines):
                i += 1
                command += "\n" + lines[i]   # bash reads backslash-newline as a continuation
            commands.append((start, command))
        i += 1
    return commands


class BlockFailed(AssertionError):
    """A documented example did not run as written."""


@dataclass
class FileRun:
    """One Markdown file's examples run in order: its folder, its interpreter, the outcomes."""

    path: Path
    document: Document
    examples: list[Example]
    folder: Path = field(init=False)
    next_index: int = 0
    outcomes: dict[int, BaseException | None] = field(default_factory=dict)
    worker: subprocess.Popen | None = None
    log: object = None

    def __post_init__(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix=f"docs-{self.path.stem}-"))

    # -- the environment both kinds of block see --------------------------------------
    def environment(self) -> dict[str, str]:
        env = dict(os.environ)
        bin_dir = str(Path(sys.executable).parent)
        env["PATH"] = bin_dir + os.pathsep + env.get("PATH", "")
        # This checkout's glraster, whichever one the venv was installed from.
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
        env["MPLBACKEND"] = "Agg"
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def output_tail(self) -> str:
        self.log.flush()
        text = (self.folder.parent / f"{self.folder.name}.log").read_text(errors="replace")
        return text[-OUTPUT_TAIL_CHARS:]

    # -- python ------------------------------------------------------------------------
    def _start_worker(self) -> None:
        self.log = open(self.folder.parent / f"{self.folder.name}.log", "w")
        request_read, self._request_write = os.pipe()
        self._reply_read, reply_write = os.pipe()
        self.worker = subprocess.Popen(
            [sys.executable, str(WORKER), str(request_read), str(reply_write)],
            cwd=self.folder, env=self.environment(), stdin=subprocess.DEVNULL,
            stdout=self.log, stderr=subprocess.STDOUT,
            pass_fds=(request_read, reply_write), start_new_session=True)
        os.close(request_read)
        os.close(reply_write)
        self._replies = os.fdopen(self._reply_read, "r", encoding="utf-8")

    def run_python(self, example: Example) -> None:
        block = block_of(example)
        if self.worker is None:
            self._start_worker()
        elif self.worker.poll() is not None:
            raise BlockFailed(f"{block.where}: the file's interpreter has exited "
                              f"(code {self.worker.returncode}) after an earlier block")
        # The block's source begins on the line after its opening fence.
        request = {"path": str(block.path), "line": block.line + 1, "source": block.source}
        os.write(self._request_write, (json.dumps(request) + "\n").encode())
        ready, _, _ = select.select([self._replies], [], [], PYTHON_BLOCK_TIMEOUT_S)
        if not ready:
            self.worker.kill()
            raise BlockFailed(f"{block.where}: the python block ran past "
                              f"{PYTHON_BLOCK_TIMEOUT_S} s\n--- output ---\n{self.output_tail()}")
        reply_line = self._replies.readline()
        if not reply_line:
            self.worker.wait()
            raise BlockFailed(f"{block.where}: the interpreter died running the python block "
                              f"(exit {self.worker.returncode})\n--- output ---\n"
                              f"{self.output_tail()}")
        reply = json.loads(reply_line)
        if not reply["ok"]:
            raise BlockFailed(f"{block.where}: the python block failed\n{reply['error']}"
                              f"--- output of the file's blocks so far ---\n{self.output_tail()}")

    # -- console -----------------------------------------------------------------------
    def run_console(self, example: Example) -> None:
        block = block_of(example)
        commands = console_commands(block.source, block.line + 1)
        if not commands:
            raise BlockFailed(f"{block.where}: a console block without a `$ ` command")
        for line, command in commands:
            process = subprocess.Popen(
                ["bash", "-o", "pipefail", "-c", command], cwd=self.folder,
                env=self.environment(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, start_new_session=True)
            try:
                output, _ = process.communicate(timeout=CONSOLE_COMMAND_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                end_process_group(process.pid)
                process.communicate()
                raise BlockFailed(f"{relative(block.path)}:{line}: `{command}` ran past "
                                  f"{CONSOLE_COMMAND_TIMEOUT_S} s") from None
            finally:
                end_process_group(process.pid)
            if process.returncode != 0:
                raise BlockFailed(f"{relative(block.path)}:{line}: `{command}` exited "
                                  f"{process.returncode}\n--- output ---\n"
                                  f"{output[-OUTPUT_TAIL_CHARS:]}")

    # -- in order ----------------------------------------------------------------------
    def outcome(self, index: int) -> BaseException | None:
        """Run the file's examples up to ``index`` (in order, once each); its outcome."""
        while self.next_index <= index:
            example = self.examples[self.next_index]
            try:
                example.evaluate()
                self.outcomes[self.next_index] = None
            except BaseException as error:  # noqa: BLE001 - SkipTest and failures alike
                self.outcomes[self.next_index] = error
            self.next_index += 1
        if self.next_index == len(self.examples):
            self.close()    # the file is done: its interpreter and what it left running go
        return self.outcomes[index]

    def close(self) -> None:
        """End the interpreter and what the blocks left running; remove the folder (idempotent)."""
        if self.worker is not None:
            os.close(self._request_write)
            try:
                self.worker.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.worker.kill()
                self.worker.wait()
            end_process_group(self.worker.pid)
            self._replies.close()
            self.log.close()
            (self.folder.parent / f"{self.folder.name}.log").unlink(missing_ok=True)
            self.worker = None
        shutil.rmtree(self.folder, ignore_errors=True)


_RUNS: dict[Document, FileRun] = {}


def run_of(document: Document) -> FileRun:
    return _RUNS[document]


def open_run(path: Path) -> FileRun:
    document = parse(path)
    run = FileRun(path, document, list(document.examples()))
    _RUNS[document] = run
    return run


def close_runs() -> None:
    for run in _RUNS.values():
        run.close()
    _RUNS.clear()

