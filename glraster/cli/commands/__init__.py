"""Subcommands of the ``glraster`` CLI: each module defines ``register(subparsers)``."""

import argparse


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
