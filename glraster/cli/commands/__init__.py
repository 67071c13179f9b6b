"""Subcommands of the ``glraster`` CLI: each module defines ``register(subparsers)``."""

import argparse
import math


def add_backend_argument(parser) -> None:
    """The ``--backend`` option every command that opens a GL context shares."""
    parser.add_argument("--backend", default=None, choices=("auto", "egl", "osmesa"),
                        help="OpenGL backend (default: $GLRASTER_BACKEND or auto)")


def add_command(subparsers, name: str, doc: str):
    """The parser of subcommand ``name`` from its module docstring ``doc``: the first line
    (after "`glraster NAME`: ") is the one-line help, the paragraphs below the description."""
    title, _, details = doc.strip().partition("\n\n")
    summary = title.split(": ", 1)[-1].rstrip(".")
    return subparsers.add_parser(name, help=summary,
                                 description=" ".join(details.split()) or summary)


def comma_list(text: str) -> str:
    """argparse ``type`` of a comma-separated list option (``--scenes``, ``--outputs``,
    ...): the text unchanged, refused when it lists nothing (``''``, ``','``), which the
    command would otherwise read as the option left out (``--scenes "$UNSET"`` running the
    whole catalog)."""
    if not any(item.strip() for item in text.split(",")):
        raise argparse.ArgumentTypeError(f"lists nothing (got {text!r}): name at least one")
    return text


def _finite_number(text: str, least: float, strict: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < least or (strict and value == least):
        raise argparse.ArgumentTypeError(
            f"must be a finite number {'>' if strict else '>='} {least:g}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse ``type`` of a float option that must be a finite number > 0 (a learning
    rate, a deadline, a size): ``nan``, ``inf`` and ``-1`` are usage errors naming the
    option, never a server that starts with them or a fit that diverges."""
    return _finite_number(text, 0.0, strict=True)


def non_negative_float(text: str) -> float:
    """argparse ``type`` of a float option that must be a finite number >= 0 (a tolerance,
    a drain time where 0 is meaningful)."""
    return _finite_number(text, 0.0, strict=False)
