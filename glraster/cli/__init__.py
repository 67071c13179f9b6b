"""The ``glraster`` command line.

Every module in :mod:`glraster.commands` defines ``register(subparsers)``, which adds its
subcommand(s) with ``set_defaults(func=handler)``; ``handler(args)`` returns the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from glraster._version import __version__
from glraster.cli import commands, exit_codes
from glraster.errors import BackendUnavailable, ShaderCompileError


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
    return parser


# optional dependency -> the pyproject extra that installs it
OPTIONAL_EXTRAS = {"torch": "torch", "starlette": "service", "uvicorn": "service",
                   "trimesh": "mesh", "pyrender": "mesh", "ray": "ray"}


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return exit_codes.USAGE
    try:
        return int(args.func(args) or exit_codes.OK)
    except BackendUnavailable as exc:
        print(f"glraster {args.command}: error: {exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    except (ValueError, FileNotFoundError, ShaderCompileError) as exc:
        print(f"glraster {args.command}: error: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    except ModuleNotFoundError as exc:
        extra = OPTIONAL_EXTRAS.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"glraster {args.command}: error: this command needs {exc.name}: "
              f"pip install 'glraster[{extra}]'", file=sys.stderr)
        return exit_codes.USAGE
