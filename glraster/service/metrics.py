"""Prometheus metrics of the service, in the text exposition format (no client library).

Exposed at ``GET /metrics``:

- ``glraster_requests_total{endpoint, status}``          counter
- ``glraster_request_duration_seconds{endpoint}``        histogram (arrival to answer)
- ``glraster_errors_total{endpoint, kind}``              counter: client (4xx), rejected
  (429, queue full), deadline (504), worker (a worker crashed or hung), server (5xx)
- ``glraster_queue_depth`` / ``glraster_queue_capacity``  gauges: requests waiting for a worker
- ``glraster_inflight_requests``                         gauge: requests held by workers
- ``glraster_workers{state}``                            gauge: ready, starting, failed
- ``glraster_worker_restarts_total{reason}``             counter: crash, deadline, error, startup
- ``glraster_worker_resident_bytes{worker}``             gauge: RSS of each worker process
- ``process_resident_memory_bytes``                      gauge: RSS of the server process

Counters are updated from the event loop (and, for safety, under one lock).
"""

from __future__ import annotations

import os
import threading
from collections import defaultdict

BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0,
           10.0, 30.0, 60.0, 120.0, 300.0, 600.0)


def rss_bytes(pid: int | str = "self") -> int | None:
    """Resident set size of a process from /proc (None where unavailable)."""
    try:
        with open(f"/proc/{pid}/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


class Metrics:
    """The counters, histograms and gauges of one server process."""

    def __init__(self):
        self._lock = threading.Lock()
        self.requests = defaultdict(int)            # (endpoint, status) -> n
        self.errors = defaultdict(int)              # (endpoint, kind) -> n
        self.restarts = defaultdict(int)            # reason -> n
        self.hist = {}                              # endpoint -> [bucket counts..., sum, n]

    def observe(self, endpoint: str, status: int, seconds: float) -> None:
        with self._lock:
            self.requests[(endpoint, status)] += 1
            h = self.hist.get(endpoint)
            if h is None:
                h = self.hist[endpoint] = [0] * len(BUCKETS) + [0.0, 0]
            for i, b in enumerate(BUCKETS):
                if seconds <= b:
                    h[i] += 1
                    break
            h[-2] += seconds
            h[-1] += 1
            kind = None
            if status == 429:
                kind = "rejected"
            elif status == 504:
                kind = "deadline"
            elif 400 <= status < 500:
                kind = "client"
            elif status >= 500:
                kind = "server"
            if kind:
                self.errors[(endpoint, kind)] += 1

    def error(self, endpoint: str, kind: str) -> None:
        with self._lock:
            self.errors[(endpoint, kind)] += 1

    def restart(self, reason: str) -> None:
        with self._lock:
            self.restarts[reason] += 1

    def render(self, pool=None) -> str:
        """The exposition text; ``pool`` (a WorkerPool) adds queue and worker gauges."""
        out = []
        with self._lock:
            out += ["# HELP glraster_requests_total Requests answered, by endpoint and status.",
                    "# TYPE glraster_requests_total counter"]
            for (ep, st), n in sorted(self.requests.items()):
                out.append(f'glraster_requests_total{{endpoint="{ep}",status="{st}"}} {n}')
            out += ["# HELP glraster_request_duration_seconds Time from arrival to answer.",
                    "# TYPE glraster_request_duration_seconds histogram"]
            for ep, h in sorted(self.hist.items()):
                acc = 0
                for b, c in zip(BUCKETS, h):
                    acc += c
                    out.append(f'glraster_request_duration_seconds_bucket{{endpoint="{ep}",'
                               f'le="{b:g}"}} {acc}')
                out.append(f'glraster_request_duration_seconds_bucket{{endpoint="{ep}",'
                           f'le="+Inf"}} {h[-1]}')
                out.append(f'glraster_request_duration_seconds_sum{{endpoint="{ep}"}} {h[-2]:.6f}')
                out.append(f'glraster_request_duration_seconds_count{{endpoint="{ep}"}} {h[-1]}')
            out += ["# HELP glraster_errors_total Requests not answered with a result, by kind.",
                    "# TYPE glraster_errors_total counter"]
            for (ep, kind), n in sorted(self.errors.items()):
                out.append(f'glraster_errors_total{{endpoint="{ep}",kind="{kind}"}} {n}')
            out += ["# HELP glraster_worker_restarts_total Worker processes replaced, by reason.",
                    "# TYPE glraster_worker_restarts_total counter"]
            for reason in ("crash", "deadline", "error", "startup"):
                out.append(f'glraster_worker_restarts_total{{reason="{reason}"}} '
                           f'{self.restarts.get(reason, 0)}')
        if pool is not None:
            snap = pool.snapshot()
            out += ["# HELP glraster_queue_depth Requests waiting for a worker.",
                    "# TYPE glraster_queue_depth gauge",
                    f"glraster_queue_depth {snap['queue_depth']}",
                    "# HELP glraster_queue_capacity Waiting requests accepted before 429.",
                    "# TYPE glraster_queue_capacity gauge",
                    f"glraster_queue_capacity {snap['queue_capacity']}",
                    "# HELP glraster_inflight_requests Requests held by a worker (rendering or next).",
                    "# TYPE glraster_inflight_requests gauge",
                    f"glraster_inflight_requests {snap['inflight']}",
                    "# HELP glraster_workers Worker processes by state.",
                    "# TYPE glraster_workers gauge"]
            states = defaultdict(int)
            for w in snap["workers"]:
                states[w["state"]] += 1
            for state in ("ready", "busy", "starting", "failed", "stopped"):
                out.append(f'glraster_workers{{state="{state}"}} {states.get(state, 0)}')
            out += ["# HELP glraster_worker_resident_bytes Resident memory of each worker.",
                    "# TYPE glraster_worker_resident_bytes gauge"]
            for w in snap["workers"]:
                rss = rss_bytes(w["pid"]) if w["pid"] else None
                if rss is not None:
                    out.append(f'glraster_worker_resident_bytes{{worker="{w["index"]}"}} {rss}')
        rss = rss_bytes()
        if rss is not None:
            out += ["# HELP process_resident_memory_bytes Resident memory of the server process.",
                    "# TYPE process_resident_memory_bytes gauge",
                    f"process_resident_memory_bytes {rss}"]
        return "\n".join(out) + "\n"
