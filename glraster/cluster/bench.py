"""``glraster batch --bench``: what Ray costs next to rasterizing in-process (docs/cluster.md).

Four figures, each from interleaved rounds (A, B, A, B, ...) and reported as medians and,
for the throughput, also as the ratio of each side's best round (other jobs on shared cores
only slow a round down):

1. **throughput ratio**: 2 GLWorker actors, 2 tasks in flight each, against 2 plain
   processes (``multiprocessing``, spawn) each looping over ``rasterize`` on its own context;
   the same scene (catalog ``torus``, 256x256, 4096 triangles, all four outputs) and the same
   number of calls per worker; ratio = median actors' calls/s / median loops' calls/s; with
   a task per call, and with a task per :data:`SHARD_CALLS` calls (as ``glraster batch``
   renders a shard per task);
2. **per-task overhead** at 64x64 (one triangle) and 1024x1024 (two triangles covering the
   image): one call in flight, round-trip time minus the time the actor spent inside
   ``rasterize``; with the outputs returned through the object store and without;
3. **head cost per task**: CPU seconds of the calling process (the driver) and of the head's
   Ray daemons (``gcs_server``, ``raylet``) per task, during (1) with a task per call;
4. **shard formats**: one shard of 64 rasters (256x256, all outputs) written as a stored
   .npz (:func:`glraster.io.npz.write_npz`) and as Parquet with fixed-shape tensor columns
   (pyarrow, uncompressed), write and read seconds and bytes.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from glraster.cluster import runtime

OUTPUTS = ("persp", "screen", "depth", "tri_id")
# Calls per task in the shard-like variant of the throughput figure (glraster batch renders
# a shard of scenes per task).
SHARD_CALLS = 15


def _loop(pos, tri, resolution, calls, start, queue):
    """A baseline worker: its own context, one warm-up call, then ``calls`` rasterizes."""
    from glraster.gpu.context import Context
    from glraster.gpu.rasterize import rasterize

    ctx = Context()
    rasterize(pos, tri, resolution, ctx=ctx, outputs=OUTPUTS)
    start.wait()
    t = time.perf_counter()
    for _ in range(calls):
        rasterize(pos, tri, resolution, ctx=ctx, outputs=OUTPUTS)
    queue.put(time.perf_counter() - t)
    ctx.release()


def _loops_throughput(pos, tri, resolution, calls, workers=2) -> float:
    """Calls per second of ``workers`` processes looping over ``rasterize``."""
    import multiprocessing as mp

    spawn = mp.get_context("spawn")
    start, queue = spawn.Event(), spawn.Queue()
    procs = [spawn.Process(target=_loop, args=(pos, tri, resolution, calls, start, queue))
             for _ in range(workers)]
    for p in procs:
        p.start()
    time.sleep(0.5)
    # wait for the warm-up: the processes block on the event until every one is ready
    while any(p.is_alive() for p in procs) and not _all_waiting(procs):
        time.sleep(0.05)
    start.set()
    seconds = [queue.get(timeout=600) for _ in procs]
    for p in procs:
        p.join()
    return workers * calls / max(seconds)


def _all_waiting(procs) -> bool:
    """Whether every process sleeps (blocked on the start event, warm-up done)."""
    for p in procs:
        try:
            state = Path(f"/proc/{p.pid}/stat").read_text().split(")")[-1].split()[0]
        except OSError:
            return True
        if state != "S":
            return False
    return True


def _daemon_cpu() -> float:
    """CPU seconds so far of this machine's Ray head daemons (gcs_server, raylet)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")]
        if name in ("gcs_server", "raylet"):
            fields = stat[stat.rindex(")") + 2:].split()
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


def _actors_throughput(ray, actors, key, calls, resolution, per_task=1) -> tuple:
    """Calls per second of ``actors`` with 2 tasks of ``per_task`` calls in flight each; and
    the head's CPU seconds per task: (calls/s, driver CPU s per task, daemons' CPU s per
    task)."""
    c0, d0 = time.process_time(), _daemon_cpu()
    t = time.perf_counter()
    tasks = calls // per_task
    left = {a: tasks for a in actors}
    inflight = {}

    def submit(a):
        inflight[a.timed_rasterize.remote(key, None, None, resolution, OUTPUTS,
                                          repeat=per_task)] = a
        left[a] -= 1

    for a in actors:
        for _ in range(2):
            submit(a)
    while inflight:
        ready, _ = ray.wait(list(inflight), num_returns=1)
        a = inflight.pop(ready[0])
        ray.get(ready[0])
        if left[a] > 0:
            submit(a)
    wall = time.perf_counter() - t
    n = tasks * len(actors)
    return n * per_task / wall, (time.process_time() - c0) / n, (_daemon_cpu() - d0) / n


def _overhead(ray, actor, key, resolution, calls, arrays) -> dict:
    """Per-task figures with one call in flight: medians of round trip and inside time."""
    trips, inside = [], []
    for _ in range(calls):
        t = time.perf_counter()
        seconds, out = ray.get(actor.timed_rasterize.remote(
            key, None, None, resolution, OUTPUTS, arrays))
        trips.append(time.perf_counter() - t)
        inside.append(seconds)
        del out
    trip, work = statistics.median(trips), statistics.median(inside)
    return {"round_trip_ms": 1e3 * trip, "rasterize_ms": 1e3 * work,
            "overhead_ms": 1e3 * (trip - work)}


def _full_screen(size):
    pos = np.array([[-1, -1, 0.2, 1], [1, -1, 0.5, 1], [1, 1, 0.8, 1], [-1, 1, 0.4, 1]],
                   np.float32)
    return pos, np.array([[0, 1, 2], [0, 2, 3]], np.int32), (size, size)


def shard_formats(count=64, size=256, rounds=3) -> dict:
    """Write and read one shard of ``count`` rasters as .npz and as Parquet (medians)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from glraster.io.npz import write_npz

    rng = np.random.default_rng(0)
    rasters = [{"persp": rng.random((size, size, 3), dtype=np.float32),
                "screen": rng.random((size, size, 3), dtype=np.float32),
                "depth": rng.random((size, size), dtype=np.float32),
                "tri_id": rng.integers(-1, 4096, (size, size), dtype=np.int32)}
               for _ in range(count)]
    times = {"npz_write": [], "npz_read": [], "parquet_write": [], "parquet_read": []}
    sizes = {}
    with tempfile.TemporaryDirectory(prefix="glraster-shard-bench-") as tmp:
        for _ in range(rounds):
            t = time.perf_counter()
            arrays = {f"s{k:04d}.{n}": a for k, r in enumerate(rasters) for n, a in r.items()}
            Path(tmp, "s.npz").write_bytes(write_npz(arrays))
            times["npz_write"].append(time.perf_counter() - t)
            t = time.perf_counter()
            with np.load(Path(tmp, "s.npz")) as z:
                total = sum(int(z[k].sum() != 0) for k in z.files)
            times["npz_read"].append(time.perf_counter() - t)
            t = time.perf_counter()
            columns = {}
            for n in OUTPUTS:
                stack = np.stack([r[n] for r in rasters])
                columns[n] = pa.FixedShapeTensorArray.from_numpy_ndarray(stack)
            pq.write_table(pa.table(columns), Path(tmp, "s.parquet"), compression="none")
            times["parquet_write"].append(time.perf_counter() - t)
            t = time.perf_counter()
            table = pq.read_table(Path(tmp, "s.parquet"))
            for n in OUTPUTS:
                stack = table[n].combine_chunks().to_numpy_ndarray()
                total += sum(int(stack[k].sum() != 0) for k in range(count))
            times["parquet_read"].append(time.perf_counter() - t)
        sizes = {"npz_bytes": Path(tmp, "s.npz").stat().st_size,
                 "parquet_bytes": Path(tmp, "s.parquet").stat().st_size}
    out = {k: statistics.median(v) for k, v in times.items()}
    out.update(sizes, rasters=count, size=size)
    return out


def run(address=None, backend=None, rounds=7, calls=150, progress=None) -> dict:
    """All four figures as a dict (see the module docstring)."""
    from glraster.cluster.workers import remote_worker
    from glraster.conformance.scenes import load_scene

    say = progress or (lambda *_: None)
    ray = runtime.connect(address, [])
    scene = load_scene("torus")
    pos, tri, res = scene.pos, scene.tri, tuple(scene.resolution)
    actors = [remote_worker(ray, None, backend=backend) for _ in range(2)]  # the node's GL
    ray.get([a.timed_rasterize.remote("torus", pos, tri, res, OUTPUTS) for a in actors])
    loops, actor_rates, shard_rates, drv, dmn = [], [], [], [], []
    for r in range(rounds):
        say(f"round {r + 1}/{rounds}: 2 in-process loops, 2 actors with a task per call, "
            f"2 actors with a task per {SHARD_CALLS} calls ({calls} calls each)")
        loops.append(_loops_throughput(pos, tri, res, calls))
        rate, d, g = _actors_throughput(ray, actors, "torus", calls, res)
        actor_rates.append(rate)
        drv.append(d)
        dmn.append(g)
        shard_rates.append(_actors_throughput(ray, actors, "torus", calls, res,
                                              per_task=SHARD_CALLS)[0])
    ratios = [a / b for a, b in zip(actor_rates, loops)]
    shard_ratios = [a / b for a, b in zip(shard_rates, loops)]
    figures = {"scene": "torus 256x256, 4096 triangles, all four outputs",
               "rounds": rounds, "calls_per_worker": calls,
               "best_loops_calls_per_s": max(loops),
               "loops_calls_per_s": statistics.median(loops),
               "actors_calls_per_s": statistics.median(actor_rates),
               # the ratio of the medians: each side's rounds are noisy on shared cores
               "throughput_ratio": statistics.median(actor_rates) / statistics.median(loops),
               "throughput_ratios": ratios,
               "shard_tasks_calls_per_s": statistics.median(shard_rates),
               "shard_throughput_ratio": statistics.median(shard_rates) / statistics.median(loops),
               "shard_throughput_ratios": shard_ratios,
               # best of the rounds on each side: other jobs on shared cores only slow a
               # round down, so the fastest round is the least disturbed one
               "best_throughput_ratio": max(actor_rates) / max(loops),
               "best_shard_throughput_ratio": max(shard_rates) / max(loops),
               "calls_per_shard_task": SHARD_CALLS,
               "head_driver_cpu_ms_per_task": 1e3 * statistics.median(drv),
               "head_daemons_cpu_ms_per_task": 1e3 * statistics.median(dmn),
               "overhead": {}}
    a = actors[0]
    for size in (64, 1024):
        p, t, rr = _full_screen(size) if size == 1024 else (
            load_scene("basic_triangle").pos, load_scene("basic_triangle").tri, (64, 64))
        key = f"{size}"
        ray.get(a.timed_rasterize.remote(key, p, t, rr, OUTPUTS))
        for arrays in (False, True):
            say(f"per-task overhead at {size}x{size}, outputs returned: {arrays}")
            samples = [_overhead(ray, a, key, rr, 30 if size == 1024 else 100, arrays)
                       for _ in range(3)]
            figures["overhead"][f"{size}x{size}" + (" +arrays" if arrays else "")] = {
                k: statistics.median(s[k] for s in samples) for k in samples[0]}
    for actor in actors:
        ray.kill(actor)
    say("shard formats: .npz and Parquet, 64 rasters of 256x256")
    figures["shard_formats"] = shard_formats()
    return figures


def format_figures(f: dict) -> str:
    lines = [f"scene: {f['scene']}",
             f"2 in-process loops: {f['loops_calls_per_s']:.1f} calls/s; 2 actors: "
             f"{f['actors_calls_per_s']:.1f} calls/s; throughput ratio "
             f"{f['throughput_ratio']:.3f} (ratio of the medians; per round: "
             + ", ".join(f"{r:.3f}" for r in f["throughput_ratios"]) + ")",
             f"2 actors, a task per {f['calls_per_shard_task']} calls (as a shard): "
             f"{f['shard_tasks_calls_per_s']:.1f} calls/s; throughput ratio "
             f"{f['shard_throughput_ratio']:.3f} (per round: "
             + ", ".join(f"{r:.3f}" for r in f["shard_throughput_ratios"]) + ")",
             f"best rounds: loops {f['best_loops_calls_per_s']:.1f} calls/s, throughput ratio "
             f"{f['best_throughput_ratio']:.3f} (a task per call), "
             f"{f['best_shard_throughput_ratio']:.3f} (a task per "
             f"{f['calls_per_shard_task']} calls)",
             f"head cost per task: driver {f['head_driver_cpu_ms_per_task']:.3f} ms CPU, "
             f"gcs_server + raylet {f['head_daemons_cpu_ms_per_task']:.3f} ms CPU"]
    for name, o in f["overhead"].items():
        lines.append(f"per-task overhead {name}: {o['overhead_ms']:.3f} ms (round trip "
                     f"{o['round_trip_ms']:.3f} ms, rasterize {o['rasterize_ms']:.3f} ms)")
    s = f["shard_formats"]
    lines.append(f"shard of {s['rasters']} rasters {s['size']}x{s['size']}: .npz write "
                 f"{s['npz_write']:.3f} s, read {s['npz_read']:.3f} s, {s['npz_bytes'] / 1e6:.1f} MB; "
                 f"Parquet write {s['parquet_write']:.3f} s, read {s['parquet_read']:.3f} s, "
                 f"{s['parquet_bytes'] / 1e6:.1f} MB")
    return "\n".join(lines)
