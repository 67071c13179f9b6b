"""No documented example escapes the docs run, and every skip says why.

A CommonMark parser (markdown-it-py) independent of sybil's lexers lists the code blocks of
README.md and docs/*.md; these tests need no GL.
"""

from __future__ import annotations

import re

import pytest
from markdown_it import MarkdownIt

from tests.docs import markdown_blocks as mb

FILES = mb.documented_files()
IDS = [mb.relative(p) for p in FILES]

# Fence languages that would hold commands or Python the docs run would not see.
SHELL_LIKE = {"sh", "bash", "shell", "zsh", "shell-session", "sh-session", "terminal"}
PYTHON_LIKE = {"py", "python3", "pycon", "ipython"}
# The first word of an indented block that would be a command shown to be typed.
COMMAND_WORDS = {"$", "glraster", "make", "pip", "python", "python3", "curl", "docker",
                 "podman", "apt-get", "sudo", "bash", "pytest"}

SKIP_COMMENT = re.compile(r"^[ \t]*<!--+\s*skip:(.*?)--+>", re.DOTALL | re.MULTILINE)
SKIP_WITH_REASON = re.compile(r'\s*next\s+"([^"]*)"\s*$')


def code_blocks(path):
    """(first line, kind, info, content) of every code block, by markdown-it-py."""
    tokens = MarkdownIt("commonmark").parse(path.read_text())
    for token in tokens:
        if token.type in ("fence", "code_block"):
            yield token.map[0] + 1, token.type, token.info.strip(), token.content


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_every_python_and_console_block_is_collected(path):
    collected = {(b.line, b.language) for b in map(mb.block_of, (
        e for e in mb.parse(path).examples() if not mb.is_skip(e)))}
    fenced = {(line, info) for line, kind, info, _ in code_blocks(path)
              if kind == "fence" and info in ("python", "console")}
    assert fenced == collected, (
        f"{mb.relative(path)}: blocks the docs run does not see: "
        f"{sorted(fenced - collected)}; seen but not blocks: {sorted(collected - fenced)}")


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_commands_and_python_are_in_blocks_that_run(path):
    wrong = []
    for line, kind, info, content in code_blocks(path):
        language = info.split()[0] if info else ""
        if kind == "fence" and language in SHELL_LIKE | PYTHON_LIKE:
            wrong.append(f"line {line}: ```{language} (use ```console with `$ ` lines, or "
                         "```python)")
        first = content.split(maxsplit=1)[0] if content.strip() else ""
        if kind == "code_block" and first in COMMAND_WORDS:
            wrong.append(f"line {line}: an indented command ({first} ...): put it in a "
                         "```console block with `$ `")
        if kind == "fence" and language == "console" and not mb.console_commands(content, 1):
            wrong.append(f"line {line}: a ```console block without a `$ ` command")
    assert not wrong, f"{mb.relative(path)}:\n" + "\n".join(wrong)


def stale_test_references(reason):
    """What a skip reason names that does not exist: test files and test functions."""
    files = [mb.REPO / f for f in re.findall(r"tests/[\w/]+\.py", reason)]
    missing = [f"{mb.relative(f)} does not exist" for f in files if not f.is_file()]
    sources = "".join(f.read_text() for f in files if f.is_file())
    for name in re.findall(r"\btest_\w+", re.sub(r"tests/[\w/]+\.py", "", reason)):
        if f"def {name}(" not in sources:
            missing.append(f"no test {name} in {[mb.relative(f) for f in files]}")
    return missing


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_every_skip_has_a_reason_and_precedes_a_block(path):
    text = path.read_text()
    block_lines = {line for line, kind, info, _ in code_blocks(path)
                   if kind == "fence" and info in ("python", "console")}
    problems = []
    for match in SKIP_COMMENT.finditer(text):
        line = text.count("\n", 0, match.start()) + 1
        reason = SKIP_WITH_REASON.match(match.group(1))
        if reason is None or not reason.group(1).strip():
            problems.append(f'line {line}: write <!-- skip: next "reason" --> '
                            f"(got {match.group(0)!r})")
            continue
        problems += [f"line {line}: {p}" for p in stale_test_references(reason.group(1))]
        # The next non-blank line must open the block being skipped.
        rest = text[match.end():]
        next_start = match.end() + len(rest) - len(rest.lstrip())
        if text.count("\n", 0, next_start) + 1 not in block_lines:
            following = text[next_start:].split("\n", 1)[0]
            problems.append(f"line {line}: the skip is not right before a ```python or "
                            f"```console block (next: {following!r})")
    assert not problems, f"{mb.relative(path)}:\n" + "\n".join(problems)
