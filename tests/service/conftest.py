"""Real servers on loopback for the service tests: ``glraster serve`` in a subprocess on
127.0.0.1 (any free port), started by the test or its module and stopped by it.

Every test that talks to a server asks for ``gl_backend`` (tests/conftest.py), which marks it
``gl``, and starts its server with ``--backend <that backend>``.
"""

from __future__ import annotations

import os
import re
import selectors
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")

from glraster.client import Client  # noqa: E402

START_TIMEOUT = 90.0


class Server:
    """A running ``glraster serve`` subprocess."""

    def __init__(self, backend, *args, token=None, log=None, env=None):
        cmd = [sys.executable, "-m", "glraster.cli", "serve", "--host", "127.0.0.1",
               "--port", "0", "--backend", backend, *args]
        self.log = log
        self._log_fh = open(log, "w") if log else subprocess.DEVNULL
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._log_fh,
                                     text=True, env={**os.environ, **(env or {})})
        self.token = token
        line = self._first_line()
        m = re.search(r"http://127\.0\.0\.1:(\d+)", line)
        if not m:
            self.kill()
            raise RuntimeError(f"glraster serve did not start: {line!r} {self.stderr()}")
        self.port = int(m.group(1))
        self.url = f"http://127.0.0.1:{self.port}"
        with self.client() as c:
            if token is None:
                c.wait_ready(START_TIMEOUT)
            else:
                c.token = token
                c.wait_ready(START_TIMEOUT)

    def _first_line(self) -> str:
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        if not sel.select(START_TIMEOUT):
            return ""
        return self.proc.stdout.readline()

    def stderr(self) -> str:
        if self.log:
            try:
                return open(self.log).read()[-3000:]
            except OSError:
                return ""
        return ""

    def client(self, token="default", **kw) -> Client:
        return Client(self.url, self.token if token == "default" else token, **kw)

    def info(self) -> dict:
        with self.client() as c:
            return c.info()

    def worker_pids(self) -> list:
        return [w["pid"] for w in self.info()["workers"]]

    def wait_worker(self, state: str, index: int = 0, timeout: float = 30.0) -> dict:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            w = self.info()["workers"][index]
            if w["state"] == state:
                return w
            time.sleep(0.02)
        raise AssertionError(f"worker {index} never reached state {state!r}: {self.info()}")

    def stop(self, sig=signal.SIGTERM, timeout=60.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise AssertionError(f"the server did not stop within {timeout} s after {sig}")
        if self._log_fh is not subprocess.DEVNULL:
            self._log_fh.close()
        return self.proc.returncode

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def resume(pid):
    """SIGCONT (a test that stopped a worker lets it go again, e.g. before shutdown)."""
    try:
        os.kill(pid, signal.SIGCONT)
    except ProcessLookupError:
        pass


class Servers:
    """One shared server per (backend, arguments) for a module; stopped at its end."""

    def __init__(self, tmp_path_factory):
        self._servers = {}
        self._tmp = tmp_path_factory

    def get(self, backend, *args, token=None) -> Server:
        key = (backend, args, token)
        server = self._servers.get(key)
        if server is None or server.proc.poll() is not None:
            log = self._tmp.mktemp("server") / "stderr.log"
            server = self._servers[key] = Server(backend, *args, token=token, log=log)
        return server

    def close(self):
        for server in self._servers.values():
            for pid in [w["pid"] for w in _safe_workers(server)]:
                if pid:
                    resume(pid)
            server.stop()


def _safe_workers(server):
    try:
        return server.info()["workers"]
    except Exception:  # noqa: BLE001 - stopping anyway
        return []


@pytest.fixture(scope="module")
def servers(tmp_path_factory):
    pool = Servers(tmp_path_factory)
    yield pool
    pool.close()


# The limits of the shared test server: small enough that the fuzzer's largest valid
# request stays fast, large enough for every catalog scene below 1024x1024.
SHARED_ARGS = ("--workers", "1", "--queue", "8", "--max-resolution", "1024",
               "--max-vertices", "200000", "--max-triangles", "200000", "--max-body", "16",
               "--deadline", "60")


@pytest.fixture
def server(gl_backend, servers) -> Server:
    """The module's shared server for this backend (1 worker, limits of SHARED_ARGS)."""
    return servers.get(gl_backend, *SHARED_ARGS)


def scrape(client) -> dict:
    """``GET /metrics`` parsed by prometheus_client's own parser: {(sample name, sorted
    label pairs): value}; a sample twice in one exposition fails the test."""
    from prometheus_client.parser import text_string_to_metric_families

    samples = {}
    for family in text_string_to_metric_families(client.metrics()):
        for s in family.samples:
            key = (s.name, tuple(sorted(s.labels.items())))
            assert key not in samples, f"{key} exposed twice"
            samples[key] = s.value
    return samples


def sample(samples: dict, name: str, **labels) -> float | None:
    """The value of one sample of :func:`scrape`'s dict (None if absent)."""
    return samples.get((name, tuple(sorted(labels.items()))))
