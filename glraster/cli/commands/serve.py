"""`glraster serve`: run the HTTP rendering service (needs the [service] extra).

Serve POST /v1/rasterize, POST /v1/check, GET /v1/info, /healthz, /readyz, /metrics and
/openapi.json (docs/service.md). Each worker process owns one GL context; requests beyond
the workers wait in a bounded queue (429 with Retry-After when it is full). SIGTERM or
SIGINT drains in-flight requests, then stops. Binds to loopback unless --host says
otherwise.
"""

from __future__ import annotations

import json
import sys

from glraster.cli import exit_codes
from glraster.cli.commands import (
    add_backend_argument,
    add_command,
    non_negative_float,
    positive_float,
)
from glraster.errors import ArgumentError
from glraster.io.destinations import OutputFile


def register(subparsers) -> None:
    p = add_command(subparsers, "serve", __doc__)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1; 0.0.0.0 for every interface)")
    p.add_argument("--port", type=int, default=8642, help="port (default 8642; 0: any free)")
    p.add_argument("--workers", type=int, default=None,
                   help="GL worker processes (default: one per available core)")
    p.add_argument("--queue", dest="queue_size", type=int, default=None, metavar="N",
                   help="requests that may wait for a worker (default 4 per worker)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help="require 'Authorization: Bearer TOKEN' with a token from FILE (one per "
                        "line; not readable by others)")
    add_backend_argument(p)
    p.add_argument("--max-body", type=positive_float, default=64, metavar="MiB",
                   help="largest request body (default 64 MiB)")
    p.add_argument("--max-vertices", type=int, default=1 << 21, metavar="N")
    p.add_argument("--max-triangles", type=int, default=1 << 21, metavar="N")
    p.add_argument("--max-resolution", type=int, default=4096, metavar="PX",
                   help="largest height or width (default 4096; the driver's maximum applies "
                        "too)")
    p.add_argument("--deadline", type=positive_float, default=30.0, metavar="S",
                   help="seconds a rasterize request may take from arrival (default 30); "
                        "past it the request is cancelled (504) and its worker replaced")
    p.add_argument("--max-deadline", type=positive_float, default=None, metavar="S",
                   help="largest ?deadline= a request may ask for (default: --deadline)")
    p.add_argument("--check-deadline", type=positive_float, default=600.0, metavar="S",
                   help="seconds a conformance check request may take (default 600)")
    p.add_argument("--body-timeout", type=positive_float, default=30.0, metavar="S",
                   help="a body not received within S seconds gets 408 (default 30)")
    p.add_argument("--drain-timeout", type=non_negative_float, default=None, metavar="S",
                   help="on shutdown, how long in-flight requests may finish (default: "
                        "--deadline + 5)")
    p.add_argument("--log-level", default="warning",
                   choices=("critical", "error", "warning", "info", "debug"))
    p.add_argument("--print-openapi", action="store_true",
                   help="print the OpenAPI schema (docs/openapi.json) and exit")
    p.set_defaults(func=run)

    b = subparsers.add_parser(
        "serve-bench", help="load-test a glraster service on loopback (a benchmark, not a test)",
        description="Start 'glraster serve' on 127.0.0.1 (or use --url, loopback only) and "
                    "measure throughput and p50/p99 latency at several concurrencies, the "
                    "per-request overhead over an in-process call, sustained throughput "
                    "against in-process loops and memory over many requests. Every loop is "
                    "bounded in count and time.")
    add_backend_argument(b)
    b.add_argument("--url", default=None, help="an already running service (loopback only)")
    b.add_argument("--token-file", default=None, metavar="FILE")
    b.add_argument("--workers", type=int, default=2, help="workers of the started server")
    b.add_argument("--quick", action="store_true", help="small counts (a smoke run, ~20 s)")
    b.add_argument("--memory-requests", type=int, default=10_000, metavar="N",
                   help="requests of the memory run (default 10000; 0 skips it)")
    b.add_argument("--json", action=OutputFile,
                   default=None, metavar="FILE", help="write the figures as JSON")
    b.set_defaults(func=run_bench)


def _config(args):
    from glraster.service.config import (
        Limits,
        MiB,
        ServiceConfig,
        default_workers,
        read_token_file,
    )

    workers = args.workers if args.workers is not None else default_workers()
    tokens = read_token_file(args.token_file) if args.token_file else ()
    limits = Limits(max_body_bytes=int(args.max_body * MiB), max_vertices=args.max_vertices,
                    max_triangles=args.max_triangles, max_resolution=args.max_resolution,
                    max_deadline=(args.deadline if args.max_deadline is None
                                  else args.max_deadline))
    for name in ("max_vertices", "max_triangles", "max_resolution"):
        if getattr(limits, name) < 1:
            option = "--" + name.replace("_", "-")
            raise ArgumentError(option, f"{option} must be >= 1")
    if limits.max_body_bytes < 1024:
        raise ArgumentError("--max-body", "--max-body must be at least 1 KiB")
    return ServiceConfig(
        host=args.host, port=args.port, workers=workers,
        queue_size=args.queue_size if args.queue_size is not None else 4 * workers,
        backend=args.backend, tokens=tokens, limits=limits, deadline=args.deadline,
        check_deadline=args.check_deadline, body_timeout=args.body_timeout,
        drain_timeout=args.drain_timeout, log_level=args.log_level)


def run(args) -> int:
    try:
        import msgspec  # noqa: F401  (the request models, also for --print-openapi)

        if args.print_openapi:   # the schema of a server with these flags (limits, tokens)
            from glraster.service.openapi import schema

            print(json.dumps(schema(_config(args)), indent=2, sort_keys=True))
            return exit_codes.OK
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as exc:
        print(f"glraster serve: the service needs the [service] extra "
              f"(pip install 'glraster[service]'): {exc}", file=sys.stderr)
        return exit_codes.USAGE
    config = _config(args)   # ValueError -> exit 2 through main
    from glraster.service.app import serve

    started = []

    def announce(line):  # called once the socket is bound, before the server runs
        started.append(line)
        if not config.loopback and not config.tokens:
            print(f"glraster serve: warning: listening on {config.host} without "
                  "--token-file: anyone who can reach this address can use the service",
                  file=sys.stderr)
        print(line, flush=True)

    try:
        return serve(config, announce=announce)
    except OSError as exc:
        if started:
            raise
        print(f"glraster serve: {bind_error(args.host, args.port, exc)}", file=sys.stderr)
        return exit_codes.USAGE


def bind_error(host: str, port: int, exc: OSError) -> str:
    """One line saying why ``host``:``port`` cannot be listened on, and what to do."""
    import errno
    import socket

    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    if isinstance(exc, socket.gaierror):
        return (f"cannot listen on {where}: --host {host!r} does not resolve "
                f"({exc.strerror or exc}); give an IP address or a name this machine knows")
    reasons = {
        errno.EADDRINUSE: "the port is in use by another process; pick another --port "
                          "(--port 0: any free one)",
        errno.EACCES: "permission denied (ports below 1024 need privileges); pick a "
                      "--port of 1024 or more",
        errno.EADDRNOTAVAIL: "the address is not one of this machine's; pick another --host "
                             "(127.0.0.1, 0.0.0.0)",
    }
    return f"cannot listen on {where}: " + reasons.get(exc.errno, exc.strerror or str(exc))


def run_bench(args) -> int:
    from glraster.studies import loadtest

    return loadtest.run(args)
