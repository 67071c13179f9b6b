"""A small client of the glraster rendering service (``glraster serve``; docs/service.md).

Standard library HTTP and NumPy only (no moderngl, no service extra), so a CI job that
renders on a remote driver needs nothing but ``pip install glraster``::

    from glraster.client import Client

    with Client("http://127.0.0.1:8642", token=None) as c:
        c.info()["driver"]["renderer"]
        r = c.rasterize(pos, tri, (256, 256))          # a glraster.Raster, bit for bit
        stats = c.rasterize(pos, tri, (256, 256), result="json", compare=True)
        exr_bytes = c.rasterize(pos, tri, (256, 256), result="exr")
        report = c.check(scenes=["grid_*"])             # JSON, with report["junit"]

Errors: a refused request raises :class:`ServiceError` (``status``, ``field``,
``message`` from the server's JSON); a server that cannot be reached, or answers 5xx,
raises :class:`ServiceUnavailable` (a subclass). 429 and 503 answers are retried after
their Retry-After (up to ``retries`` times) before they raise.
"""

from __future__ import annotations

import http.client
import json
import socket
import time
import urllib.parse

import numpy as np

from glraster.errors import ArgumentError
from glraster.io.npz import read_npz, write_npz
from glraster.types import OUTPUTS, Raster

NPZ = "application/x-npz"
EXR = "image/x-exr"
JSON = "application/json"
_ACCEPT = {"npz": NPZ, "json": JSON, "exr": EXR}


class ServiceError(Exception):
    """The service refused a request: HTTP ``status``, the ``field`` it names, ``message``."""

    def __init__(self, status: int, field: str, message: str):
        if not status:     # no HTTP answer at all: the message says why
            text = message
        else:
            text = f"{status} {field}: {message}" if field else f"{status}: {message}"
        super().__init__(text)
        self.status, self.field, self.message = status, field, message


class ServiceUnavailable(ServiceError):
    """The service could not be reached or failed (5xx, connection error, 429 after retries).
    ``status`` is 0 when no HTTP answer came (the message names the URL and the cause)."""


def _unreachable(url: str, host: str, port, timeout: float, exc: BaseException) -> str:
    """Why ``url`` gave no HTTP answer, for people."""
    if isinstance(exc, ConnectionRefusedError):
        why = (f"connection refused: nothing listens on {host}:{port} (is glraster serve "
               "running there?)")
    elif isinstance(exc, socket.gaierror):
        why = f"the host name {host!r} does not resolve ({exc.strerror or exc})"
    elif isinstance(exc, (TimeoutError, socket.timeout)):
        why = f"no answer within {timeout:g} s (the client's timeout)"
    elif isinstance(exc, http.client.RemoteDisconnected):
        why = "the server closed the connection without answering"
    elif isinstance(exc, OSError) and exc.strerror:
        why = exc.strerror[:1].lower() + exc.strerror[1:]
    else:
        why = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    return f"cannot reach the service at {url}: {why}"


class Client:
    """A connection to one service URL (kept alive between requests; not thread-safe: use
    one Client per thread).

    url     : ``http://host:port`` (https works too)
    token   : bearer token, or None
    timeout : socket timeout in seconds for each request
    retries : times a 429 / 503 answer is retried after its Retry-After (capped at 30 s)
    """

    def __init__(self, url: str, token: str | None = None, *, timeout: float = 600.0,
                 retries: int = 2):
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ArgumentError("url", f"url must be http://HOST:PORT or https://..., got {url!r}")
        self.url = url.rstrip("/")
        self._scheme, self._host, self._port = parts.scheme, parts.hostname, parts.port
        self._base = parts.path.rstrip("/")
        self.token = token
        self.timeout = timeout
        self.retries = retries
        self._conn = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    # -- transport ------------------------------------------------------------------------
    def _connection(self):
        if self._conn is None:
            cls = http.client.HTTPSConnection if self._scheme == "https" else http.client.HTTPConnection
            self._conn = cls(self._host, self._port, timeout=self.timeout)
        return self._conn

    def request(self, method: str, path: str, body: bytes | None = None, *,
                content_type: str | None = None, accept: str = JSON, query: dict | None = None):
        """One HTTP exchange; returns (status, headers dict (lower-case), body as a
        bytearray) for a 2xx answer, raises ServiceError / ServiceUnavailable otherwise."""
        headers = {"Accept": accept}
        if content_type:
            headers["Content-Type"] = content_type
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        url = self._base + path
        if query:
            url += "?" + urllib.parse.urlencode(query)
        attempt = 0
        while True:
            try:
                conn = self._connection()
                conn.request(method, url, body=body, headers=headers)
                resp = conn.getresponse()
                data = _read_body(resp)
                rheaders = {k.lower(): v for k, v in resp.getheaders()}
                if rheaders.get("connection", "").lower() == "close":
                    self.close()
            except (OSError, http.client.HTTPException) as exc:
                self.close()
                if attempt < 1 and isinstance(exc, (http.client.RemoteDisconnected,
                                                    ConnectionResetError, BrokenPipeError)):
                    attempt += 1      # a kept-alive connection the server had closed
                    continue
                raise ServiceUnavailable(0, "", _unreachable(
                    self.url, self._host, self._port or (443 if self._scheme == "https" else 80),
                    self.timeout, exc)) from None
            if 200 <= resp.status < 300:
                return resp.status, rheaders, data
            if resp.status in (429, 503) and attempt < self.retries:
                attempt += 1
                try:
                    wait = float(rheaders.get("retry-after", "1"))
                except ValueError:
                    wait = 1.0
                time.sleep(min(max(wait, 0.1), 30.0))
                continue
            raise _error(resp.status, data)

    # -- endpoints ------------------------------------------------------------------------
    def info(self) -> dict:
        """``GET /v1/info``: driver, limits, workers, queue."""
        return json.loads(self.request("GET", "/v1/info")[2])

    def healthy(self) -> bool:
        """``GET /healthz`` answered 200."""
        try:
            self.request("GET", "/healthz")
            return True
        except ServiceError:
            return False

    def ready(self) -> bool:
        """``GET /readyz`` answered 200 (a worker holds a working context)."""
        try:
            self.request("GET", "/readyz")
            return True
        except ServiceError:
            return False

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Block until :meth:`ready` (ServiceUnavailable after ``timeout`` seconds)."""
        end = time.monotonic() + timeout
        while not self.ready():
            if time.monotonic() > end:
                raise ServiceUnavailable(0, "", f"{self.url} not ready after {timeout:g} s")
            time.sleep(0.1)

    def metrics(self) -> str:
        """``GET /metrics``: the Prometheus text."""
        return self.request("GET", "/metrics", accept="text/plain")[2].decode()

    def rasterize(self, pos, tri, resolution, *, outputs=OUTPUTS, method: str = "hw",
                  reference: bool = False, compare: bool = False, cull_backfaces: bool = False,
                  crop: bool = False, result: str = "npz", deadline: float | None = None,
                  samples: int = 1, interpolation: str = "center"):
        """``POST /v1/rasterize`` with the scene as .npz (exact float32 / int32 bytes).
        ``samples`` / ``interpolation``: multisampling, as for :func:`glraster.rasterize`
        (per-sample arrays in the result).

        result : "npz" -> a :class:`glraster.Raster` (arrays bit for bit as the server's
                 :func:`glraster.rasterize` returned them; ``info["comparison"]`` with
                 ``compare``; ``info["headers"]`` the response headers),
                 "json" -> the statistics dict, "exr" -> the EXR file's bytes.
        """
        if result not in _ACCEPT:
            raise ArgumentError(
                "result", f"result must be one of {sorted(_ACCEPT)}, got {result!r}")
        body = encode_scene(pos, tri, resolution)
        query = {"outputs": ",".join([outputs] if isinstance(outputs, str) else outputs),
                 "method": method}
        for key, value in (("reference", reference), ("compare", compare),
                           ("cull_backfaces", cull_backfaces), ("crop", crop)):
            if value:
                query[key] = "true"
        if samples != 1 or interpolation != "center":
            query.update(samples=str(samples), interpolation=interpolation)
        if deadline is not None:
            query["deadline"] = f"{deadline:g}"
        _, headers, data = self.request("POST", "/v1/rasterize", body, content_type=NPZ,
                                        accept=_ACCEPT[result], query=query)
        if result == "json":
            return json.loads(data)
        if result == "exr":
            return bytes(data)
        return decode_raster(data, headers)

    def check(self, scenes=None, *, method: str = "hw", golden: bool = True, mutants=False,
              shard: str | None = None, junit: bool = False, deadline: float | None = None):
        """``POST /v1/check`` on the server's driver: the result dict (``ok``, ``scenes``,
        ``junit`` ...), or with ``junit=True`` the JUnit XML text."""
        doc = {"method": method, "golden": golden, "mutants": mutants}
        if scenes is not None:
            doc["scenes"] = scenes
        if shard is not None:
            doc["shard"] = shard
        query = {"deadline": f"{deadline:g}"} if deadline is not None else None
        _, _, data = self.request("POST", "/v1/check", json.dumps(doc).encode(),
                                  content_type=JSON, accept="application/xml" if junit else JSON,
                                  query=query)
        return data.decode() if junit else json.loads(data)


def _read_body(resp) -> bytearray:
    """The whole body, read into one writeable buffer (the arrays of an .npz result are
    views into it, so they are writeable like ``np.load``'s)."""
    if resp.length is None:
        return bytearray(resp.read())
    buf = bytearray(resp.length)
    view, got = memoryview(buf), 0
    while got < len(buf):
        n = resp.readinto(view[got:])
        if not n:
            raise http.client.IncompleteRead(bytes(view[:got]), len(buf) - got)
        got += n
    return buf


def _error(status: int, data) -> ServiceError:
    try:
        doc = json.loads(data)
        field, message = str(doc.get("field", "")), str(doc.get("error", ""))
    except (ValueError, AttributeError):
        field, message = "", data[:300].decode("utf-8", "replace")
    cls = ServiceUnavailable if status >= 500 or status == 429 else ServiceError
    return cls(status, field, message)


def encode_scene(pos, tri, resolution) -> bytes:
    """A scene as the .npz body of ``POST /v1/rasterize``: pos as float32 (what
    :func:`glraster.rasterize` converts it to), tri as int32 when it fits, resolution."""
    pos = np.asarray(pos)
    if pos.dtype.kind == "f" and pos.dtype != np.float32:
        with np.errstate(over="ignore"):
            pos = pos.astype(np.float32)
    tri = np.asarray(tri)
    if tri.dtype.kind in "iu" and tri.size and tri.min() >= 0 and tri.max() < 2**31:
        tri = tri.astype(np.int32)
    return write_npz({"pos": pos, "tri": tri,
                      "resolution": np.asarray(resolution, dtype=np.int64)})


def decode_raster(data, headers: dict | None = None) -> Raster:
    """A :class:`glraster.Raster` from an .npz result. Its arrays are views into ``data``
    (no copy): writeable when it is a bytearray (as :meth:`Client.request` returns),
    read-only when it is ``bytes``."""
    arrays = read_npz(data)
    mask = arrays.pop("mask")
    info = {}
    if "comparison" in arrays:
        info["comparison"] = json.loads(str(arrays.pop("comparison")))
    if headers is not None:
        info["headers"] = dict(headers)
    fields = {n: arrays[n] for n in OUTPUTS if n in arrays}
    if "sample_positions" in arrays:           # multisampled: a sample axis after W
        positions = arrays.pop("sample_positions")
        interpolation = json.loads(str(arrays.pop("interpolation", '"center"')))
        return Raster(resolution=tuple(mask.shape[:2]), mask=mask, info=info,
                      samples=len(positions), interpolation=interpolation,
                      sample_positions=positions, **fields)
    return Raster(resolution=tuple(mask.shape), mask=mask, info=info, **fields)
