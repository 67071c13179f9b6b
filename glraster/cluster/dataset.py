"""``glraster batch``: a dataset rendered with Ray Data into .npz shards and a manifest.

The pipeline (:func:`render_dataset`):

- the head lists the items (:mod:`glraster.cluster.inputs`), cuts them into shards
  (:func:`glraster.cluster.shards.plan`) and keeps those whose file is missing or holds other
  items (a rerun renders nothing else);
- ``ray.data.from_items`` (one row per shard: its index and item list, a few hundred bytes)
  feeds ``map_batches`` with :class:`ShardRenderer`, a fixed pool of actors, each holding one
  GL context. A worker renders its shard's items one after the other and writes the shard
  file itself (atomically) where ``out_dir`` is (a folder every node sees), returning only
  the shard's manifest lines, so no raster crosses the object store;
- Ray Data's streaming executor gives bounded memory and backpressure: one shard in flight
  per actor (``max_tasks_in_flight_per_actor=1``), outputs consumed as they come
  (``iter_rows``), a small object store. A worker holds one shard's arrays at a time
  (``shard_size`` x the bytes of one scene's outputs);
- faults: a worker process that dies is restarted (``max_restarts=-1``) and its shard
  retried (``max_task_retries``, :data:`SHARD_RETRIES`); the shard's crash ledger
  (:class:`glraster.cluster.shards.CrashLedger`) turns an item that crashed its worker twice
  into an error line; a shard whose retries all die is reported (its items as errors, no
  file) and the run goes on (``DataContext.max_errored_blocks = -1``);
- at the end the manifest is rebuilt from all shard files: each item exactly once.
"""

from __future__ import annotations

import json
import os
import socket
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from glraster.cluster import inputs as _inputs
from glraster.cluster import runtime
from glraster.cluster import shards as _shards
from glraster.errors import ArgumentError

# Retries of a shard whose worker died: a scene that crashes every time needs two deaths
# to be recognised (the first attempt does not record items), and one to spare.
SHARD_RETRIES = 3
DEFAULT_SHARD_SIZE = 64


def render_scene(ctx, scene, outputs, method="hw") -> dict:
    """``{output: array}`` of :func:`glraster.rasterize` of ``scene`` on ``ctx`` (``outputs``
    None: the scene's) at the scene's samples and interpolation, as ``glraster render``
    renders it; a multisampled scene adds its per-sample ``mask`` (H, W, S) and
    ``sample_positions`` (S, 2)."""
    from glraster.gpu.rasterize import rasterize

    outputs = tuple(outputs) if outputs else scene.outputs
    raster = rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=outputs,
                       method=method, samples=scene.samples, interpolation=scene.interpolation)
    arrays = {name: getattr(raster, name) for name in outputs}
    if scene.samples > 1:    # which samples a value belongs to, and where they lie
        arrays.update(mask=raster.mask, sample_positions=raster.sample_positions)
    return arrays


class ShardRenderer:
    """The Ray Data map worker: one GL context, a shard per call (a batch of one row:
    ``shard`` index, ``items`` JSON list)."""

    def __init__(self, out_dir, outputs=None, method="hw", backend=None, render=None):
        from glraster.gpu.context import Context

        self.out_dir = Path(out_dir)
        self.outputs, self.method = outputs, method
        self.render = render or render_scene
        self.node = socket.gethostname()
        try:
            self.ctx = Context(backend=backend)
        except Exception as exc:
            raise RuntimeError(f"GL did not come up on node {self.node}: "
                               f"{type(exc).__name__}: {exc}") from None

    def __call__(self, batch):
        rows = {"shard": [], "lines": [], "rendered": [], "pid": [], "node": [], "seconds": [],
                "write_error": []}
        for index, items in zip(batch["shard"], batch["items"]):
            t = time.perf_counter()
            shard = _shards.Shard(int(index), tuple(json.loads(str(items))))
            lines, rendered, write_error = [], 0, ""
            try:
                lines, rendered = self._render(shard)
            except OSError as exc:   # OUT takes no shard (a full disk): the head stops the run
                write_error = json.dumps([exc.errno, exc.strerror or str(exc), exc.filename])
            for key, value in (("shard", shard.index), ("lines", json.dumps(lines)),
                               ("rendered", rendered), ("pid", os.getpid()),
                               ("node", self.node), ("seconds", time.perf_counter() - t),
                               ("write_error", write_error)):
                rows[key].append(value)
        return rows

    def _render(self, shard):
        """Render and write ``shard``: (its manifest lines, scenes rendered). An OSError
        when its file or its crash ledger cannot be written."""
        ledger = _shards.CrashLedger(self.out_dir, shard)
        results, rendered = [], 0
        for k, item in enumerate(shard.items):
            crashes = ledger.crashes(k)
            if crashes >= _shards.CRASHES_BEFORE_ERROR:
                results.append(f"crashed its worker {crashes} times; not rendered again")
                continue
            ledger.starting(k)
            try:
                scene = _inputs.load_item(item)
                results.append(self.render(self.ctx, scene, self.outputs, self.method))
                rendered += 1
            except Exception as exc:  # a bad scene is an error line, not a lost shard
                results.append(f"{type(exc).__name__}: {exc}")
        lines = _shards.write_shard(self.out_dir, shard, results)
        ledger.done()
        return lines, rendered


@dataclass
class BatchSummary:
    """What a run did. ``skipped``: shards already finished before it; ``lost``: shards
    whose every retry died (their items are error lines); ``errors``: manifest lines with
    an error; ``manifest``: its path."""

    items: int = 0
    shards: int = 0
    rendered_shards: int = 0
    rendered_items: int = 0
    skipped: int = 0
    lost: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    seconds: float = 0.0
    workers: int = 0
    manifest: str = ""
    pids: list = field(default_factory=list)  # worker processes that wrote shards

    @property
    def ok(self) -> bool:
        return not self.errors and not self.lost

    def text(self) -> str:
        rate = self.rendered_items / self.seconds if self.seconds else 0.0
        lines = [f"{self.items} scenes in {self.shards} shards: {self.rendered_shards} shards "
                 f"({self.rendered_items} scenes) rendered, {self.skipped} already done; "
                 f"{len(self.errors)} errors, {len(self.lost)} shards lost; "
                 f"{self.workers} workers, {self.seconds:.1f} s ({rate:.1f} scenes/s)",
                 f"manifest: {self.manifest}"]
        lines += [f"  error: {e['scene']}: {e['error']}" for e in self.errors[:20]]
        if len(self.errors) > 20:
            lines.append(f"  ... {len(self.errors) - 20} more (see the manifest)")
        return "\n".join(lines)


def render_dataset(source, out_dir, *, address=None, driver=None, shard_size=DEFAULT_SHARD_SIZE,
                   outputs=None, method="hw", workers=None, backend=None, render=None,
                   progress=None) -> BatchSummary:
    """Render every item of ``source`` into ``out_dir`` (shards and ``manifest.jsonl``).

    source  : a folder of scene files, a .txt list, a list of paths, or a views file
              (:mod:`glraster.cluster.inputs`)
    address : Ray address (None: ``RAY_ADDRESS``, else a local cluster)
    driver  : place the workers on nodes advertising ``driver:<name>`` and select it with
              its environment; None: every node's default GL, no driver resource
    outputs : subset of persp, screen, depth, tri_id (None: each scene's own outputs)
    workers : actors (default: the CPUs of the nodes that can take them)
    render  : ``render(ctx, scene, outputs, method) -> {output: array}`` run on the workers
              (default :func:`render_scene`)
    progress(done_items, total_items, label): after each finished shard.

    A shard that ``out_dir`` cannot take (a full disk) stops the run with that OSError
    (naming the file); the shards written stay, and a rerun resumes after them.
    """
    t0 = time.perf_counter()
    if outputs is not None:
        from glraster import validate

        outputs = validate.outputs(outputs)
    if driver is not None:
        driver = runtime.check_driver_names([driver])[0]
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ArgumentError("workers", f"workers must be a positive integer, got {workers!r}")
    items = _inputs.list_items(source)
    plan = _shards.plan(items, shard_size)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = BatchSummary(items=len(items), shards=len(plan))
    lines_of = {s.index: _shards.finished(out_dir, s) for s in plan}
    todo = [s for s in plan if lines_of[s.index] is None]
    summary.skipped = len(plan) - len(todo)
    done_items = sum(len(s.items) for s in plan if lines_of[s.index] is not None)
    if progress:
        progress(done_items, len(items), f"{summary.skipped} shards already done")
    sizes = {s.index: len(s.items) for s in plan}
    if todo:
        ray = runtime.connect(address, [driver] if driver else [])
        summary.workers = workers or _worker_count(ray, driver)
        rows = iter(_pipeline(ray, todo, out_dir, driver, outputs, method, backend, render,
                              summary.workers).iter_rows())
        for row in rows:
            if row["write_error"]:  # every later shard would fail alike: stop; a rerun resumes
                rows.close()        # (the pipeline and its workers stop)
                _remove_temporaries(out_dir)
                raise OSError(*json.loads(str(row["write_error"])))
            index = int(row["shard"])
            lines_of[index] = str(row["lines"])  # JSON text: ~200 bytes a scene on the head
            summary.rendered_shards += 1
            summary.rendered_items += int(row["rendered"])
            if int(row["pid"]) not in summary.pids:
                summary.pids.append(int(row["pid"]))
            done_items += sizes[index]
            if progress:
                progress(done_items, len(items), f"shard {index} on {row['node']}")
    _remove_temporaries(out_dir)

    def manifest():
        for s in plan:
            lines = lines_of[s.index]
            if isinstance(lines, str):
                lines = json.loads(lines)
            if lines is None:  # every retry died, or the pipeline dropped it
                lines = _shards.finished(out_dir, s)  # written, but its answer was lost
            if lines is None:
                summary.lost.append(s.index)
                why = f"shard {s.index} lost: its worker died {1 + SHARD_RETRIES} times"
                lines = [{"scene": item, "shard": None, "keys": {}, "error": why}
                         for item in s.items]
            summary.errors += [ln for ln in lines if "error" in ln]
            yield from lines

    summary.manifest = str(_shards.write_manifest(out_dir, manifest()))
    summary.seconds = time.perf_counter() - t0
    return summary


def _remove_temporaries(out_dir: Path) -> None:
    """A worker killed while writing leaves its temporary file (its retry wrote the shard):
    with every worker done, remove them, so that OUT holds whole files only."""
    for tmp in out_dir.glob(".shard-*.npz.*"):
        tmp.unlink(missing_ok=True)


def _worker_count(ray, driver) -> int:
    """The CPUs of the nodes that can take a worker (those advertising ``driver``)."""
    if driver is None:
        return max(1, int(ray.cluster_resources().get("CPU", 1)))
    nodes = runtime.driver_nodes(ray).get(driver)
    if not nodes:
        raise ArgumentError(
            "driver", f"driver: no node of the cluster advertises driver:{driver} "
                      f"(advertised: {', '.join(sorted(runtime.driver_nodes(ray))) or 'none'})")
    return max(1, sum(min(n["cpus"], n["slots"]) for n in nodes))


def _pipeline(ray, todo, out_dir, driver, outputs, method, backend, render, workers):
    """The Ray Data dataset of the shards ``todo``: rows {shard, lines, rendered, pid, node,
    seconds}, streamed."""
    import logging

    import ray.data

    logging.getLogger("ray.data").setLevel(logging.WARNING)  # the head prints its own lines
    context = ray.data.DataContext.get_current()
    context.max_errored_blocks = -1          # a lost shard is reported; the others go on
    context.enable_progress_bars = False     # the head prints its own, per shard
    rows = [{"shard": s.index, "items": json.dumps(list(s.items))} for s in todo]
    ds = ray.data.from_items(rows, override_num_blocks=len(rows))
    named = {"runtime_env": {"env_vars": runtime.driver_env(driver) if driver else {}}}
    if driver:
        named["resources"] = {runtime.RESOURCE_PREFIX + driver: 1}
        if driver not in runtime.SIMULATED_DRIVERS and ray.cluster_resources().get("GPU"):
            named["num_gpus"] = 1  # a GPU's driver: one GPU per worker
    with warnings.catch_warnings():
        # Ray Data names no parameter for the retries; they go as plain remote arguments.
        warnings.filterwarnings("ignore", message=".*ray_remote_args.*is deprecated")
        return ds.map_batches(
            ShardRenderer, batch_size=1, num_cpus=1,
            compute=ray.data.ActorPoolStrategy(size=min(workers, len(todo)),
                                               max_tasks_in_flight_per_actor=1),
            fn_constructor_kwargs={"out_dir": str(out_dir.resolve()), "outputs": outputs,
                                   "method": method, "backend": backend, "render": render},
            max_restarts=-1, max_task_retries=SHARD_RETRIES, **named)
