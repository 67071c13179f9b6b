"""`glraster junit-merge`: merge the JUnit files of 'glraster check --shard I/N' runs.

Join JUnit files written by 'glraster check --junit' (typically one per CI runner with
--shard I/N, for one or several drivers) into one file: the shards of each driver and
method become one suite again. Fails (exit 1) when a shard is missing or given twice, a
scene appears in two files, or any test case failed; the merged file is written in every
case but the first two.
"""

from __future__ import annotations

import sys

from glraster.cli import exit_codes
from glraster.cli.commands import add_command
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "junit-merge", __doc__)
    p.add_argument("inputs", nargs="+", metavar="JUNIT.xml", help="the shards' JUnit files")
    p.add_argument("-o", "--output", action=OutputFile, required=True, metavar="OUT.xml",
                   help="merged JUnit file to write")
    p.set_defaults(func=run)


def run(args) -> int:
    from glraster.conformance import junit

    try:
        tree = junit.merge(args.inputs)
    except junit.MergeError as exc:
        print(f"glraster junit-merge: {exc}", file=sys.stderr)
        return exit_codes.FAIL
    except OSError as exc:
        print(f"glraster junit-merge: cannot read the inputs: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    path = junit.write_tree(tree, args.output)
    root = tree.getroot()
    tests, failures, errors = (int(root.get(k)) for k in ("tests", "failures", "errors"))
    suites = len(root.findall("testsuite"))
    print(f"{path}: {tests} test cases in {suites} suite(s) from {len(args.inputs)} file(s); "
          f"{failures} failed, {errors} errors")
    return exit_codes.OK if failures == errors == 0 else exit_codes.FAIL
