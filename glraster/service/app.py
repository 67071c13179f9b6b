"""The ASGI app (Starlette) and the uvicorn server of ``glraster serve``.

The event loop does only HTTP: authentication, the body (size limit, read timeout), content
negotiation, the queue and the deadline. Parsing, validation, rendering and encoding happen
in the worker processes (:mod:`glraster.service.worker`), so a hostile body costs the
server no more than reading it. Every refusal is JSON ``{"error", "field", "status"}``.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import json
import socket
import sys
import time

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import ClientDisconnect, Request
from starlette.responses import Response
from starlette.routing import Route

from glraster._version import __version__
from glraster.service import models, openapi, protocol
from glraster.service.config import ServiceConfig
from glraster.service.metrics import CONTENT_TYPE, Metrics
from glraster.service.pool import Job, Outcome, QueueFull, Unavailable, WorkerPool

_ACCEPT_RASTER = {"application/json": "json", "application/x-npz": "npz",
                  "application/npz": "npz", "image/x-exr": "exr", "image/exr": "exr",
                  "*/*": "json", "application/*": "json"}
_ACCEPT_CHECK = {"application/json": "json", "application/xml": "junit", "text/xml": "junit",
                 "application/junit+xml": "junit", "*/*": "json", "application/*": "json"}
_CONTENT = {"application/json": protocol.JSON, "application/x-npz": protocol.NPZ,
            "application/npz": protocol.NPZ}


def _json(status: int, doc, headers=None) -> Response:
    return Response(json.dumps(doc), status_code=status, media_type="application/json",
                    headers=headers)


def _refuse(exc: protocol.RequestError) -> Response:
    headers = dict(exc.headers)
    if exc.status in (408, 413):
        headers["connection"] = "close"    # the rest of the body is not read
    return _json(exc.status, exc.body(), headers)


def _negotiate(header: str | None, table: dict) -> str:
    """The first acceptable result type of an Accept header (by q, then order)."""
    if not header:
        return table["*/*"]
    choices = []
    for n, part in enumerate(header.split(",")):
        media, *params = (s.strip() for s in part.split(";"))
        q = 1.0
        for p in params:
            if p.startswith("q="):
                try:
                    q = float(p[2:])
                except ValueError:
                    q = 0.0
        if q > 0:
            choices.append((-q, n, media.lower()))
    for _, _, media in sorted(choices):
        if media in table:
            return table[media]
    raise protocol.RequestError(406, "accept", f"cannot produce any of {header[:200]!r}; "
                                               f"offered: {', '.join(sorted(set(table) - {'*/*', 'application/*'}))}")


def _token_digest(token: str) -> bytes:
    return hashlib.sha256(token.encode("utf-8", "surrogateescape")).digest()


class Service:
    """The app's state: config, metrics, pool; ``app`` is the Starlette application."""

    def __init__(self, config: ServiceConfig):
        self.config = config
        self.metrics = Metrics()
        self.pool = WorkerPool(config, self.metrics)
        self.metrics.watch(self.pool)
        self.draining = False
        self.started = time.time()
        self._digests = tuple(_token_digest(t) for t in config.tokens)
        self._models = models.for_config(config)
        self._schema = json.dumps(openapi.schema(config), indent=2, sort_keys=True).encode()
        routes = [
            Route("/v1/rasterize", self.rasterize, methods=["POST"]),
            Route("/v1/check", self.check, methods=["POST"]),
            Route("/v1/info", self.info, methods=["GET"]),
            Route("/healthz", self.healthz, methods=["GET"]),
            Route("/readyz", self.readyz, methods=["GET"]),
            Route("/metrics", self.metrics_text, methods=["GET"]),
            Route("/openapi.json", self.openapi_json, methods=["GET"]),
        ]
        self.app = Starlette(routes=routes, lifespan=self._lifespan,
                             exception_handlers={HTTPException: self._http_error,
                                                 Exception: self._crash})

    # -- lifecycle ------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def _lifespan(self, app):
        self.pool.start()
        try:
            yield
        finally:
            self.draining = True
            await self.pool.stop()

    # -- errors ---------------------------------------------------------------------------
    async def _http_error(self, request, exc):
        field = {404: "path", 405: "method"}.get(exc.status_code, "request")
        self.metrics.observe("other", exc.status_code, 0.0)
        return _json(exc.status_code, {"error": str(exc.detail), "field": field,
                                       "status": exc.status_code}, getattr(exc, "headers", None))

    async def _crash(self, request, exc):
        self.metrics.observe("other", 500, 0.0)
        print(f"glraster serve: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return _json(500, {"error": f"internal error ({type(exc).__name__})", "field": "server",
                           "status": 500})

    # -- helpers --------------------------------------------------------------------------
    def _authorize(self, request: Request) -> None:
        if not self._digests:
            return
        header = request.headers.get("authorization")
        challenge = {"www-authenticate": 'Bearer realm="glraster"'}
        if not header:
            raise protocol.RequestError(401, "authorization", "a bearer token is required "
                                        "(Authorization: Bearer TOKEN)", challenge)
        scheme, _, token = header.partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise protocol.RequestError(401, "authorization", "the Authorization header must "
                                        "be 'Bearer TOKEN'", challenge)
        digest = _token_digest(token.strip())
        ok = False
        for known in self._digests:   # every token compared, in constant time
            ok |= hmac.compare_digest(digest, known)
        if not ok:
            raise protocol.RequestError(403, "authorization", "the bearer token is not accepted")

    async def _body(self, request: Request) -> bytes:
        limit = self.config.limits.max_body_bytes
        length = request.headers.get("content-length")
        if length is not None:
            if not length.isdigit():
                raise protocol.RequestError(400, "content-length", "Content-Length must be a "
                                                                   "non-negative integer")
            if int(length) > limit:
                raise protocol.RequestError(413, "body", f"the body has {int(length)} bytes, "
                                            f"above this server's limit of {limit}")
        chunks, size = [], 0
        # the read times out by a timer cancelling this task (no task of its own, which
        # would cost the request two more turns of the event loop)
        task = asyncio.current_task()
        timed_out = []

        def time_out():
            timed_out.append(True)
            task.cancel()

        timer = asyncio.get_running_loop().call_later(self.config.body_timeout, time_out)
        try:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise protocol.RequestError(413, "body", f"the body exceeds this server's "
                                                             f"limit of {limit} bytes")
                chunks.append(chunk)
        except asyncio.CancelledError:
            if not timed_out:
                raise
            raise protocol.RequestError(408, "body", f"the body was not received within "
                                        f"{self.config.body_timeout:g} s") from None
        except ClientDisconnect:
            raise protocol.RequestError(400, "body", "the client disconnected") from None
        finally:
            timer.cancel()
        return chunks[0] if len(chunks) == 1 else b"".join(chunks)

    def _query(self, request: Request, kind: str):
        """The query parameters as the endpoint's query model (``models.RasterizeQuery`` or
        ``CheckQuery``): unknown, repeated or invalid ones are 422 naming the parameter."""
        try:
            return self._models.query(kind, request.query_params.multi_items())
        except models.ModelError as exc:
            raise protocol.RequestError(422, exc.field, exc.message) from None

    async def _run(self, kind: str, meta: dict, body: bytes, arrived: float,
                   deadline: float) -> Response:
        loop = asyncio.get_running_loop()
        meta["deadline"] = deadline
        job = Job(kind, meta, body, arrived + deadline, loop)
        try:
            self.pool.submit(job)
        except QueueFull as exc:
            raise protocol.RequestError(429, "queue", f"all workers are busy and the queue of "
                                        f"{self.pool.capacity} is full; retry later",
                                        {"retry-after": str(exc.retry_after)}) from None
        except Unavailable as exc:
            return _json(503, {"error": str(exc), "field": "server", "status": 503},
                         {"retry-after": "5"})
        # At the deadline a job still queued is dropped and answered 504 here; one a worker
        # has is answered by its slot (which kills the worker).
        timer = loop.call_later(max(0.0, job.deadline - time.monotonic()), _expire_queued,
                                job, deadline)
        try:
            outcome = await job.future
        finally:
            timer.cancel()
        headers = dict(outcome.headers)
        if outcome.worker is not None:
            headers["x-glraster-worker"] = str(outcome.worker)
        return Response(outcome.body, status_code=outcome.status,
                        media_type=outcome.content_type, headers=headers)

    async def _handle(self, endpoint: str, request: Request, work) -> Response:
        t0 = time.monotonic()
        try:
            response = await work()
        except protocol.RequestError as exc:
            response = _refuse(exc)
        if self.draining:
            response.headers["connection"] = "close"
        self.metrics.observe(endpoint, response.status_code, time.monotonic() - t0)
        return response

    # -- endpoints ------------------------------------------------------------------------
    async def rasterize(self, request: Request) -> Response:
        async def work():
            arrived = time.monotonic()
            self._authorize(request)
            accept = _negotiate(request.headers.get("accept"), _ACCEPT_RASTER)
            ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
            if ctype not in _CONTENT:
                raise protocol.RequestError(415, "content-type", "the body must be "
                                            "application/json or application/x-npz, got "
                                            f"{ctype[:80] or 'none'!r}")
            query = self._query(request, "rasterize")
            deadline = self.config.deadline if query.deadline is models.UNSET \
                else query.deadline
            options = {k: v for k, v in request.query_params.items() if k != "deadline"}
            body = await self._body(request)
            return await self._run("rasterize", {"content_type": _CONTENT[ctype],
                                                 "accept": accept, "query": options},
                                   body, arrived, deadline)
        return await self._handle("rasterize", request, work)

    async def check(self, request: Request) -> Response:
        async def work():
            arrived = time.monotonic()
            self._authorize(request)
            accept = _negotiate(request.headers.get("accept"), _ACCEPT_CHECK)
            ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
            if ctype not in ("", "application/json"):
                raise protocol.RequestError(415, "content-type", "the body must be "
                                            f"application/json, got {ctype[:80]!r}")
            query = self._query(request, "check")
            deadline = self.config.check_deadline if query.deadline is models.UNSET \
                else query.deadline
            body = await self._body(request)
            return await self._run("check", {"accept": accept}, body, arrived, deadline)
        return await self._handle("check", request, work)

    async def info(self, request: Request) -> Response:
        async def work():
            self._authorize(request)
            cfg, lim = self.config, self.config.limits
            driver = self.pool.info()
            driver_max = driver.get("max_texture_size")
            doc = {
                "service": "glraster", "version": __version__,
                "driver": driver,
                "limits": {"max_body_bytes": lim.max_body_bytes,
                           "max_vertices": lim.max_vertices,
                           "max_triangles": lim.max_triangles,
                           "max_resolution": (min(lim.max_resolution, driver_max)
                                              if driver_max else lim.max_resolution),
                           "configured_max_resolution": lim.max_resolution,
                           "driver_max_resolution": driver_max,
                           "deadline": cfg.deadline, "check_deadline": cfg.check_deadline,
                           "max_deadline": max(cfg.deadline, lim.max_deadline),
                           "body_timeout": cfg.body_timeout},
                "methods": list(protocol.METHOD_NAMES), "outputs": list(protocol.OUTPUT_NAMES),
                "auth": bool(self._digests), "draining": self.draining,
                "uptime": time.time() - self.started,
                **self.pool.snapshot(),
            }
            return _json(200, doc)
        return await self._handle("info", request, work)

    async def healthz(self, request: Request) -> Response:
        return await self._handle("healthz", request,
                                  lambda: _async(_json(200, {"status": "alive"})))

    async def readyz(self, request: Request) -> Response:
        async def work():
            if self.draining:
                return _json(503, {"status": "draining"})
            if not self.pool.ready():
                snap = self.pool.snapshot()
                errors = sorted({w["error"] for w in snap["workers"] if w["error"]})
                return _json(503, {"status": "starting" if not errors else "no working context",
                                   "errors": errors})
            return _json(200, {"status": "ready", "renderer": self.pool.info().get("renderer")})
        return await self._handle("readyz", request, work)

    async def metrics_text(self, request: Request) -> Response:
        async def work():
            self._authorize(request)
            return Response(self.metrics.render(), media_type=CONTENT_TYPE)
        return await self._handle("metrics", request, work)

    async def openapi_json(self, request: Request) -> Response:
        async def work():
            return Response(self._schema, media_type="application/json")
        return await self._handle("openapi", request, work)


def _expire_queued(job: Job, deadline: float) -> None:
    if job.abandon():
        job.answer(Outcome(504, protocol.JSON, {}, protocol.error_json(
            504, "deadline", f"the request waited {deadline:g} s, its deadline, for a worker")))


async def _async(value):
    return value


def create_app(config: ServiceConfig) -> Starlette:
    """The Starlette app for ``config`` (its workers start with the app's lifespan)."""
    return Service(config).app


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host.strip("[]"), port))
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


def serve(config: ServiceConfig, *, announce=print, max_connections: int = 1024) -> int:
    """Run the service until SIGTERM / SIGINT, then drain: the listening socket closes,
    in-flight requests finish (up to ``config.effective_drain_timeout``), queued ones that
    no worker took get 503, and the workers stop. Returns 0."""
    import uvicorn

    service = Service(config)
    sock = _bind(config.host, config.port)
    host, port = sock.getsockname()[:2]

    class Server(uvicorn.Server):
        def handle_exit(self, sig, frame):
            service.draining = True
            super().handle_exit(sig, frame)
            # uvicorn re-raises the signal once it has stopped; a drained shutdown is a
            # clean one: exit 0 (systemd and container runtimes see a normal stop)
            captured = getattr(self, "_captured_signals", None)
            if isinstance(captured, list):
                captured.clear()

    loop = "auto"
    http = "auto"
    uconfig = uvicorn.Config(
        service.app, log_level=config.log_level, access_log=False, lifespan="on",
        loop=loop, http=http, timeout_keep_alive=5, server_header=False, date_header=True,
        timeout_graceful_shutdown=int(config.effective_drain_timeout) + 1,
        limit_concurrency=max_connections, proxy_headers=False)
    server = Server(uconfig)
    shown = f"[{host}]" if ":" in host else host
    announce(f"glraster service on http://{shown}:{port} ({config.workers} worker"
             f"{'s' if config.workers != 1 else ''}, queue {config.queue_size}, "
             f"auth {'on' if config.tokens else 'off'})")
    server.run(sockets=[sock])
    return 0
