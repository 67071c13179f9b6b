"""The worker pool: N worker processes, one bounded queue, deadlines, crash recovery.

Everything runs on the server's event loop: one asyncio task per worker (a *slot*) takes
jobs from the shared queue, writes each to its process over a socket pair and reads the
answers, non-blocking (no thread sits between the event loop and the worker, so a request
costs one hand-off to the worker and one back). A worker holds up to ``PIPELINE`` jobs:
the one it renders and the next, which waits in its pipe, so that it starts the next job
the moment it has answered instead of waiting for the event loop to take the answer and
send more (on two cores shared with the server, that wait left the cores idle about 40 %
of the time). The worker answers in order; the slot watches the oldest job's deadline:

- answer in time: delivered to the waiting request, and the worker topped up at once;
- no answer by the deadline (a hang, or simply too slow): the process is killed, the
  request answered 504, a fresh process started and the jobs behind it sent to it;
- the process died (EOF on the pipe): a fresh process is started and the job it was
  rendering retried on it once (a second death answers 503); the jobs behind it had not
  started and are sent again as they are. No other request is affected.

A job that waited in a worker until its deadline is refused by the worker (504) without
being rendered. A slot whose process died while idle replaces it before taking the next
job. A job goes straight to an idle slot (the last to become idle, whose caches are warm),
else to a worker with room; beyond that, requests wait in the queue (``queue_size``);
when it is full :meth:`submit` raises :class:`QueueFull` with a Retry-After estimate from
the recent service times. Starting and joining processes (rare) run in the loop's default
executor, so they never block the loop.

The wire format is :mod:`glraster.service.wire`'s: one frame per message, a pickled header
(``(kind, meta)`` for a job, ``(status, content_type, headers)`` for an answer) and the raw
body, read by the event loop straight into the answer's final buffer.
"""

from __future__ import annotations

import asyncio
import collections
import math
import multiprocessing
import os
import socket
import time

from glraster.service.cells import Arena
from glraster.service.wire import Died, FrameProtocol
from glraster.service.worker import worker_main

RETRIES = 1            # a job whose worker died is retried this many times
STOP_TIMEOUT = 5.0     # seconds a worker gets to exit after "stop" before it is killed
IDLE_CHECK = 0.25      # seconds between liveness checks of an idle worker
PIPELINE = 2           # jobs a worker holds: the one it renders and the next, so that it
                       # never waits for the event loop between jobs
PIPELINE_GRACE = 0.05  # seconds a job that waited in a worker gets past its deadline
_SOCKET_BUFFER = 4 << 20   # bytes in flight on a worker's pipe (capped by net.core.wmem_max)


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
    """One request for a worker. ``deadline`` is a ``time.monotonic()`` instant. Used only
    on the event loop's thread."""

    def __init__(self, kind: str, meta: dict, body: bytes, deadline: float, loop):
        self.kind, self.meta, self.body, self.deadline = kind, meta, body, deadline
        self.loop = loop
        self.future = loop.create_future()
        self.state = "queued"       # queued -> running -> done, or queued -> abandoned
        self.attempts = 0           # deaths of a worker rendering it
        meta["expires"] = deadline  # the worker refuses the job after this (monotonic)

    def claim(self) -> bool:
        """A slot takes the job (False: the request gave up while it was queued)."""
        if self.state != "queued" or self.future.done():
            return False
        self.state = "running"
        return True

    def abandon(self) -> bool:
        """The request stops waiting; True when no worker had taken the job yet."""
        if self.state == "queued":
            self.state = "abandoned"
            return True
        return False

    def answer(self, outcome: Outcome) -> None:
        self.state = "done"
        if not self.future.done():
            self.future.set_result(outcome)


def _expire(answer: asyncio.Future) -> None:
    if not answer.done():
        answer.set_exception(asyncio.TimeoutError())


class Slot:
    """One worker process and the task that feeds it."""

    def __init__(self, pool: "WorkerPool", index: int):
        self.pool = pool
        self.index = index
        self.proc = None
        self.channel = None          # wire.FrameProtocol on the worker's socket pair
        self.state = "starting"
        self.info: dict = {}
        self.error = ""
        self.requests = 0
        self.restarts = 0
        self.started = 0.0
        self.sent = collections.deque()   # jobs written to the worker, not yet answered
        self.arena = None            # cells.Arena: shared memory for its .npz results
        self.task = None
        self._waiter = None          # a future while idle: submit hands a job through it
        self._reaping = []           # tasks joining killed processes

    # -- the process ----------------------------------------------------------------------
    async def _spawn(self) -> bool:
        cfg = self.pool.config
        loop = asyncio.get_running_loop()
        self.state = "starting"
        mp = multiprocessing.get_context("spawn")
        parent, child_sock = socket.socketpair()
        for sock in (parent, child_sock):   # a body or result in one write where allowed
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _SOCKET_BUFFER)
            except OSError:
                pass
        if self.arena is None and hasattr(os, "memfd_create"):
            self.arena = Arena()
        shared = self.arena.shared() if self.arena is not None else None
        proc = mp.Process(target=worker_main, args=(child_sock, cfg.backend, cfg.limits, shared),
                          name=f"glraster-worker-{self.index}", daemon=True)
        try:
            await loop.run_in_executor(None, proc.start)
        except BaseException as exc:  # noqa: BLE001 - reported as the slot's error
            child_sock.close()
            parent.close()
            self.error = f"could not start a worker: {exc}"[:300]
            self.state = "failed"
            return False
        child_sock.close()
        self.proc = proc
        _, self.channel = await loop.create_unix_connection(FrameProtocol, sock=parent)
        deadline = time.monotonic() + cfg.worker_start_timeout
        first = self.channel.expect()
        msg = None
        try:
            while msg is None:
                done, _ = await asyncio.wait({first}, timeout=0.2)
                if done:
                    msg = first.result()[0]
                elif time.monotonic() > deadline or self.pool.stopping:
                    raise TimeoutError(f"no working context reported in "
                                       f"{cfg.worker_start_timeout:g} s")
        except (Died, ConnectionError, OSError):
            for _ in range(20):
                if not proc.is_alive():
                    break
                await asyncio.sleep(0.05)
            msg = ("failed", f"exited with code {proc.exitcode} while starting"
                   if not proc.is_alive() else "the worker closed its pipe while starting")
        except TimeoutError as exc:
            msg = ("failed", str(exc))
        except Exception as exc:  # noqa: BLE001 - an unreadable first message
            msg = ("failed", f"{type(exc).__name__}: {exc}")
        finally:
            if not first.done():
                first.cancel()
        if msg[0] != "ready":
            self.error = msg[1]
            self._kill()
            self.state = "failed"
            return False
        self.info = msg[1]
        self.error = ""
        self.started = time.monotonic()
        self.state = "busy" if self.sent else "ready"   # a retry keeps it busy
        return True

    def _kill(self) -> None:
        """Kill the process (a signal: immediate) and close the pipe; it is joined in the
        background."""
        proc, channel = self.proc, self.channel
        self.proc = self.channel = None
        if channel is not None:
            channel.close()
        if proc is not None:
            if proc.is_alive():
                proc.kill()
            task = asyncio.ensure_future(
                asyncio.get_running_loop().run_in_executor(None, proc.join, STOP_TIMEOUT))
            self._reaping.append(task)
            task.add_done_callback(self._reaping.remove)

    async def _stop_process(self) -> None:
        proc, channel = self.proc, self.channel
        if proc is not None and channel is not None and proc.is_alive():
            try:
                channel.send(("stop",))
            except (OSError, ConnectionError, RuntimeError):
                pass
            await asyncio.get_running_loop().run_in_executor(None, proc.join, STOP_TIMEOUT)
        self._kill()
        if self._reaping:
            await asyncio.wait(list(self._reaping))
        self.state = "stopped"

    async def _replace(self, reason: str, respawn: bool = True) -> None:
        self._kill()
        self.restarts += 1
        self.pool.metrics.restart(reason)
        if respawn and not self.pool.stopping:
            await self._spawn()

    @property
    def pid(self):
        return self.proc.pid if self.proc is not None else None

    # -- the loop -------------------------------------------------------------------------
    async def _next_job(self):
        """The next job: from the queue, or handed over by :meth:`WorkerPool.submit`
        while idle; None after ``IDLE_CHECK`` seconds without one."""
        job = self.pool.take()
        if job is not None:
            return job
        waiter = asyncio.get_running_loop().create_future()
        self._waiter = waiter
        self.pool.idle.append(self)
        try:
            await asyncio.wait({waiter}, timeout=IDLE_CHECK)
        finally:
            if self._waiter is waiter:       # nobody handed a job over
                self._waiter = None
                self.pool.idle.remove(self)
        if waiter.done() and not waiter.cancelled():
            return waiter.result()            # already claimed by submit
        waiter.cancel()
        return None

    def can_take(self) -> bool:
        """The worker is up and holds fewer than ``PIPELINE`` jobs."""
        return (self.channel is not None and self.state == "busy"
                and 0 < len(self.sent) < PIPELINE)

    def send(self, job: Job) -> None:
        """Write a claimed job to the worker (it answers jobs in the order they were sent);
        a job asking for .npz gets a shared-memory cell for its result when one is free."""
        if self.arena is not None and job.meta.get("accept") == "npz" and "cell" not in job.meta:
            cell = self.arena.take()
            if cell is not None:
                job.meta["cell"] = cell
        self.channel.send((job.kind, job.meta), job.body)
        self.sent.append(job)
        self.state = "busy"

    def _top_up(self) -> None:
        while len(self.sent) < PIPELINE and not self.pool.stopping:
            job = self.pool.take()
            if job is None:
                return
            self.send(job)

    def _settle(self, job: Job, outcome: Outcome) -> None:
        """Answer a job; a cell it still holds is free again."""
        cell = job.meta.pop("cell", None)
        if cell is not None:
            self.arena.give_back(cell)
        job.answer(outcome)

    def _answer_all(self, status: int, message: str) -> None:
        while self.sent:
            self._settle(self.sent.popleft(), _error(status, "server", message, self.index))

    async def run(self) -> None:
        pool = self.pool
        backoff = 0.5
        try:
            while not pool.stopping or self.sent:
                # (the pipe tells a death: no process poll per job)
                if self.proc is None or self.channel.closed:
                    if self.proc is not None:    # died while idle, or after answering a 500
                        self.restarts += 1
                        clean = not self.proc.is_alive() and self.proc.exitcode == 0
                        pool.metrics.restart("error" if clean else "crash")
                        self._kill()
                    if not await self._spawn():
                        pool.metrics.restart("startup")
                        self._answer_all(503, f"no worker: {self.error}"[:300])
                        try:
                            await asyncio.wait_for(pool.stopped.wait(), backoff)
                            break
                        except asyncio.TimeoutError:
                            pass
                        backoff = min(backoff * 2, 10.0)
                        continue
                    backoff = 0.5
                    for job in self.sent:       # jobs a dead worker had not answered
                        self.channel.send((job.kind, job.meta), job.body)
                if not self.sent:
                    job = await self._next_job()
                    if job is None:
                        continue
                    self.send(job)
                self._top_up()
                try:
                    await self._settle_oldest()
                except asyncio.CancelledError:
                    self._answer_all(503, "the server shut down while rendering this request")
                    raise
                except BaseException as exc:  # noqa: BLE001 - never leave a request unanswered
                    self._answer_all(503, f"worker slot failed: {exc}"[:300])
                    await self._replace("crash", respawn=False)
                if not self.sent and self.state == "busy":
                    self.state = "ready"
        finally:
            await self._stop_process()

    async def _settle_oldest(self) -> None:
        """Wait for the answer to the oldest job sent, up to its deadline, and deliver it;
        on a deadline or a death, settle what the worker held."""
        job = self.sent[0]
        t0 = time.monotonic()
        answer = self.channel.expect()
        # A job that waited behind another in the worker may start near its deadline: the
        # worker answers 504 itself when it has passed, so it gets a moment for that.
        timer = asyncio.get_running_loop().call_later(
            max(job.deadline - t0, PIPELINE_GRACE), _expire, answer)
        try:
            (status, ctype, headers, cell_bytes), body = await answer
        except asyncio.TimeoutError:
            self.sent.popleft()
            self._kill()            # replaced at the top of the loop; the others are resent
            self.restarts += 1
            self.pool.metrics.restart("deadline")
            self._settle(job, _error(504, "deadline", f"the request was not done by its deadline "
                                               f"({job.meta.get('deadline', 0):g} s); it was "
                                               "cancelled and its worker replaced", self.index))
            return
        except (Died, ConnectionError, OSError):
            # the worker died rendering the oldest job; the jobs behind it never started
            job.attempts += 1
            if job.attempts > RETRIES:
                self.sent.popleft()
                self._settle(job, _error(503, "server", "the worker rendering this request died "
                                                 "twice; it was not answered", self.index))
            await self._replace("crash", respawn=False)
            return
        finally:
            timer.cancel()
        self.sent.popleft()
        self._top_up()              # the worker gets its next job before anything else runs
        self.requests += 1
        self.pool.note_service_time(time.monotonic() - t0)
        headers = dict(headers)
        if job.attempts:
            headers["x-glraster-retried"] = str(job.attempts)
        cell = job.meta.pop("cell", None)
        if cell is not None and cell_bytes:
            body = self.arena.result(cell, cell_bytes)   # the cell now belongs to the response
        elif cell is not None:
            self.arena.give_back(cell)
        job.answer(Outcome(status, ctype, headers, body, self.index))


class WorkerPool:
    """``config.workers`` worker slots sharing a queue of ``config.queue_size`` jobs. Every
    method is called on the event loop's thread."""

    def __init__(self, config, metrics):
        self.config = config
        self.metrics = metrics
        self.maxsize = max(config.queue_size, 0) or 1
        self.pending: collections.deque = collections.deque()
        self.idle: list = []
        self.capacity = config.queue_size
        self.stopping = False
        self.stopped = None
        self.slots = [Slot(self, i) for i in range(config.workers)]
        self._ewma = 0.05

    def start(self) -> None:
        self.stopped = asyncio.Event()
        for slot in self.slots:
            slot.task = asyncio.ensure_future(slot.run())

    def note_service_time(self, seconds: float) -> None:
        self._ewma = 0.9 * self._ewma + 0.1 * seconds

    def retry_after(self) -> int:
        """Seconds until a queued request would likely be taken (at least 1)."""
        waiting = len(self.pending) + len(self.slots)
        return max(1, math.ceil(self._ewma * waiting / max(1, len(self.slots))))

    def submit(self, job: Job) -> None:
        """Hand ``job`` to an idle worker or queue it; :class:`QueueFull` when the queue is
        full, :class:`Unavailable` when the pool is stopping or no worker has a working
        context."""
        if self.stopping:
            raise Unavailable("the server is shutting down")
        if not any(s.state in ("ready", "busy", "starting") for s in self.slots):
            errors = "; ".join(sorted({s.error for s in self.slots if s.error}))
            raise Unavailable(f"no worker has a working GL context ({errors or 'starting'})")
        while self.idle:
            slot = self.idle.pop()       # the last to become idle: its caches are warm
            waiter, slot._waiter = slot._waiter, None
            if waiter is not None and not waiter.done() and job.claim():
                slot.state = "busy"
                waiter.set_result(job)
                return
        if not self.pending:
            for slot in sorted(self.slots, key=lambda s: len(s.sent)):
                if slot.can_take() and job.claim():
                    slot.send(job)
                    return
        if self.capacity == 0 and not any(s.state == "ready" for s in self.slots):
            raise QueueFull(self.retry_after())
        if len(self.pending) >= self.maxsize:
            raise QueueFull(self.retry_after())
        self.pending.append(job)

    def take(self):
        """The next queued job a worker may start (claimed), or None."""
        while self.pending:
            job = self.pending.popleft()
            if job.claim():
                return job
        return None

    def ready(self) -> bool:
        return any(s.state in ("ready", "busy") for s in self.slots)

    def info(self) -> dict:
        for s in self.slots:
            if s.info:
                return dict(s.info)
        return {}

    def snapshot(self) -> dict:
        workers = [{"index": s.index, "pid": s.pid, "state": s.state, "jobs": len(s.sent),
                    "free_cells": s.arena.free if s.arena is not None else 0,
                    "requests": s.requests, "restarts": s.restarts, "error": s.error}
                   for s in self.slots]
        return {"queue_depth": len(self.pending), "queue_capacity": self.capacity,
                "inflight": sum(w["jobs"] for w in workers), "workers": workers}

    async def stop(self) -> None:
        """Stop taking jobs, answer what is still queued with 503, let the in-flight jobs
        finish, stop the workers."""
        self.stopping = True
        if self.stopped is not None:
            self.stopped.set()
        while self.pending:
            job = self.pending.popleft()
            if job.claim():
                job.answer(_error(503, "server", "the server shut down before a worker took "
                                                 "this request"))
        tasks = [s.task for s in self.slots if s.task is not None]
        if tasks:
            done, pending = await asyncio.wait(tasks, timeout=STOP_TIMEOUT + 30.0)
            for t in pending:
                t.cancel()
            if pending:
                await asyncio.wait(pending, timeout=STOP_TIMEOUT + 5.0)
