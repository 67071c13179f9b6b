"""The GL worker: one Ray actor per OpenGL context, on one driver.

A :class:`GLWorker` owns the only GL context of its worker process (a context is never
shared by tasks of different processes), made with the node's backend and the driver its
``runtime_env`` selects (:func:`glraster.cluster.runtime.driver_env`). A context that does
not come up does not kill the actor: :meth:`GLWorker.describe` reports it with the node's
name, so the fleet goes on without that node.

Ray restarts a worker process that dies (``max_restarts``, :data:`MAX_RESTARTS`) and retries
the calls it held (``max_task_retries``, :data:`MAX_TASK_RETRIES`); a call that kills its
worker every time fails after ``1 + MAX_TASK_RETRIES`` attempts and is reported as an error.
"""

from __future__ import annotations

import os
import socket
import tempfile

from glraster.cluster.runtime import driver_env, driver_name

# A worker process that dies is started again, always: a node loses no capacity to a crash.
MAX_RESTARTS = -1
# A call whose worker died is retried this many times, then fails (a scene that crashes its
# worker every time is an error after 3 attempts, not a loop).
MAX_TASK_RETRIES = 2


class GLWorker:
    """One GL context on ``driver`` (None: the node's own, whichever it is); the remote
    methods of the fleet's tasks."""

    def __init__(self, driver: str | None, backend: str | None = None):
        self.driver = driver
        self.node = socket.gethostname()
        self.pid = os.getpid()
        self.ctx = None
        self.error = ""
        try:
            from glraster.gpu.context import Context

            self.ctx = Context(backend=backend)
            found = driver_name(self.ctx.renderer, self.ctx.vendor)
            if driver is None:
                self.driver = found
            elif found != driver:
                self.error = f"asked for driver {driver}, GL came up as {self.ctx.renderer!r}"
        except Exception as exc:  # a node whose GL does not come up is reported, not fatal
            self.error = f"{type(exc).__name__}: {exc}"

    def describe(self) -> dict:
        """``{"driver", "node", "pid", "ok", "error", "backend", "renderer", "gl_version"}``."""
        ctx = self.ctx
        return {"driver": self.driver, "node": self.node, "pid": self.pid,
                "ok": not self.error, "error": self.error,
                "backend": ctx.backend if ctx else None, "renderer": ctx.renderer if ctx else None,
                "gl_version": ctx.gl_version if ctx else None}

    def _context(self):
        if self.error:
            raise RuntimeError(f"GL is not up on {self.node}: {self.error}")
        return self.ctx

    # -- conformance ---------------------------------------------------------------------

    def setup(self, probes: bool = True):
        """The driver's rules and probes (:func:`glraster.conformance.check.setup_driver`)."""
        from glraster.conformance.check import setup_driver

        return setup_driver(self._context(), probes=probes)

    def check_scene(self, name: str, method: str, setup, golden_dir=None,
                    check_golden: bool = True, images: bool = False):
        """One catalog scene checked with ``method`` and the driver's ``setup``, exactly as
        :func:`glraster.conformance.check.run` checks it. Returns ``(SceneResult, images)``:
        images = ``(info, {file name: PNG bytes})`` of the HTML report when ``images``, else
        None (the report's folder is on the head, not here). The report's per-pixel maps
        are dropped: what travels is the figures (a few KB a scene), not (H, W) arrays."""
        from glraster.conformance.check import run_scene
        from glraster.conformance.scenes import load_scene

        ctx = self._context()
        scene = load_scene(name)
        res, art = run_scene(scene, ctx, method=method, golden_dir=golden_dir,
                             check_golden=check_golden, keep=images, fill_rule=setup.rule,
                             clip_defect=setup.clip_defect,
                             sample_persp_defect=setup.sample_persp_defect)
        pictures = None
        if images and art is not None:
            from glraster.conformance.html_report import HtmlReport

            with tempfile.TemporaryDirectory(prefix="glraster-images-") as tmp, \
                    HtmlReport(tmp) as report:
                report.add_scene(res, art)
                info = report.images[res.name]
                pictures = (info, {f: (report.img / f).read_bytes()
                                   for f in info["files"].values()})
        if res.report is not None:  # the per-pixel maps stay here (images carry them)
            res.report.maps = None
        return res, pictures

    # -- datasets ------------------------------------------------------------------------

    def rasterize(self, pos, tri, resolution, outputs, method="hw"):
        """:func:`glraster.rasterize` on this worker's context; returns the Raster."""
        from glraster.gpu.rasterize import rasterize

        return rasterize(pos, tri, resolution, ctx=self._context(), outputs=outputs,
                         method=method)

    def timed_rasterize(self, key, pos, tri, resolution, outputs, arrays=False, repeat=1):
        """:meth:`rasterize` ``repeat`` times, for the benchmark: the scene ``key`` is kept
        after its first call (``pos``/``tri`` None then), so a call is the draw alone.
        Returns (seconds inside, the last call's output arrays when ``arrays`` else None)."""
        import time

        cache = self.__dict__.setdefault("_bench_scenes", {})
        if pos is not None:
            cache[key] = (pos, tri)
        pos, tri = cache[key]
        t = time.perf_counter()
        for _ in range(repeat):
            r = self.rasterize(pos, tri, resolution, outputs)
        seconds = time.perf_counter() - t
        return seconds, ({n: getattr(r, n) for n in outputs} if arrays else None)


def remote_worker(ray, driver: str | None, *, backend=None, node_id=None, gpus: float = 0,
                  num_cpus: float = 1):
    """A :class:`GLWorker` actor for ``driver``: ``num_cpus`` CPUs, one unit of ``driver:<name>`` (and
    ``gpus`` GPUs), its environment from :func:`driver_env`, on node ``node_id`` when given
    (hard affinity: the fleet asks each node for its own driver)."""
    from glraster.cluster.runtime import RESOURCE_PREFIX

    options = {"num_cpus": num_cpus, "max_restarts": MAX_RESTARTS,
               "max_task_retries": MAX_TASK_RETRIES}
    if driver is not None:  # None: any node, its own GL
        options["resources"] = {RESOURCE_PREFIX + driver: 1}
        options["runtime_env"] = {"env_vars": driver_env(driver)}
    if gpus:
        options["num_gpus"] = gpus
    if node_id is not None:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        options["scheduling_strategy"] = NodeAffinitySchedulingStrategy(node_id, soft=False)
    return ray.remote(GLWorker).options(**options).remote(driver, backend)
