"""Subcommands of the ``glraster`` CLI: each module defines ``register(subparsers)``."""


def add_backend_argument(parser) -> None:
    """The ``--backend`` option every command that opens a GL context shares."""
    parser.add_argument("--backend", default=None, choices=("auto", "egl", "osmesa"),
                        help="OpenGL backend (default: $GLRASTER_BACKEND or auto)")
