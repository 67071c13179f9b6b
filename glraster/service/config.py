"""What a ``glraster serve`` process is configured with: address, workers, limits, auth.

Every limit is enforced before the work it guards: the body size while the body is read,
vertex and triangle counts from the arrays' shapes (for .npz before a byte is decompressed),
the resolution against both the configured maximum and the driver's (the smaller wins),
and the deadline from the moment the request arrived (queueing included).
"""

from __future__ import annotations

import ipaddress
import math
import os
import stat
from dataclasses import dataclass, field, replace
from pathlib import Path

from glraster.errors import ArgumentError

MiB = 1 << 20

# The shortest bearer token a token file may hold (a guessable token is no protection).
MIN_TOKEN_LENGTH = 16


@dataclass(frozen=True)
class Limits:
    """Per-request limits (checked in the worker that parses the request).

    max_body_bytes : request body size (413 above it; also bounds a member of an .npz)
    max_vertices   : rows of ``pos``
    max_triangles  : rows of ``tri``
    max_resolution : largest height or width; the driver's maximum applies as well
    max_deadline   : largest deadline a request may ask for (``?deadline=S``), seconds
    """

    max_body_bytes: int = 64 * MiB
    max_vertices: int = 1 << 21
    max_triangles: int = 1 << 21
    max_resolution: int = 4096
    max_deadline: float = 30.0


@dataclass(frozen=True)
class ServiceConfig:
    """Configuration of one service replica (``glraster serve``; docs/service.md).

    host, port       : where uvicorn listens; loopback unless told otherwise
    workers          : GL worker processes, each owning one context
    queue_size       : requests waiting for a worker beyond those being rendered; a request
                       that finds the queue full gets 429 with Retry-After
    backend          : GL backend of the workers ("auto", "egl", "osmesa"; None: the
                       environment's $GLRASTER_BACKEND)
    tokens           : accepted bearer tokens (empty: no authentication)
    limits           : :class:`Limits`
    deadline         : default deadline of a rasterize request, seconds from arrival
    check_deadline   : deadline of a conformance check request
    body_timeout     : a request body not received within this many seconds gets 408
    worker_start_timeout : a worker that reports no working context within this is replaced
    drain_timeout    : on SIGTERM/SIGINT, how long in-flight requests may still finish
    """

    host: str = "127.0.0.1"
    port: int = 8642
    workers: int = 1
    queue_size: int = 16
    backend: str | None = None
    tokens: tuple = field(default=(), repr=False)
    limits: Limits = Limits()
    deadline: float = 30.0
    check_deadline: float = 600.0
    body_timeout: float = 30.0
    worker_start_timeout: float = 120.0
    drain_timeout: float | None = None
    log_level: str = "warning"

    def __post_init__(self):
        for name in ("workers", "queue_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "workers" else 0):
                raise ArgumentError(name, f"{name} must be an integer >= "
                                          f"{1 if name == 'workers' else 0}, got {value!r}")
        if not (0 <= int(self.port) <= 65535):
            raise ArgumentError("port", f"port must be in [0, 65535], got {self.port}")
        seconds = {name: getattr(self, name) for name in (
            "deadline", "check_deadline", "body_timeout", "worker_start_timeout")}
        seconds["max_deadline"] = self.limits.max_deadline
        for name, value in seconds.items():   # inf too: the request models need a bound
            if not 0 < float(value) < math.inf:
                raise ArgumentError(name, f"{name} must be a finite number > 0 seconds, "
                                          f"got {value!r}")
        if self.drain_timeout is not None and not 0 <= float(self.drain_timeout) < math.inf:
            raise ArgumentError("drain_timeout", f"drain_timeout must be None or a finite "
                                                 f"number >= 0 seconds, got "
                                                 f"{self.drain_timeout!r}")
        if self.backend not in (None, "auto", "egl", "osmesa"):
            raise ArgumentError("backend", f"backend must be auto, egl or osmesa, "
                                           f"got {self.backend!r}")

    @property
    def effective_drain_timeout(self) -> float:
        """Seconds in-flight requests get on shutdown (default: a deadline plus margin)."""
        if self.drain_timeout is not None:
            return float(self.drain_timeout)
        return float(self.deadline) + 5.0

    @property
    def loopback(self) -> bool:
        """True when ``host`` is a loopback address (or ``localhost``)."""
        return is_loopback(self.host)

    def with_limits(self, **changes) -> "ServiceConfig":
        return replace(self, limits=replace(self.limits, **changes))


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is on the loopback interface."""
    if host in ("localhost", "localhost.localdomain"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def read_token_file(path) -> tuple[str, ...]:
    """The bearer tokens in ``path``: one per line, blank lines and ``#`` comments ignored
    (several lines let a token be rotated without downtime). ValueError naming the file
    when it is missing, empty, holds a token shorter than ``MIN_TOKEN_LENGTH`` (16)
    characters or with whitespace, or is readable by others than its owner and group."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
        text = p.read_text()
    except OSError as exc:
        raise ArgumentError("token_file",
                            f"token file {str(p)!r}: {exc.strerror or exc}") from None
    if mode & stat.S_IROTH:
        raise ArgumentError("token_file", f"token file {str(p)!r} is readable by every user "
                                          f"(mode {stat.filemode(mode)}); chmod o-r it")
    tokens = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        problem = (f"it has {len(line)} characters" if len(line) < MIN_TOKEN_LENGTH
                   else "it holds a space" if any(c.isspace() for c in line)
                   else "it holds a character that is not printable"
                   if not line.isprintable() else None)
        if problem:
            raise ArgumentError(
                "token_file", f"token file {str(p)!r} line {n}: {problem}; a token must be at "
                              f"least {MIN_TOKEN_LENGTH} printable characters without spaces "
                              "(make one with: python -c \"import secrets; "
                              "print(secrets.token_urlsafe(32))\")")
        tokens.append(line)
    if not tokens:
        raise ArgumentError("token_file", f"token file {str(p)!r} holds no token")
    return tuple(tokens)


def default_workers() -> int:
    """One worker per core available to this process (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
