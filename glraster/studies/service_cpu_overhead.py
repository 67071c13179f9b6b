"""CPU the service spends per request beyond the in-process call, 256x256 torus, JSON result.

    glraster study service-cpu-overhead [--backend egl] [--rounds 8] [--per 200]

The service's latency goal (<= 1 ms over an in-process ``glraster.rasterize`` plus the JSON
statistics, docs/service.md) is a wall-clock figure, which on a machine whose cores are
shared with other work measures the scheduler: a request crosses three processes (client,
server, worker), and each hand-off waits for a core. The CPU time the server and its
worker spend per request does not wait: it is what the machinery costs, and on idle cores
the latency overhead is that serial work plus four wake-ups (client -> server -> worker ->
server -> client). This measures it, with prometheus_client's metrics observed on every
request and ``/metrics`` scraped once per round (as a Prometheus would, every 15 s):

- per round, ``per`` requests at concurrency 1 to a 1-worker ``glraster serve`` (CPU of the
  server and worker processes, every thread, from /proc/PID/task/*/schedstat in ns), then
  ``per`` in-process calls on a context of this process (the same scene, the same
  statistics; CPU of this process the same way);
- rounds interleave the two (the machine's speed drifts); printed are the medians of the
  rounds and of the per-round differences, in ms per request, and the wall-clock p50s of
  the same rounds (on a shared machine these carry the scheduler's waits), and the least
  CPU per request of any round on each side (other work only adds CPU time: cache and
  core contention);
- the CPU one scrape of ``/metrics`` costs the server.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from glraster.client import Client, encode_scene
from glraster.studies.registry import argument_parser
from glraster.studies.loadtest import (
    InProcess,
    StartedServer,
    _run,
    http_request,
    make_scene,
    run_load,
)


def cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) of every thread of process ``pid`` so far."""
    total = 0
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/schedstat") as f:
                total += int(f.read().split()[0])
        except (FileNotFoundError, ProcessLookupError):
            pass   # a thread that ended between the listing and the read
    return total * 1e-9


def main(argv=None) -> int:
    parser = argument_parser("service-cpu-overhead", __doc__)
    parser.add_argument("--backend", default=None)
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--per", type=int, default=200, help="requests (calls) per round")
    args = parser.parse_args(argv)

    server = StartedServer(args.backend, 1)
    client = Client(server.url)
    local = None
    try:
        client.wait_ready(120)
        pids = [server.proc.pid] + [w["pid"] for w in client.info()["workers"]]
        pos, tri, res = make_scene("256")
        req = http_request(server.host, server.port, "/v1/rasterize", encode_scene(pos, tri, res),
                           "application/x-npz", "application/json")
        _run(run_load(server.host, server.port, req, 50, 1, 60.0))            # warm-up
        local = InProcess(args.backend, "256")
        local.times(20)
        me = os.getpid()
        rows = []
        for _ in range(args.rounds):
            before = [cpu_seconds(p) for p in pids]
            load = _run(run_load(server.host, server.port, req, args.per, 1, 120.0))
            spent = [(cpu_seconds(p) - b) / load["requests"] for p, b in zip(pids, before)]
            before = cpu_seconds(server.proc.pid)
            client.metrics()
            scrape_cpu = cpu_seconds(server.proc.pid) - before
            before = cpu_seconds(me)
            wall = local.times(args.per)
            local_cpu = (cpu_seconds(me) - before) / args.per
            before = cpu_seconds(me)
            local.times(args.per, reuse=True)
            reuse_cpu = (cpu_seconds(me) - before) / args.per
            rows.append({"service_cpu": sum(spent), "server_cpu": spent[0],
                         "worker_cpu": sum(spent[1:]), "local_cpu": local_cpu,
                         "reuse_cpu": reuse_cpu,
                         "service_p50": load["p50_ms"] * 1e-3,
                         "local_p50": statistics.median(wall), "scrape_cpu": scrape_cpu})
    finally:
        if local is not None:
            local.close()
        client.close()
        server.stop()

    def med(key):
        return statistics.median(r[key] for r in rows) * 1e3

    cpu_over = [(r["service_cpu"] - r["local_cpu"]) * 1e3 for r in rows]
    wall_over = [(r["service_p50"] - r["local_p50"]) * 1e3 for r in rows]
    print(f"256x256 torus, JSON result, {args.rounds} interleaved rounds of {args.per}, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"CPU per request: service (server + worker) {med('service_cpu'):.3f} ms, in process "
          f"{med('local_cpu'):.3f} ms: overhead {statistics.median(cpu_over):+.3f} ms "
          f"(rounds {min(cpu_over):+.3f} .. {max(cpu_over):+.3f})")
    low = {k: min(r[k] for r in rows) * 1e3 for k in ("service_cpu", "local_cpu", "reuse_cpu")}
    print(f"  least of the rounds (other work only adds CPU time): service "
          f"{low['service_cpu']:.3f} ms, in process {low['local_cpu']:.3f} ms: "
          f"{low['service_cpu'] - low['local_cpu']:+.3f} ms; against out= "
          f"{low['reuse_cpu']:.3f} ms: {low['service_cpu'] - low['reuse_cpu']:+.3f} ms")
    print(f"  server {med('server_cpu'):.3f} ms, worker {med('worker_cpu'):.3f} ms; in process "
          f"into the previous call's arrays (out=, as the worker renders) {med('reuse_cpu'):.3f} ms")
    print(f"wall p50: service {med('service_p50'):.3f} ms, in process {med('local_p50'):.3f} ms: "
          f"{statistics.median(wall_over):+.3f} ms (rounds {min(wall_over):+.3f} .. "
          f"{max(wall_over):+.3f})")
    print(f"one /metrics scrape: {med('scrape_cpu'):.3f} ms of server CPU")
    return 0


if __name__ == "__main__":
    t0 = time.perf_counter()
    code = main()
    print(f"({time.perf_counter() - t0:.0f} s)")
    sys.exit(code)
