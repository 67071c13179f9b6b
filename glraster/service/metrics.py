"""Prometheus metrics of the service, kept and rendered by ``prometheus_client``.

Exposed at ``GET /metrics`` in the Prometheus text format 0.0.4; each server has its own
registry (:attr:`Metrics.registry`), so several servers or tests in one process never share
a series:

- ``glraster_requests_total{endpoint, status}``          counter: requests answered
- ``glraster_request_duration_seconds{endpoint}``        histogram: arrival to answer, in s
  (buckets :data:`BUCKETS`)
- ``glraster_errors_total{endpoint, kind}``              counter: answers that are not a
  result, by the status's kind: ``client`` (4xx but 429), ``rejected`` (429, queue full),
  ``deadline`` (504), ``server`` (other 5xx: 500, and 503 when no worker is ready, the
  worker rendering the request died, or the server is stopping)
- ``glraster_worker_restarts_total{reason}``             counter: worker processes replaced,
  ``crash``, ``deadline`` (killed at a request's deadline), ``error`` (exited cleanly after
  an error), ``startup`` (failed to start); all four reasons are always present
- ``glraster_queue_depth`` / ``glraster_queue_capacity``  gauges: requests waiting for a
  worker / waiting requests accepted before 429
- ``glraster_inflight_requests``                         gauge: requests held by workers
- ``glraster_workers{state}``                            gauge: worker slots by state,
  ``starting``, ``ready``, ``busy``, ``failed``, ``stopped`` (all five always present)
- ``glraster_worker_resident_bytes{worker}``             gauge: RSS of each running worker
- ``process_*`` (``process_resident_memory_bytes``, ``process_cpu_seconds_total``, ...) of
  the server process, from ``prometheus_client``'s process collector (Linux /proc)

Counters and the histogram are updated on the request path (:meth:`Metrics.observe`,
:meth:`Metrics.restart`); the gauges are read from the worker pool when ``/metrics`` is
scraped (:meth:`Metrics.watch`), so a request pays nothing for them.
"""

from __future__ import annotations

import os
from collections import Counter as Tally

from prometheus_client import (CONTENT_TYPE_PLAIN_0_0_4, CollectorRegistry, Counter,
                               Histogram, ProcessCollector, generate_latest)
from prometheus_client.core import GaugeMetricFamily

#: Upper bounds (s) of the request-duration histogram: 0.5 ms (a cached answer) to 10 min
#: (the longest deadline).
BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0,
           10.0, 30.0, 60.0, 120.0, 300.0, 600.0)
RESTART_REASONS = ("crash", "deadline", "error", "startup")
WORKER_STATES = ("starting", "ready", "busy", "failed", "stopped")
#: The media type of :meth:`Metrics.render`'s text.
CONTENT_TYPE = CONTENT_TYPE_PLAIN_0_0_4


def rss_bytes(pid: int | str = "self") -> int | None:
    """Resident set size of a process in bytes, from /proc (None where unavailable)."""
    try:
        with open(f"/proc/{pid}/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def error_kind(status: int) -> str | None:
    """The ``kind`` label of ``glraster_errors_total`` for an HTTP status (None: a result)."""
    if status == 429:
        return "rejected"
    if status == 504:
        return "deadline"
    if 400 <= status < 500:
        return "client"
    if status >= 500:
        return "server"
    return None


class _PoolCollector:
    """The queue and worker gauges, read from a WorkerPool's ``snapshot()`` at each scrape."""

    def __init__(self, pool):
        self.pool = pool

    @staticmethod
    def _families():
        return (
            GaugeMetricFamily("glraster_queue_depth", "Requests waiting for a worker."),
            GaugeMetricFamily("glraster_queue_capacity",
                              "Waiting requests accepted before 429."),
            GaugeMetricFamily("glraster_inflight_requests",
                              "Requests held by a worker (rendering or next)."),
            GaugeMetricFamily("glraster_workers", "Worker processes by state.",
                              labels=["state"]),
            GaugeMetricFamily("glraster_worker_resident_bytes",
                              "Resident memory of each worker process.", labels=["worker"]),
        )

    def describe(self):
        # Names only, so that registering checks them against the registry's others.
        return self._families()

    def collect(self):
        depth, capacity, inflight, workers, resident = self._families()
        snap = self.pool.snapshot()
        depth.add_metric([], snap["queue_depth"])
        capacity.add_metric([], snap["queue_capacity"])
        inflight.add_metric([], snap["inflight"])
        states = Tally(w["state"] for w in snap["workers"])
        for state in WORKER_STATES:
            workers.add_metric([state], states.get(state, 0))
        for w in snap["workers"]:
            rss = rss_bytes(w["pid"]) if w["pid"] else None
            if rss is not None:
                resident.add_metric([str(w["index"])], rss)
        return depth, capacity, inflight, workers, resident


class Metrics:
    """The counters, histogram and gauges of one server, in their own registry."""

    def __init__(self):
        self.registry = CollectorRegistry()
        self._requests = Counter("glraster_requests", "Requests answered, by endpoint and "
                                 "status.", ["endpoint", "status"], registry=self.registry)
        self._duration = Histogram("glraster_request_duration_seconds", "Time from arrival "
                                   "to answer.", ["endpoint"], buckets=BUCKETS,
                                   registry=self.registry)
        self._errors = Counter("glraster_errors", "Requests not answered with a result, by "
                               "kind.", ["endpoint", "kind"], registry=self.registry)
        self._restarts = Counter("glraster_worker_restarts", "Worker processes replaced, by "
                                 "reason.", ["reason"], registry=self.registry)
        for reason in RESTART_REASONS:
            self._restarts.labels(reason)          # present (at 0) before the first restart
        ProcessCollector(registry=self.registry)
        # (endpoint, status) -> its bound series: labels() validates and locks on every call,
        # a dict hit does not (a racing first insert binds the same children twice: harmless).
        self._bound: dict = {}

    def watch(self, pool) -> None:
        """Expose ``pool``'s (a WorkerPool) queue and worker gauges, read at each scrape."""
        self.registry.register(_PoolCollector(pool))

    def observe(self, endpoint: str, status: int, seconds: float) -> None:
        """Count one answered request: its status, its duration (s) and its error kind."""
        bound = self._bound.get((endpoint, status))
        if bound is None:
            kind = error_kind(status)
            bound = self._bound[(endpoint, status)] = (
                self._requests.labels(endpoint, str(status)),
                self._duration.labels(endpoint),
                self._errors.labels(endpoint, kind) if kind else None)
        requests, duration, errors = bound
        requests.inc()
        duration.observe(seconds)
        if errors is not None:
            errors.inc()

    def restart(self, reason: str) -> None:
        """Count one worker replaced; ``reason`` is one of :data:`RESTART_REASONS`."""
        if reason not in RESTART_REASONS:
            raise ValueError(f"reason: {reason!r} is not one of {', '.join(RESTART_REASONS)}")
        self._restarts.labels(reason).inc()

    def render(self) -> bytes:
        """The exposition text (format 0.0.4, media type :data:`CONTENT_TYPE`), UTF-8."""
        return generate_latest(self.registry)
