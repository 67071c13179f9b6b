"""Judging where a command will write before it runs.

A long run (a fit, the conformance suite, a benchmark) that fails only at its last write
loses the run. :class:`OutputFile` and :class:`OutputFolder` are argparse actions that
refuse such an option when the command line is parsed: one line on stderr naming the
option, exit code 2 (argparse's own for a bad command line), nothing made. argparse runs
no action for an option left at its default (``out/fit/cube``, say):
:func:`refuse_unwritable_defaults` judges those once the command line is parsed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def unwritable_reason(path, folder: bool = False) -> str | None:
    """Why a file (``folder=False``) or a folder cannot be made at ``path``, judged without
    making anything: a folder stands where the file must go (or a file where the folder
    must), a file stands where a folder above it must be, or the nearest existing folder
    is read-only; None when none of these (the write can still fail: a full disk, say)."""
    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        return f"{path} is a {'file, not a folder' if folder else 'folder, not a file'}"
    for above in path.parents:   # nearest first; a relative path ends at "."
        if above.exists():
            if not above.is_dir():
                return f"{above} is a file, not a folder"
            if not os.access(above, os.W_OK | os.X_OK):
                return f"{above} is not writable"
            return None
    return None


def refuse_unwritable(parser: argparse.ArgumentParser, option: str, value,
                      folder: bool = False) -> None:
    """Exit 2 with one line "PROG: error: argument OPTION: cannot write VALUE (why)" when
    :func:`unwritable_reason` finds a reason; nothing when ``value`` is None."""
    reason = None if value is None else unwritable_reason(value, folder)
    if reason is not None:
        parser.exit(2, f"{parser.prog}: error: argument {option}: cannot write {value} "
                       f"({reason})\n")


class OutputFile(argparse.Action):
    """``action=`` of an option naming a file to write (:func:`refuse_unwritable`)."""

    folder = False

    def __call__(self, parser, namespace, values, option_string=None):
        refuse_unwritable(parser, "/".join(self.option_strings) or self.metavar or self.dest,
                          values, self.folder)
        setattr(namespace, self.dest, values)


class OutputFolder(OutputFile):
    """``action=`` of an option naming a folder to write into (made if missing)."""

    folder = True


def refuse_unwritable_defaults(parser: argparse.ArgumentParser,
                               namespace: argparse.Namespace) -> None:
    """:func:`refuse_unwritable` for each :class:`OutputFile` option of ``parser`` that
    ``namespace`` holds at its default (not given on the command line)."""
    for action in parser._actions:
        if isinstance(action, OutputFile) and action.default is not None \
                and getattr(namespace, action.dest, None) is action.default:
            refuse_unwritable(parser, "/".join(action.option_strings) or action.metavar
                              or action.dest, action.default, action.folder)
