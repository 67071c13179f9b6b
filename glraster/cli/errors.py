"""The one-line message of a bad-input error, naming the command-line argument at fault.

glraster's errors about an argument are :class:`glraster.errors.ArgumentError`: their
``.argument`` names the library argument (``outputs``, ``resolution``) or, for a check of
the command line itself, the option (``--shard-size``). A command passes option values on
to the library under the option's dest (``--outputs`` -> ``outputs``), so the option the
user typed is found from ``.argument``, never from the message's wording.
"""

from __future__ import annotations

import argparse

from glraster.errors import ArgumentError


def options_of(parser: argparse.ArgumentParser) -> dict[str, str]:
    """dest -> the argument as the user writes it: "-o/--output" for an option, the
    metavar ("OUT") for a positional, for each argument of ``parser`` (help aside)."""
    out = {}
    for action in parser._actions:   # argparse offers no public list of a parser's arguments
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) \
                or action.dest == argparse.SUPPRESS:
            continue
        if action.option_strings:
            out[action.dest] = "/".join(action.option_strings)
        else:
            out[action.dest] = action.metavar if isinstance(action.metavar, str) \
                else action.dest.upper()
    return out


def name_options(parser: argparse.ArgumentParser, inherited: dict | None = None) -> None:
    """Give every (sub)command's namespace ``cli_options``: :func:`options_of` its parser
    and the parsers above it, for :func:`describe`."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                options = {**(inherited or {}), **options_of(sub)}
                sub.set_defaults(cli_options=options)
                name_options(sub, options)


def describe(exc: Exception, args: argparse.Namespace | None = None) -> str:
    """The message of ``exc``, preceded by "argument --option: " when it is an
    :class:`ArgumentError` about an argument of the command line (``args.cli_options``,
    set by :func:`glraster.cli.build_parser`) that the message does not already start with."""
    message = str(exc)
    if not isinstance(exc, ArgumentError):
        return message
    options = getattr(args, "cli_options", None) or {}
    if exc.argument.startswith("-"):
        spelled = exc.argument
    else:
        spelled = options.get(exc.argument)
    if spelled is None or any(message.startswith(s) for s in spelled.split("/")):
        return message
    return f"argument {spelled}: {message}"
