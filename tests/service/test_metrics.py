"""glraster.service.metrics without a server: what Metrics records, read back through
prometheus_client's own parser of the exposition text (exact values: counts are integers,
the durations sums of the exact floats given)."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("prometheus_client")

from prometheus_client.parser import text_string_to_metric_families  # noqa: E402

from glraster.service.metrics import (BUCKETS, RESTART_REASONS, WORKER_STATES,  # noqa: E402
                                      Metrics, error_kind)


def _samples(metrics: Metrics) -> dict:
    out = {}
    for family in text_string_to_metric_families(metrics.render().decode()):
        for s in family.samples:
            key = (s.name, tuple(sorted(s.labels.items())))
            assert key not in out, key
            out[key] = s.value
    return out


def _get(samples, name, **labels):
    return samples.get((name, tuple(sorted(labels.items()))))


class FakePool:
    """What Metrics.watch reads: WorkerPool.snapshot()'s keys."""

    def __init__(self, workers, depth=0, capacity=4, inflight=0):
        self.snap = {"queue_depth": depth, "queue_capacity": capacity, "inflight": inflight,
                     "workers": workers}

    def snapshot(self):
        return self.snap


def test_error_kind_of_each_status_class():
    assert [error_kind(s) for s in (200, 204, 400, 401, 404, 413, 429, 500, 503, 504)] == [
        None, None, "client", "client", "client", "client", "rejected", "server", "server",
        "deadline"]


def test_requests_errors_and_histogram_after_known_observations():
    m = Metrics()
    for status, seconds in ((200, 0.0004), (200, 0.003), (200, 0.75), (400, 0.001),
                            (429, 0.0001), (504, 2.0)):
        m.observe("rasterize", status, seconds)
    m.observe("other", 404, 0.0)
    s = _samples(m)
    assert _get(s, "glraster_requests_total", endpoint="rasterize", status="200") == 3
    assert _get(s, "glraster_requests_total", endpoint="rasterize", status="400") == 1
    assert _get(s, "glraster_requests_total", endpoint="other", status="404") == 1
    assert _get(s, "glraster_errors_total", endpoint="rasterize", kind="client") == 1
    assert _get(s, "glraster_errors_total", endpoint="rasterize", kind="rejected") == 1
    assert _get(s, "glraster_errors_total", endpoint="rasterize", kind="deadline") == 1
    assert _get(s, "glraster_errors_total", endpoint="other", kind="client") == 1
    # a 200 is no error: no series for it
    assert _get(s, "glraster_errors_total", endpoint="rasterize", kind="server") is None
    # cumulative buckets: <=0.5 ms holds 0.0004 and 0.0001; <=1 ms adds 0.001; ...
    bucket = {b: _get(s, "glraster_request_duration_seconds_bucket", endpoint="rasterize",
                      le=repr(float(b))) for b in BUCKETS}
    assert (bucket[0.0005], bucket[0.001], bucket[0.005], bucket[1.0], bucket[2.0]) == (
        2, 3, 4, 5, 6)
    assert _get(s, "glraster_request_duration_seconds_bucket", endpoint="rasterize",
                le="+Inf") == 6
    assert _get(s, "glraster_request_duration_seconds_count", endpoint="rasterize") == 6
    total = _get(s, "glraster_request_duration_seconds_sum", endpoint="rasterize")
    assert total == pytest.approx(0.0004 + 0.003 + 0.75 + 0.001 + 0.0001 + 2.0, rel=1e-12)


def test_restarts_start_at_zero_and_count_by_reason():
    m = Metrics()
    assert {r: _get(_samples(m), "glraster_worker_restarts_total", reason=r)
            for r in RESTART_REASONS} == dict.fromkeys(RESTART_REASONS, 0)
    m.restart("crash")
    m.restart("crash")
    m.restart("deadline")
    s = _samples(m)
    assert _get(s, "glraster_worker_restarts_total", reason="crash") == 2
    assert _get(s, "glraster_worker_restarts_total", reason="deadline") == 1
    assert _get(s, "glraster_worker_restarts_total", reason="error") == 0


def test_restart_of_an_unknown_reason_is_a_value_error():
    with pytest.raises(ValueError, match="reason"):
        Metrics().restart("bored")


def test_each_server_has_its_own_registry():
    a, b = Metrics(), Metrics()             # no "Duplicated timeseries" from a shared registry
    a.observe("rasterize", 200, 0.01)
    assert _get(_samples(a), "glraster_requests_total", endpoint="rasterize", status="200") == 1
    assert _get(_samples(b), "glraster_requests_total", endpoint="rasterize",
                status="200") is None


def test_pool_gauges_are_read_at_each_scrape():
    workers = [{"index": 0, "pid": os.getpid(), "state": "busy"},
               {"index": 1, "pid": None, "state": "starting"},
               {"index": 2, "pid": None, "state": "failed"}]
    pool = FakePool(workers, depth=3, capacity=8, inflight=2)
    m = Metrics()
    m.watch(pool)
    s = _samples(m)
    assert (_get(s, "glraster_queue_depth"), _get(s, "glraster_queue_capacity"),
            _get(s, "glraster_inflight_requests")) == (3, 8, 2)
    assert {st: _get(s, "glraster_workers", state=st) for st in WORKER_STATES} == {
        "starting": 1, "ready": 0, "busy": 1, "failed": 1, "stopped": 0}
    # resident memory only for a worker with a process (this test's own, > 1 MiB)
    assert _get(s, "glraster_worker_resident_bytes", worker="0") > 2**20
    assert _get(s, "glraster_worker_resident_bytes", worker="1") is None
    assert _get(s, "process_resident_memory_bytes") > 2**20
    pool.snap["queue_depth"] = 0                          # the next scrape sees the change
    assert _get(_samples(m), "glraster_queue_depth") == 0


def test_watching_two_pools_is_refused():
    m = Metrics()
    m.watch(FakePool([]))
    with pytest.raises(ValueError, match="glraster_queue_depth"):
        m.watch(FakePool([]))
