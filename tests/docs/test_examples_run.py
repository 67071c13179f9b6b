"""Every ```python and ```console block of README.md and docs/*.md runs as written.

One test per block, named ``FILE:LINE`` of its opening fence. The blocks of one file run in
file order in one fresh interpreter and one empty folder (tests/docs/markdown_blocks.py);
running a single block (``-k 'README.md:173'``) first runs the file's earlier blocks, whose
definitions it may use. A block after ``<!-- skip: next "reason" -->`` is reported as
skipped with that reason.
"""

from __future__ import annotations

import unittest

import pytest

from tests.docs import markdown_blocks as mb

# The examples render with the default backend (GLRASTER_BACKEND or auto), in subprocesses.
pytestmark = pytest.mark.gl


def _blocks():
    params = []
    for path in mb.documented_files():
        for index, example in enumerate(mb.parse(path).examples()):
            if not mb.is_skip(example):
                block = mb.block_of(example)
                params.append(pytest.param(path, index, id=block.where))
    return params


@pytest.fixture(scope="module")
def file_runs():
    runs: dict = {}

    def run_for(path):
        if path not in runs:
            runs[path] = mb.open_run(path)
        return runs[path]

    yield run_for
    mb.close_runs()


@pytest.mark.parametrize(("path", "index"), _blocks())
def test_documented_block_runs_as_written(file_runs, path, index):
    run = file_runs(path)
    outcome = run.outcome(index)
    if isinstance(outcome, unittest.SkipTest):
        pytest.skip(f"{mb.block_of(run.examples[index]).where}: {outcome}")
    if outcome is not None:
        raise outcome
