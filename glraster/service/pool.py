"""The worker pool: N worker processes, one bounded queue, deadlines, crash recovery.

One thread per worker (a *slot*) takes jobs from the shared queue, hands each to its
process over a pipe and waits for the answer up to the job's deadline:

- answer in time: delivered to the waiting request;
- no answer by the deadline (a hang, or simply too slow): the process is killed, the
  request answered 504, and a fresh process started;
- the process died (EOF on the pipe): a fresh process is started and the job retried on it
  once; a second death answers 503. No other request is affected: each slot owns only
  its job.

A slot whose process died while idle replaces it before taking the next job. Requests
beyond the workers wait in the queue (``queue_size``); when it is full :meth:`submit`
raises :class:`QueueFull` with a Retry-After estimate from the recent service times.
"""

from __future__ import annotations

import math
import multiprocessing
import queue
import threading
import time

from glraster.service.worker import worker_main

RETRIES = 1            # a job whose worker died is retried this many times
STOP_TIMEOUT = 5.0     # seconds a worker gets to exit after "stop" before it is killed


class QueueFull(Exception):
    """The queue is full; retry after ``retry_after`` seconds."""

    def __init__(self, retry_after: int):
        super().__init__(f"the queue is full; retry after {retry_after} s")
        self.retry_after = retry_after


class Unavailable(Exception):
    """No worker can take the job (none has a working context, or the pool is stopping)."""


class Outcome:
    """A worker's answer (or the pool's own: 503, 504)."""

    __slots__ = ("status", "content_type", "headers", "body", "worker")

    def __init__(self, status, content_type, headers, body, worker=None):
        self.status, self.content_type, self.headers, self.body = status, content_type, headers, body
        self.worker = worker


def _error(status: int, field: str, message: str, worker=None) -> Outcome:
    from glraster.service.protocol import JSON, error_json

    return Outcome(status, JSON, {}, error_json(status, field, message), worker)


class Job:
    """One request for a worker. ``deadline`` is a ``time.monotonic()`` instant."""

    def __init__(self, kind: str, meta: dict, body: bytes, deadline: float, loop):
        self.kind, self.meta, self.body, self.deadline = kind, meta, body, deadline
        self.loop = loop
        self.future = loop.create_future()
        self.state = "queued"       # queued -> running -> done, or queued -> abandoned
        self._lock = threading.Lock()

    def claim(self) -> bool:
        """A slot takes the job (False: the request gave up while it was queued)."""
        with self._lock:
            if self.state != "queued":
                return False
            self.state = "running"
            return True

    def abandon(self) -> bool:
        """The request stops waiting; True when no worker had taken the job yet."""
        with self._lock:
            if self.state == "queued":
                self.state = "abandoned"
                return True
            return False

    def answer(self, outcome: Outcome) -> None:
        with self._lock:
            self.state = "done"

        def resolve():
            if not self.future.done():
                self.future.set_result(outcome)
        try:
            self.loop.call_soon_threadsafe(resolve)
        except RuntimeError:   # the loop is closed: nobody is waiting any more
            pass


class Slot(threading.Thread):
    """One worker process and the thread that feeds it."""

    def __init__(self, pool: "WorkerPool", index: int):
        super().__init__(name=f"glraster-slot-{index}", daemon=True)
        self.pool = pool
        self.index = index
        self.proc = None
        self.conn = None
        self.state = "starting"
        self.info: dict = {}
        self.error = ""
        self.requests = 0
        self.restarts = 0
        self.started = 0.0
        self.job = None

    # -- the process ----------------------------------------------------------------------
    def _spawn(self) -> bool:
        cfg = self.pool.config
        self.state = "starting"
        mp = multiprocessing.get_context("spawn")
        parent, child = mp.Pipe(duplex=True)
        proc = mp.Process(target=worker_main, args=(child, cfg.backend, cfg.limits),
                          name=f"glraster-worker-{self.index}", daemon=True)
        proc.start()
        child.close()
        self.proc, self.conn = proc, parent
        deadline = time.monotonic() + cfg.worker_start_timeout
        try:
            while not parent.poll(0.2):
                if not proc.is_alive() or time.monotonic() > deadline or self.pool.stopping.is_set():
                    raise TimeoutError("no working context reported in "
                                       f"{cfg.worker_start_timeout:g} s" if proc.is_alive()
                                       else f"exited with code {proc.exitcode} while starting")
            msg = parent.recv()
        except (TimeoutError, EOFError, OSError) as exc:
            msg = ("failed", str(exc) or type(exc).__name__)
        if msg[0] != "ready":
            self.error = msg[1]
            self._kill()
            self.state = "failed"
            return False
        self.info = msg[1]
        self.error = ""
        self.started = time.monotonic()
        self.state = "busy" if self.job is not None else "ready"   # a retry keeps it busy
        return True

    def _kill(self) -> None:
        proc, conn = self.proc, self.conn
        self.proc = self.conn = None
        if proc is not None:
            if proc.is_alive():
                proc.kill()
            proc.join(STOP_TIMEOUT)
        if conn is not None:
            conn.close()

    def _stop_process(self) -> None:
        proc, conn = self.proc, self.conn
        if proc is not None and conn is not None and proc.is_alive():
            try:
                conn.send(("stop",))
            except OSError:
                pass
            proc.join(STOP_TIMEOUT)
        self._kill()
        self.state = "stopped"

    def _replace(self, reason: str) -> None:
        self._kill()
        self.restarts += 1
        self.pool.metrics.restart(reason)
        if not self.pool.stopping.is_set():
            self._spawn()

    @property
    def pid(self):
        return self.proc.pid if self.proc is not None else None

    # -- the loop -------------------------------------------------------------------------
    def run(self) -> None:
        pool = self.pool
        backoff = 0.5
        while not pool.stopping.is_set():
            if self.proc is None or not self.proc.is_alive():
                if self.proc is not None:       # died while idle, or after answering a 500
                    self.restarts += 1
                    pool.metrics.restart("error" if self.proc.exitcode == 0 else "crash")
                    self._kill()
                if not self._spawn():
                    pool.metrics.restart("startup")
                    if pool.stopping.wait(backoff):
                        break
                    backoff = min(backoff * 2, 10.0)
                    continue
                backoff = 0.5
            try:
                job = pool.queue.get(timeout=0.25)
            except queue.Empty:
                continue
            if not job.claim():
                continue
            self.state = "busy"
            self.job = job
            try:
                job.answer(self._execute(job))
            except BaseException as exc:  # noqa: BLE001 - never leave a request unanswered
                job.answer(_error(503, "server", f"worker slot failed: {exc}"[:300], self.index))
                self._replace("crash")
            finally:
                self.job = None
                if self.state == "busy":
                    self.state = "ready"
        self._stop_process()

    def _execute(self, job: Job) -> Outcome:
        attempts = 0
        while True:
            remaining = job.deadline - time.monotonic()
            if remaining <= 0:
                return _error(504, "deadline", "the request's deadline passed while it was "
                                               "queued", self.index)
            if self.proc is None:
                return _error(503, "server", f"no worker: {self.error}"[:300], self.index)
            t0 = time.monotonic()
            try:
                self.conn.send((job.kind, job.meta))
                self.conn.send_bytes(job.body)
                answered = self.conn.poll(remaining)
                if answered:
                    status, ctype, headers = self.conn.recv()
                    body = self.conn.recv_bytes()
            except (EOFError, OSError):
                attempts += 1
                self._replace("crash")
                if attempts > RETRIES:
                    return _error(503, "server", "the worker rendering this request died twice; "
                                                 "it was not answered", self.index)
                continue
            if not answered:
                self._replace("deadline")
                return _error(504, "deadline",
                              f"the request was not done by its deadline "
                              f"({job.meta.get('deadline', 0):g} s); it was cancelled and its "
                              "worker replaced", self.index)
            self.requests += 1
            self.pool.note_service_time(time.monotonic() - t0)
            headers = dict(headers)
            if attempts:
                headers["x-glraster-retried"] = str(attempts)
            return Outcome(status, ctype, headers, body, self.index)


class WorkerPool:
    """``config.workers`` worker slots sharing a queue of ``config.queue_size`` jobs."""

    def __init__(self, config, metrics):
        self.config = config
        self.metrics = metrics
        self.queue: queue.Queue = queue.Queue(maxsize=max(config.queue_size, 0) or 1)
        self.capacity = config.queue_size
        self.stopping = threading.Event()
        self.slots = [Slot(self, i) for i in range(config.workers)]
        self._ewma = 0.05
        self._lock = threading.Lock()

    def start(self) -> None:
        for slot in self.slots:
            slot.start()

    def note_service_time(self, seconds: float) -> None:
        with self._lock:
            self._ewma = 0.9 * self._ewma + 0.1 * seconds

    def retry_after(self) -> int:
        """Seconds until a queued request would likely be taken (at least 1)."""
        with self._lock:
            per = self._ewma
        waiting = self.queue.qsize() + len(self.slots)
        return max(1, math.ceil(per * waiting / max(1, len(self.slots))))

    def submit(self, job: Job) -> None:
        """Queue ``job``; :class:`QueueFull` when the queue is full, :class:`Unavailable`
        when the pool is stopping or no worker has a working context."""
        if self.stopping.is_set():
            raise Unavailable("the server is shutting down")
        if not any(s.state in ("ready", "busy", "starting") for s in self.slots):
            errors = "; ".join(sorted({s.error for s in self.slots if s.error}))
            raise Unavailable(f"no worker has a working GL context ({errors or 'starting'})")
        if self.capacity == 0 and not any(s.state == "ready" for s in self.slots):
            raise QueueFull(self.retry_after())
        try:
            self.queue.put_nowait(job)
        except queue.Full:
            raise QueueFull(self.retry_after()) from None

    def ready(self) -> bool:
        return any(s.state in ("ready", "busy") for s in self.slots)

    def info(self) -> dict:
        for s in self.slots:
            if s.info:
                return dict(s.info)
        return {}

    def snapshot(self) -> dict:
        workers = [{"index": s.index, "pid": s.pid, "state": s.state, "requests": s.requests,
                    "restarts": s.restarts, "error": s.error} for s in self.slots]
        return {"queue_depth": self.queue.qsize(), "queue_capacity": self.capacity,
                "inflight": sum(w["state"] == "busy" for w in workers), "workers": workers}

    def stop(self) -> None:
        """Stop taking jobs, answer what is still queued with 503, stop the workers."""
        self.stopping.set()
        while True:
            try:
                job = self.queue.get_nowait()
            except queue.Empty:
                break
            if job.claim():
                job.answer(_error(503, "server", "the server shut down before a worker took "
                                                 "this request"))
        for slot in self.slots:
            slot.join(STOP_TIMEOUT + 30.0)
