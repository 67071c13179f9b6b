"""Cost of the service's metrics now against an earlier revision's, in process.

    python benchmarks/metrics_ab.py [REV]     # REV default 432fdaa, the hand-written text

Loads ``glraster/service/metrics.py`` of git revision REV beside the current one and times,
per call, what a request pays (``Metrics.observe`` of one answered request: its counter, its
histogram, its error counter) and what a scrape pays (rendering the exposition text with a
pool of 4 workers, after requests to 6 endpoints with 5 statuses). Rounds alternate between
the two modules (the machine's speed drifts); printed are the medians of the rounds and the
median of the per-round differences, in microseconds.
"""

from __future__ import annotations

import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from glraster.service import metrics as current  # noqa: E402

ENDPOINTS = ("rasterize", "check", "info", "healthz", "readyz", "metrics")
STATUSES = (200, 400, 429, 503, 504)


class FakePool:
    """WorkerPool.snapshot()'s shape: 4 workers, this process standing in for each."""

    def snapshot(self):
        return {"queue_depth": 1, "queue_capacity": 16, "inflight": 3,
                "workers": [{"index": i, "pid": os.getpid(), "state": "busy"}
                            for i in range(4)]}


def _load(rev: str):
    source = subprocess.run(["git", "show", f"{rev}:glraster/service/metrics.py"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "metrics_then.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("metrics_then", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["metrics_then"] = module
    spec.loader.exec_module(module)
    return module


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


def main(rev: str = "432fdaa", rounds: int = 15) -> None:
    then = _load(rev)
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


def _client_version() -> str:
    from importlib.metadata import version

    return version("prometheus_client")


if __name__ == "__main__":
    main(*sys.argv[1:2])
