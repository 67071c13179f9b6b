"""Cost of the service's metrics now against an earlier revision's, in process.

    glraster study metrics-ab [REV] [--rounds 15]     # REV default e60bcd9, the hand-written text

Loads ``glraster/service/metrics.py`` of git revision REV beside the current one and times,
per call, what a request pays (``Metrics.observe`` of one answered request: its counter, its
histogram, its error counter) and what a scrape pays (rendering the exposition text with a
pool of 4 workers, after requests to 6 endpoints with 5 statuses). Rounds alternate between
the two modules (the machine's speed drifts); printed are the medians of the rounds and the
median of the per-round differences, in microseconds.
"""

from __future__ import annotations

import os
import statistics
import time

from glraster.service import metrics as current
from glraster.studies.registry import argument_parser
from glraster.studies.revision import load_module_at

ENDPOINTS = ("rasterize", "check", "info", "healthz", "readyz", "metrics")
STATUSES = (200, 400, 429, 503, 504)


class FakePool:
    """WorkerPool.snapshot()'s shape: 4 workers, this process standing in for each."""

    def snapshot(self):
        return {"queue_depth": 1, "queue_capacity": 16, "inflight": 3,
                "workers": [{"index": i, "pid": os.getpid(), "state": "busy"}
                            for i in range(4)]}


def _filled(module, pool):
    m = module.Metrics()
    if hasattr(m, "watch"):
        m.watch(pool)
    for ep in ENDPOINTS:
        for st in STATUSES:
            m.observe(ep, st, 0.003)
    for reason in ("crash", "deadline"):
        m.restart(reason)
    return m


def _render(m, pool):
    return m.render() if hasattr(m, "watch") else m.render(pool)


def _per_call_us(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def main(argv=None) -> int:
    parser = argument_parser("metrics-ab", __doc__)
    parser.add_argument("rev", nargs="?", default="e60bcd9", metavar="REV",
                        help="the git revision to compare with (default e60bcd9)")
    parser.add_argument("--rounds", type=int, default=15, help="interleaved rounds")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    rev, rounds = args.rev, args.rounds
    then = load_module_at(rev, "glraster/service/metrics.py", "metrics_then")
    pool = FakePool()
    modules = {"then": then, "now": current}
    filled = {k: _filled(mod, pool) for k, mod in modules.items()}
    times = {(k, what): [] for k in modules for what in ("observe", "render")}
    for r in range(rounds):
        for k in (("then", "now") if r % 2 == 0 else ("now", "then")):
            m = filled[k]
            times[(k, "observe")].append(_per_call_us(
                lambda m=m: m.observe("rasterize", 200, 0.0042), 20000))
            times[(k, "render")].append(_per_call_us(lambda m=m: _render(m, pool), 200))
    print(f"metrics, {rev} (hand-written text) against now (prometheus_client "
          f"{_client_version()}); {rounds} interleaved rounds, medians in microseconds")
    for what, label in (("observe", "per request (observe)"), ("render", "per scrape (render)")):
        a, b = times[("then", what)], times[("now", what)]
        diff = statistics.median(y - x for x, y in zip(a, b))
        print(f"  {label:24s} then {statistics.median(a):8.2f}   now {statistics.median(b):8.2f}"
              f"   now - then {diff:+8.2f}")
    return 0


def _client_version() -> str:
    from importlib.metadata import version

    return version("prometheus_client")


if __name__ == "__main__":
    raise SystemExit(main())
