"""The ``glraster`` command line.

Every module in :mod:`glraster.commands` defines ``register(subparsers)``, which adds its
subcommand(s) with ``set_defaults(func=handler)``; ``handler(args)`` returns the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import signal
import sys
import threading

from glraster._version import __version__
from glraster.cli import commands, exit_codes
from glraster.cli.errors import describe, name_options
from glraster.errors import BackendUnavailable, ShaderCompileError, needs_extra
from glraster.io.destinations import refuse_unwritable_defaults


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="glraster",
        description="Headless GPU rasterization of barycentric coordinates, checked "
                    "against an analytic float64 reference.",
    )
    parser.add_argument("--version", action="version", version=f"glraster {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"{commands.__name__}.{module.name}").register(subparsers)
    name_options(parser)   # errors name the option at fault (glraster.cli.errors)
    return parser


def main(argv=None) -> int:
    """Run one command; every error is one line on stderr and an exit code of
    :mod:`glraster.cli.exit_codes` (a traceback only for a bug in glraster)."""
    terminate = _raise_on_sigterm()
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # Every file glraster writes goes through glraster.io.atomic: an interrupted write
        # leaves the previous file (or none) and no temporary file.
        _quiet_stdout()
        print("glraster: interrupted", file=sys.stderr)
        return exit_codes.INTERRUPTED
    except Terminated:
        _quiet_stdout()
        print("glraster: terminated", file=sys.stderr)
        return exit_codes.TERMINATED
    except BrokenPipeError:
        _quiet_stdout()
        return exit_codes.BROKEN_PIPE
    finally:
        if terminate is not None:
            signal.signal(signal.SIGTERM, terminate)


class Terminated(BaseException):
    """SIGTERM (a CI job cancelled or timed out), raised where the command is, so that its
    clean-up runs as for Ctrl-C (without it, Python dies at once and leaves temporary files
    and staged folders behind)."""


def _terminated(signum, frame):
    raise Terminated


def _raise_on_sigterm():
    """Make SIGTERM raise :class:`Terminated` (main thread only, where handlers can be set,
    and only over the default action); returns the handler to put back, or None."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return None
    return signal.signal(signal.SIGTERM, _terminated)


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush of what is still
    buffered (to a pipe that is closed, or mid-interrupt) cannot fail a second time."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass  # stdout is no file (captured in-process): nothing is flushed to a pipe


def _main(argv) -> int:
    parser = build_parser()
    args = _parse(parser, sys.argv[1:] if argv is None else list(argv))
    if not getattr(args, "func", None):
        parser.print_help()
        return exit_codes.USAGE
    try:
        code = int(args.func(args) or exit_codes.OK)
        sys.stdout.flush()  # a closed pipe shows up here, not at interpreter exit
        return code
    except BackendUnavailable as exc:
        print(f"glraster {args.command}: error: {exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    except (ValueError, ShaderCompileError) as exc:
        print(f"glraster {args.command}: error: {describe(exc, args)}", file=sys.stderr)
        return exit_codes.USAGE
    except ModuleNotFoundError as exc:
        error = needs_extra("this command", exc)
        if error is exc:   # a module no extra of glraster installs: a bug, with traceback
            raise
        print(f"glraster {args.command}: error: {error}", file=sys.stderr)
        return exit_codes.USAGE
    except BrokenPipeError:
        raise
    except OSError as exc:  # a file that cannot be read or written, a full disk
        print(f"glraster {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
        return exit_codes.USAGE


def _parse(parser: argparse.ArgumentParser, argv: list) -> argparse.Namespace:
    """``parser.parse_args(argv)``, except that an argument no parser knows is refused by
    the (sub)command it was given to, with that command's usage ("glraster fit cube:
    error: unrecognized arguments: --itrations 5"), not the top level's, and that output
    options left at their defaults are judged too (:mod:`glraster.io.destinations`)."""
    args, extra = parser.parse_known_args(argv)
    command = _command_parser(parser, argv)
    if extra:
        command.error(f"unrecognized arguments: {' '.join(extra)}")
    refuse_unwritable_defaults(command, args)   # (given ones were judged as parsed)
    return args


def _command_parser(parser: argparse.ArgumentParser, argv: list) -> argparse.ArgumentParser:
    """The innermost (sub)command parser that ``argv`` names."""
    while True:
        commands = next((a.choices for a in parser._actions
                         if isinstance(a, argparse._SubParsersAction)), None)
        name = next((t for t in argv if t in commands), None) if commands else None
        if name is None:
            return parser
        parser, argv = commands[name], argv[argv.index(name) + 1:]


def describe_os_error(exc: OSError) -> str:
    """"cannot write out.exr: Permission denied" style text of an OSError."""
    if exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc)
