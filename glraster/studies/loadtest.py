"""The loopback load test of the service (``glraster serve-bench``, ``glraster study
serve-bench``): a benchmark, never a pass/fail test.

What it measures (docs/service.md, "Measured"):

1. throughput and p50 / p99 latency at concurrency 1, 4 and 16 for a 256x256 scene (the
   catalog's torus, 4096 triangles) and a 1024x1024 scene of 20,000 triangles, result as .npz;
2. the per-request overhead of the service over an in-process call at 256x256 with the JSON
   result (no transfer of the result): service p50 minus the in-process p50 of the same work
   (:func:`glraster.rasterize` plus the same statistics);
3. sustained throughput of a 2-worker server against two in-process loops (two processes
   each calling :func:`glraster.rasterize` back to back, with fresh arrays and, as the
   workers do, into the previous call's arrays), in interleaved rounds;
4. the resident memory of the server and its workers over 10,000 requests.

Traffic goes to loopback only: a ``--url`` whose host is not a loopback address is refused.
Every loop is bounded in count and in time. The client is a minimal HTTP/1.1 client
(keep-alive, one connection per concurrent stream, responses read by a buffered protocol
into a reused buffer, on uvloop), so that its own cost, which shares the machine's cores
with the server, stays small.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import re
import statistics
import subprocess
import sys
import time
import urllib.parse

from dataclasses import dataclass

import numpy as np

from glraster.client import encode_scene
from glraster.errors import ArgumentError
from glraster.io.atomic import write_text

SCENES = {"256": (256, 256, 4096), "1024": (1024, 1024, 20_000)}


def make_scene(name: str):
    """Deterministic scenes: ``"256"``: the catalog's torus (256x256, 4096 triangles);
    ``"1024"``: a 1024x1024 perspective grid of 20,000 triangles (w from 1 to 4)."""
    h, w, t = SCENES[name]
    if name == "256":
        from glraster.conformance.scenes import load_scene

        s = load_scene("torus")
        return np.array(s.pos), np.array(s.tri), tuple(s.resolution)
    rng = np.random.default_rng(13)
    n = 100                                   # 100 x 100 quads = 20,000 triangles
    gx, gy = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    gx += rng.uniform(-0.3, 0.3, gx.shape) / n
    gy += rng.uniform(-0.3, 0.3, gy.shape) / n
    ww = 1.0 + 1.5 * (gy + 1) + rng.uniform(0, 0.05, gx.shape)
    z = rng.uniform(-0.5, 0.5, gx.shape)
    pos = np.stack([gx * ww, gy * ww, z * ww, ww], -1).reshape(-1, 4).astype(np.float32)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    quads = np.stack([i, i + 1, i + n + 2, i, i + n + 2, i + n + 1], -1).reshape(-1, 3)
    return pos, quads.astype(np.int32), (h, w)


# -- the client -----------------------------------------------------------------------------

class _HTTPConnection(asyncio.BufferedProtocol):
    """One kept-alive HTTP/1.1 connection of the load test's client: it sends a prepared
    request and reads the response's status line and headers; the body is read into a
    reused scratch buffer and dropped, so the client's own cost (which shares the cores
    with the server) stays near the kernel's copy."""

    def __init__(self):
        self.transport = None
        self._buf = bytearray(1 << 16)
        self._have = 0
        self._scratch = bytearray(1 << 20)
        self._body_left = None      # bytes of the body still to read
        self._status = self._close = None
        self._done = None
        self.lost = False

    def connection_made(self, transport):
        self.transport = transport

    def connection_lost(self, exc):
        self.lost = True
        if self._done is not None and not self._done.done():
            self._done.set_exception(ConnectionError("the server closed the connection"))

    def get_buffer(self, sizehint):
        if self._body_left is not None:
            return memoryview(self._scratch)[:min(len(self._scratch), self._body_left)]
        return memoryview(self._buf)[self._have:]

    def buffer_updated(self, nbytes):
        if self._body_left is not None:
            self._body_left -= nbytes
        else:
            self._have += nbytes
            end = self._buf.find(b"\r\n\r\n", 0, self._have)
            if end < 0:
                if self._have == len(self._buf):
                    self._fail("a response head above 64 KiB")
                return
            head = bytes(self._buf[:end]).decode("latin-1").split("\r\n")
            self._status = int(head[0].split()[1])
            length, self._close = None, False
            for line in head[1:]:
                k, _, v = line.partition(":")
                k = k.strip().lower()
                if k == "content-length":
                    length = int(v)
                elif k == "connection" and v.strip().lower() == "close":
                    self._close = True
            if length is None:
                self._fail("a response without Content-Length")
                return
            extra = self._have - (end + 4)
            self._have = 0
            self._body_left = length - extra
        if self._body_left is not None and self._body_left <= 0:
            self._body_left = None
            if not self._done.done():
                self._done.set_result((self._status, self._close))

    def _fail(self, what):
        if not self._done.done():
            self._done.set_exception(ConnectionError(f"the server sent {what}"))
        self.transport.close()

    async def exchange(self, request: bytes):
        """``(status, close)`` of one request / response."""
        self._done = asyncio.get_running_loop().create_future()
        self.transport.write(request)
        return await self._done


async def _connect(host, port) -> _HTTPConnection:
    _, conn = await asyncio.get_running_loop().create_connection(_HTTPConnection, host, port)
    return conn


async def run_load(host, port, request: bytes, count: int, concurrency: int,
                   time_limit: float) -> dict:
    """``count`` requests (at most ``time_limit`` seconds) over ``concurrency`` kept-alive
    connections. Returns throughput, latency percentiles (ms) and status counts."""
    latencies, statuses = [], {}
    issued = 0
    start = time.perf_counter()
    stop_at = start + time_limit

    async def stream():
        nonlocal issued
        conn = await _connect(host, port)
        try:
            while issued < count and time.perf_counter() < stop_at:
                issued += 1
                t = time.perf_counter()
                try:
                    status, close = await conn.exchange(request)
                except ConnectionError:
                    status, close = 0, True
                latencies.append(time.perf_counter() - t)
                statuses[status] = statuses.get(status, 0) + 1
                if close or conn.lost:
                    conn.transport.close()
                    conn = await _connect(host, port)
        finally:
            conn.transport.close()

    await asyncio.gather(*(stream() for _ in range(concurrency)))
    wall = time.perf_counter() - start
    lat = np.array(latencies) * 1e3
    return {"requests": len(latencies), "concurrency": concurrency, "seconds": wall,
            "throughput": len(latencies) / wall if wall else 0.0,
            "p50_ms": float(np.percentile(lat, 50)) if lat.size else None,
            "p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
            "statuses": {str(k): v for k, v in sorted(statuses.items())}}


def _run(coro):
    """Run the client on uvloop (the [service] extra has it): the load generator shares the
    cores with the server, and uvloop's transports cost it a fraction of asyncio's."""
    import uvloop

    loop = uvloop.new_event_loop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


def http_request(host, port, path, body, content_type, accept, token=None) -> bytes:
    head = [f"POST {path} HTTP/1.1", f"Host: {host}:{port}", f"Content-Type: {content_type}",
            f"Accept: {accept}", f"Content-Length: {len(body)}"]
    if token:
        head.append(f"Authorization: Bearer {token}")
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


# -- in-process baselines -------------------------------------------------------------------

class InProcess:
    """:func:`glraster.rasterize` of a scene in this process, on a context of its own."""

    def __init__(self, backend, name: str):
        import glraster as gr
        from glraster.service.protocol import raster_stats

        self.gr, self.stats = gr, raster_stats
        self.ctx = gr.Context(backend=backend)
        self.scene = make_scene(name)
        for _ in range(3):
            self.raster = gr.rasterize(*self.scene, ctx=self.ctx)

    def times(self, count: int, reuse: bool = False) -> list:
        """Seconds per warm call plus the service's JSON statistics; ``reuse``: into the
        previous call's arrays (``out=``), as the service's workers do."""
        out = []
        for _ in range(count):
            t = time.perf_counter()
            r = self.gr.rasterize(*self.scene, ctx=self.ctx, out=self.raster if reuse else None)
            self.stats(r)
            out.append(time.perf_counter() - t)
        return out

    def close(self):
        self.ctx.release()


def _loop_process(backend, name, reuse, commands, results):
    """One in-process loop: waits for ``(count, seconds)`` commands, answers
    ``(calls, seconds)``; ``None`` ends it."""
    import glraster as gr

    ctx = gr.Context(backend=backend)
    pos, tri, res = make_scene(name)
    raster = None
    for _ in range(3):
        raster = gr.rasterize(pos, tri, res, ctx=ctx)
    results.put(os.getpid())
    while (command := commands.get()) is not None:
        count, time_limit = command
        t = time.perf_counter()
        n = 0
        end = t + time_limit
        while n < count and time.perf_counter() < end:
            gr.rasterize(pos, tri, res, ctx=ctx, out=raster if reuse else None)
            n += 1
        results.put((n, time.perf_counter() - t))
    ctx.release()


class TwoLoops:
    """Two in-process loops in two processes (each warm, on a context of its own), calling
    :func:`glraster.rasterize` back to back; ``reuse``: into the arrays of the previous
    call (``out=``), as the service's workers do."""

    def __init__(self, backend, name: str, reuse: bool = False):
        mp = multiprocessing.get_context("spawn")
        self._commands = [mp.Queue() for _ in range(2)]
        self._results = mp.Queue()
        self._procs = [mp.Process(target=_loop_process, daemon=True,
                                  args=(backend, name, reuse, q, self._results))
                       for q in self._commands]
        for p in self._procs:
            p.start()
        for _ in self._procs:
            self._results.get(timeout=120)

    def run(self, count: int, time_limit: float) -> dict:
        """Both loops started together, ``count`` calls between them (at most
        ``time_limit`` seconds): calls per second."""
        for q in self._commands:
            q.put((count // 2, time_limit))
        results = [self._results.get(timeout=time_limit + 120) for _ in self._procs]
        calls = sum(n for n, _ in results)
        wall = max(s for _, s in results)
        return {"calls": calls, "seconds": wall, "throughput": calls / wall}

    def close(self) -> None:
        for q in self._commands:
            q.put(None)
        for p in self._procs:
            p.join(30)
            if p.is_alive():
                p.kill()


# -- the server -----------------------------------------------------------------------------

class StartedServer:
    """``glraster serve`` in a subprocess on 127.0.0.1, any free port."""

    def __init__(self, backend, workers, extra=()):
        cmd = [sys.executable, "-m", "glraster.cli", "serve", "--host", "127.0.0.1",
               "--port", "0", "--workers", str(workers), "--queue", "64", *extra]
        if backend:
            cmd += ["--backend", backend]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True)
        line = self.proc.stdout.readline()
        m = re.search(r"http://([\d.]+):(\d+)", line)
        if not m:
            self.proc.kill()
            raise RuntimeError(f"glraster serve did not start: {line!r}")
        self.host, self.port = m.group(1), int(m.group(2))
        self.url = f"http://{self.host}:{self.port}"

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def memory(client) -> dict:
    """Resident MiB of the server and each worker, from /metrics."""
    from prometheus_client.parser import text_string_to_metric_families

    out = {}
    for family in text_string_to_metric_families(client.metrics()):
        for s in family.samples:
            if s.name == "process_resident_memory_bytes":
                out["server"] = s.value / 2**20
            elif s.name == "glraster_worker_resident_bytes":
                out[f"worker{s.labels['worker']}"] = s.value / 2**20
    return out


@dataclass
class Target:
    """The service under load: where it listens, its token, the client of its JSON
    endpoints, and the server this run started (None for ``--url``)."""

    host: str
    port: int
    token: str | None
    client: object
    server: StartedServer | None = None

    def request(self, scene: str, accept: str) -> bytes:
        """A prepared POST /v1/rasterize of ``make_scene(scene)`` as .npz, answered as
        ``accept`` ("application/json" or "application/x-npz")."""
        body = encode_scene(*make_scene(scene))
        return http_request(self.host, self.port, "/v1/rasterize", body, "application/x-npz",
                            accept, self.token)

    def load(self, request: bytes, count: int, concurrency: int, time_limit: float) -> dict:
        """:func:`run_load` against this service."""
        return _run(run_load(self.host, self.port, request, count, concurrency, time_limit))

    def close(self) -> None:
        self.client.close()
        if self.server is not None:
            self.server.stop()


def open_target(args) -> Target:
    """The service of ``args``: ``--url`` (loopback only: an
    :class:`~glraster.errors.ArgumentError` otherwise) or a started ``glraster serve``."""
    from glraster.client import Client
    from glraster.service.config import is_loopback, read_token_file

    token = read_token_file(args.token_file)[0] if args.token_file else None
    if args.url:
        parts = urllib.parse.urlsplit(args.url)
        if not parts.hostname or not is_loopback(parts.hostname):
            raise ArgumentError("--url", f"--url must be a loopback address (127.0.0.1, ::1, "
                                f"localhost), got {args.url!r}")
        return Target(parts.hostname, parts.port or 80, token, Client(args.url, token))
    extra = ("--token-file", args.token_file) if args.token_file else ()
    server = StartedServer(args.backend, args.workers, extra)
    try:
        client = Client(server.url, token)
    except BaseException:
        server.stop()
        raise
    return Target(server.host, server.port, token, client, server)


# -- the four measurements ------------------------------------------------------------------

def measure_load(target: Target, quick: bool, limit: float) -> dict:
    """1. Throughput and latency at concurrency 1, 4 and 16, .npz results, per scene."""
    scenes = {}
    for name in ("256", "1024"):
        pos, tri, res = make_scene(name)
        body = encode_scene(pos, tri, res)
        req = http_request(target.host, target.port, "/v1/rasterize", body,
                           "application/x-npz", "application/x-npz", target.token)
        count = {"256": 12 if quick else 600, "1024": 4 if quick else 80}[name]
        target.load(req, min(count, 20), 2, limit)                    # warm-up
        rows = []
        for c in (1, 4, 16):
            rows.append(r := target.load(req, count, c, limit))
            print(f"{name}^2 npz  concurrency {c:>2}: {r['throughput']:8.1f} req/s  "
                  f"p50 {r['p50_ms']:8.2f} ms  p99 {r['p99_ms']:8.2f} ms  {r['statuses']}",
                  flush=True)
        scenes[name] = {"resolution": list(res), "triangles": int(len(tri)),
                        "npz_bytes_request": len(body), "load": rows}
    return scenes


def measure_overhead(target: Target, backend, quick: bool, limit: float) -> dict:
    """2. The service's overhead per request over an in-process call at 256², JSON result
    (no transfer of the result), in interleaved rounds (a service block, then in-process
    blocks; the median of each): the in-process call with fresh arrays (what a plain loop
    does) and into the previous call's arrays (what the workers do, so that the difference
    is the cost of HTTP and the pipes)."""
    rounds, per = (3, 10) if quick else (10, 100)
    req = target.request("256", "application/json")
    target.load(req, 10 if quick else 50, 1, limit)                    # warm-up
    local = InProcess(backend, "256")
    svc, plain, reuse = [], [], []
    try:
        for _ in range(rounds):
            svc.append(target.load(req, per, 1, limit)["p50_ms"])
            plain.append(statistics.median(local.times(per)) * 1e3)
            reuse.append(statistics.median(local.times(per, reuse=True)) * 1e3)
    finally:
        local.close()
    over_plain = [a - b for a, b in zip(svc, plain)]
    over_reuse = [a - b for a, b in zip(svc, reuse)]
    over = {"rounds": rounds, "requests_per_round": per,
            "service_p50_ms": statistics.median(svc),
            "in_process_p50_ms": statistics.median(plain),
            "in_process_reuse_p50_ms": statistics.median(reuse),
            "overhead_ms": statistics.median(over_plain),
            "overhead_vs_reuse_ms": statistics.median(over_reuse),
            "overhead_ms_rounds": over_plain, "overhead_vs_reuse_ms_rounds": over_reuse}
    print(f"overhead at 256^2 (JSON result, {rounds} interleaved rounds, medians): service "
          f"p50 {over['service_p50_ms']:.3f} ms; in process {over['in_process_p50_ms']:.3f} "
          f"ms (into its own arrays {over['in_process_reuse_p50_ms']:.3f} ms): "
          f"{over['overhead_ms']:+.3f} ms ({over['overhead_vs_reuse_ms']:+.3f} ms against "
          f"the reusing call)", flush=True)
    return over


def measure_sustained(target: Target, backend, quick: bool, limit: float) -> dict:
    """3. Sustained throughput of the 2-worker server against two in-process loops, per
    scene, in interleaved rounds (loops, loops into their own arrays, service JSON, service
    .npz), since the machine's load drifts between blocks; the medians of the rounds and
    of the rounds' ratios."""
    out = {}
    rounds = 1 if quick else 5
    for name, count in (("256", 40 if quick else 1500), ("1024", 6 if quick else 120)):
        reqs = {"json": target.request(name, "application/json"),
                "npz": target.request(name, "application/x-npz")}
        for req in reqs.values():
            target.load(req, 16, 8, limit)                              # warm-up
        loops = {"plain": TwoLoops(backend, name), "reuse": TwoLoops(backend, name, reuse=True)}
        per_round = []
        try:
            for _ in range(rounds):
                row = {f"loops_{k}": v.run(count, limit)["throughput"] for k, v in loops.items()}
                for label, req in reqs.items():
                    row[f"service_{label}"] = target.load(req, count, 8, limit)["throughput"]
                per_round.append(row)
        finally:
            for v in loops.values():
                v.close()
        out[name] = summary = _sustained_summary(per_round, reqs, loops)
        print(f"sustained {name}^2 ({rounds} interleaved rounds, medians): two "
              f"in-process loops {summary['loops_plain']:.1f}/s (into their own "
              f"arrays {summary['loops_reuse']:.1f}/s); service, 2 workers, "
              f"concurrency 8: JSON {summary['service_json']:.1f}/s "
              f"({summary['ratio_json_vs_plain']:.0%}; "
              f"{summary['ratio_json_vs_reuse']:.0%} of the reusing loops), "
              f".npz {summary['service_npz']:.1f}/s "
              f"({summary['ratio_npz_vs_plain']:.0%}; "
              f"{summary['ratio_npz_vs_reuse']:.0%})", flush=True)
    return out


def _sustained_summary(per_round: list, labels, loops) -> dict:
    """The rounds, the median of every figure over them, and the medians of the per-round
    ratios service / loops (``ratio_{json,npz}_vs_{plain,reuse}``)."""
    summary = {"rounds": per_round}
    for label in labels:
        for k in loops:
            summary[f"ratio_{label}_vs_{k}"] = statistics.median(
                r[f"service_{label}"] / r[f"loops_{k}"] for r in per_round)
    for key in per_round[0]:
        summary[key] = statistics.median(r[key] for r in per_round)
    return summary


def measure_memory(target: Target, total: int) -> dict:
    """4. Resident memory of the server and its workers over ``total`` requests (256²,
    JSON result, concurrency 4), sampled at 5%, 25%, 50%, 75% and 100%."""
    req = target.request("256", "application/json")
    samples = []
    done = 0
    marks = sorted({min(total, m) for m in (total // 20, total // 4, total // 2,
                                            3 * total // 4, total)} - {0})
    for mark in marks:
        done += target.load(req, mark - done, 4, 600.0)["requests"]
        samples.append({"requests": done, **memory(target.client)})
    first, last = samples[0], samples[-1]
    growth = {k: last[k] - first[k] for k in first if k != "requests" and k in last}
    print(f"memory over {done} requests (MiB, after {first['requests']}): "
          + ", ".join(f"{k} {first[k]:.1f} -> {last[k]:.1f}" for k in growth), flush=True)
    return {"samples": samples, "growth_mib_after_warmup": growth}


def run(args) -> int:
    """``glraster serve-bench``: the four measurements against the service of ``args``;
    the figures as JSON to ``args.json`` (written atomically) when given."""
    quick = args.quick
    target = open_target(args)
    figures = {"quick": quick, "workers": args.workers, "scenes": {}, "machine": {
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
        else os.cpu_count()}}
    try:
        target.client.wait_ready(120)
        figures["renderer"] = target.client.info()["driver"].get("renderer")
        limit = 15.0 if quick else 60.0
        figures["scenes"] = measure_load(target, quick, limit)
        figures["overhead_256"] = measure_overhead(target, args.backend, quick, limit)
        if args.workers == 2 and target.server is not None:
            figures["sustained"] = measure_sustained(target, args.backend, quick, limit)
        total = args.memory_requests if not quick else min(args.memory_requests, 1000)
        if total:
            figures["memory"] = measure_memory(target, total)
    finally:
        target.close()
    if args.json:
        write_text(args.json, json.dumps(figures, indent=2))
        print(f"figures: {args.json}")
    return 0
