"""`glraster study`: list the measurement studies, or run one by name.

`glraster study --list` prints every study (benchmarks, figures, A/B timings) with a line
on what it measures and the extra it needs. `glraster study NAME [options]` runs one; the
options are the study's own (`glraster study NAME --help`). Studies that have their own
command (`glraster bench`, `glraster stress`, ...) run as that command with the same
options. Studies measure and print; none of them is a pass/fail test.
"""

from __future__ import annotations

import argparse

from glraster.cli import exit_codes
from glraster.cli.commands import add_command


def register(subparsers) -> None:
    p = add_command(subparsers, "study", __doc__)
    p.add_argument("--list", action="store_true", help="list the studies and exit")
    p.add_argument("name", nargs="?", metavar="NAME", help="the study to run")
    p.add_argument("options", nargs=argparse.REMAINDER, metavar="...",
                   help="the study's own options (glraster study NAME --help)")
    p.set_defaults(func=run)


def run(args) -> int:
    from glraster.studies import registry

    if args.list or args.name is None:
        print_list(registry.STUDIES.values())
        return exit_codes.OK if args.list else exit_codes.USAGE
    study = registry.get(args.name)             # ArgumentError (exit 2) for an unknown name
    if study.command is not None:
        from glraster.cli import main

        return main([study.command, *args.options])
    return registry.run(study.name, args.options)


def print_list(studies) -> None:
    """One line per study: name, what it measures, how it runs and the extra it needs."""
    studies = sorted(studies, key=lambda s: (s.command is None, s.name))
    width = max(len(s.name) for s in studies)
    for s in studies:
        notes = [f"= glraster {s.command}"] if s.command else []
        if s.extra:
            notes.append(f"needs glraster[{s.extra}]")
        note = f"  ({'; '.join(notes)})" if notes else ""
        print(f"{s.name:<{width}}  {s.summary}{note}")
