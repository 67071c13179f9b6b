"""A worker process: one GL context, one request at a time (contexts belong to one thread).

The server talks to each worker over a socket pair in :mod:`glraster.service.wire`'s
frames (:func:`worker_main`): a job is a header ``(kind, meta)`` and the raw body bytes; the
answer a header ``(status, content_type, headers)`` and the result bytes. The worker parses
and validates the request itself (so no request data is decoded in the server's event
loop), renders, and encodes the result. A bad request is answered with its 4xx and the
worker goes on; an unexpected exception is answered with 500 and the worker exits
afterwards, so the server replaces it with a fresh context. The worker ignores SIGINT and
SIGTERM: the server stops it with a message after draining, or kills it.
"""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import time
import traceback

from glraster.service.cells import MIN_BYTES, WorkerCells

PROBE = ("probe",)

# A worker keeps the arrays of its last GPU raster and the buffer of its last .npz result
# (each up to this many bytes) and writes the next request of the same resolution, outputs
# and method into them (``rasterize(out=)``): fresh frame-sized arrays cost their page
# faults on every request (1024x1024, 20,000 triangles: 41 ms per call with fresh arrays,
# 25 ms reusing them; docs/service.md).
REUSE_MAX_BYTES = 128 << 20


def _probe(ctx, gr) -> dict:
    """A one-triangle render whose answer is known: the context works."""
    import numpy as np

    pos = np.array([[-1, -1, 0.5, 1], [3, -1, 0.5, 1], [-1, 3, 0.5, 1]], np.float32)
    r = gr.rasterize(pos, np.array([[0, 1, 2]]), (4, 4), ctx=ctx, outputs=("depth", "tri_id"))
    if not (r.mask.all() and (r.tri_id == 0).all() and np.allclose(r.depth, 0.75)):
        raise RuntimeError("the probe render came back wrong: the context does not work")
    return {"probe_ok": True}


def _warm_reference(gr) -> None:
    import numpy as np

    try:
        pos = np.array([[-1, -1, 0.5, 1], [3, -1, 0.5, 2], [-1, 3, 0.5, 1]], np.float32)
        gr.reference.rasterize(pos, np.array([[0, 1, 2]]), (4, 4))
    except Exception:  # noqa: BLE001 - only a warm-up; a real request reports the error
        pass


def _server_timing(timings: dict, encode_started: float) -> str:
    timings["encode"] = time.perf_counter() - encode_started
    return ", ".join(f"{k};dur={v * 1e3:.3f}" for k, v in timings.items())


def _nbytes(raster) -> int:
    return sum(getattr(raster, n).nbytes for n in ("mask", *raster.outputs))


class Handler:
    """Executes jobs on one context. ``handle(kind, meta, body) -> protocol.Result``."""

    def __init__(self, ctx, limits, cells=None):
        import glraster as gr
        from glraster.service import protocol

        self.gr = gr
        self.ctx = ctx
        self.limits = limits
        self.p = protocol
        self.fatal = False   # set after an unexpected exception: exit after answering
        self._frame = None   # (key, Raster): the last GPU raster, reused by the next request
        self._result = None  # uint8 array the .npz results are written into (sent, then reused)
        self.cells = cells   # cells.WorkerCells: shared memory the server may assign a result

    # -- rasterize ----------------------------------------------------------------------
    def rasterize(self, meta: dict, body: bytes):
        p, gr, ctx = self.p, self.gr, self.ctx
        t0 = time.perf_counter()
        req = p.parse_rasterize(meta["content_type"], body, meta.get("query", {}), self.limits,
                                ctx.max_texture_size)
        timings = {"parse": time.perf_counter() - t0}
        gpu = ref = evaluation = None
        try:
            if not req.reference or req.compare:
                t = time.perf_counter()
                key = (req.resolution, req.outputs, req.method)
                single = req.samples == 1
                reuse = self._frame[1] if single and self._frame and self._frame[0] == key \
                    else None
                gpu = gr.rasterize(req.pos, req.tri, req.resolution, ctx=ctx, outputs=req.outputs,
                                   method=req.method, cull_backfaces=req.cull_backfaces,
                                   out=reuse, samples=req.samples,
                                   interpolation=req.interpolation)
                if single and _nbytes(gpu) <= REUSE_MAX_BYTES:
                    self._frame = (key, gpu)
                timings["rasterize"] = time.perf_counter() - t
            if req.reference or req.compare:
                t = time.perf_counter()
                wanted = tuple(dict.fromkeys(req.outputs + ("tri_id",))) if req.compare \
                    else req.outputs
                ref = gr.reference.rasterize(
                    req.pos, req.tri, req.resolution, outputs=wanted, fill_rule="llvmpipe",
                    samples=req.samples, interpolation=req.interpolation,
                    sample_positions=gpu.sample_positions if gpu is not None and req.samples > 1
                    else None)
                timings["reference"] = time.perf_counter() - t
        except ValueError as exc:
            raise p.invalid(exc) from None
        if req.compare:
            from glraster.conformance.check import evaluate
            from glraster.gpu.methods import error_model

            t = time.perf_counter()
            evaluation = p.comparison_dict(evaluate(gpu, ref, ctx, error_model(req.method, ctx)))
            timings["compare"] = time.perf_counter() - t
        raster = ref if req.reference else gpu
        outputs = req.outputs
        source = "reference" if req.reference else "gpu"
        producer = ("glraster.reference.rasterize (float64, fill rule llvmpipe)" if req.reference
                    else f"glraster.rasterize on {ctx.renderer} via {ctx.backend}, {ctx.gl_version}")
        headers = {"x-glraster-source": source}
        if evaluation is not None:
            headers["x-glraster-comparison"] = "pass" if evaluation["ok"] else "fail"
        accept = meta["accept"]
        t = time.perf_counter()
        if accept == "npz":
            extra = {"comparison": evaluation} if evaluation is not None else {}
            if req.samples > 1:
                extra["interpolation"] = req.interpolation
            cell = meta.get("cell") if self.cells is not None else None
            into = self.cells.cell(cell) if cell is not None else self._result
            data, ctype = p.encode_npz(raster, outputs, extra, into), p.NPZ
            if cell is not None and data.obj is into and len(data) >= MIN_BYTES:
                headers["server-timing"] = _server_timing(timings, t)
                return p.Result(200, ctype, b"", headers, cell_bytes=len(data))
            if cell is None and data.obj is not into and len(data) <= REUSE_MAX_BYTES:
                self._result = data.obj        # grown: the next results reuse it
        elif accept == "exr" and req.samples > 1:
            raise p.RequestError(406, "samples", "multisampled results (samples > 1) come as "
                                                 ".npz or JSON, not EXR")
        elif accept == "exr":
            md = {"producer": producer, "source": source, "method": req.method}
            if evaluation is not None:
                md["comparison"] = "pass" if evaluation["ok"] else "fail"
            data, ctype = p.encode_exr(raster, outputs, req.crop, md), p.EXR
        else:
            doc = {
                "resolution": list(req.resolution), "vertices": int(len(req.pos)),
                "triangles": int(len(req.tri)), "outputs": list(outputs),
                "method": req.method, "source": source, **p.raster_stats(raster),
                "samples": req.samples, "interpolation": req.interpolation,
                "sample_positions": raster.sample_positions.tolist(),
                "info": p._jsonable(gpu.info) if gpu is not None else {},
                "backend": ctx.backend, "renderer": ctx.renderer, "gl_version": ctx.gl_version,
                "timings": timings,
            }
            if evaluation is not None:
                doc["comparison"] = evaluation
            data, ctype = json.dumps(doc).encode(), p.JSON
        headers["server-timing"] = _server_timing(timings, t)
        return p.Result(200, ctype, data, headers)

    # -- check --------------------------------------------------------------------------
    def check(self, meta: dict, body: bytes):
        p, ctx = self.p, self.ctx
        from glraster.conformance import check, junit
        from glraster.conformance.scenes import list_scenes

        req = p.parse_check(body, list_scenes(), self.limits)
        names = req.scenes
        mutant_scenes = None
        if req.shard is not None:
            i, n = req.shard
            names = check.shard_scenes(names, i, n)
            if req.mutants:
                if i == 1:
                    mutant_scenes = list_scenes()
                else:
                    req.mutants = None
        if req.mutants:
            from glraster.conformance import mutants

            try:
                mutants.select(req.mutants)
            except ValueError as exc:
                raise p.RequestError(422, "mutants", str(exc)[:300]) from None
        kwargs = {"mutant_scenes": mutant_scenes} if mutant_scenes is not None else {}
        result = check.run(ctx, names, method=req.method, check_golden=req.golden,
                           mutants=bool(req.mutants), mutant_pattern=req.mutants, **kwargs)
        if req.shard is not None:
            result.shard = req.shard
        ctx.release_targets()   # the catalog's 4096x4096 scene leaves big targets behind
        xml = junit.to_string(result)
        if meta["accept"] == "junit":
            return p.Result(200, p.JUNIT, xml.encode(),
                            {"x-glraster-check": "pass" if result.ok else "fail"})
        doc = check.to_dict(result)
        doc["junit"] = xml
        return p.Result(200, p.JSON, json.dumps(p._jsonable(doc)).encode(),
                        {"x-glraster-check": "pass" if result.ok else "fail"})

    def handle(self, kind: str, meta: dict, body: bytes):
        p = self.p
        if time.monotonic() > meta.get("expires", math.inf):
            # it waited behind another job here until its deadline (pool.PIPELINE)
            return p.Result(504, p.JSON, p.error_json(
                504, "deadline", "the request's deadline passed before a worker could start it"))
        try:
            if kind == "rasterize":
                return self.rasterize(meta, body)
            if kind == "check":
                return self.check(meta, body)
            if kind == "probe":
                _probe(self.ctx, self.gr)
                return p.Result(200, p.JSON, b'{"ok": true}')
            return p.Result(400, p.JSON, p.error_json(400, "kind", f"unknown job {kind!r}"))
        except p.RequestError as exc:
            return p.Result(exc.status, p.JSON, json.dumps(exc.body()).encode(), exc.headers)
        except MemoryError:
            self.fatal = True
            return p.Result(507, p.JSON, p.error_json(
                507, "resolution", "the request needs more memory than this worker has"))
        except Exception as exc:  # a bug or a broken context: answer, then be replaced
            self.fatal = True
            traceback.print_exc(file=sys.stderr)
            return p.Result(500, p.JSON, p.error_json(
                500, "server", f"internal error ({type(exc).__name__}: {exc})"[:500]))


def worker_main(sock, backend, limits, shared_cells=None) -> None:
    """Entry point of a worker process (multiprocessing, spawn start method); ``sock`` is
    its end of the socket pair, ``shared_cells`` the server's result cells
    (:class:`glraster.service.cells.SharedFile`) or None."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    from glraster.service import wire

    try:
        import glraster as gr

        ctx = gr.Context(backend=backend)
        _probe(ctx, gr)
        wire.send(sock, ("ready", {
            "pid": os.getpid(), "backend": ctx.backend, "renderer": ctx.renderer,
            "gl_version": ctx.gl_version, "vendor": ctx.vendor,
            "max_texture_size": ctx.max_texture_size, "subpixel_bits": ctx.subpixel_bits,
            "fill_rule_modeled": ctx.is_llvmpipe, "sample_counts": list(ctx.sample_counts),
            "glraster": gr.__version__,
        }))
    except BaseException as exc:  # noqa: BLE001 - reported to the server, which retries
        try:
            wire.send(sock, ("failed", f"{type(exc).__name__}: {exc}"))
        except OSError:
            pass
        return
    handler = Handler(ctx, limits, WorkerCells(shared_cells) if shared_cells else None)
    # Load the reference's compiled kernels (numba's cache) while the first requests come:
    # otherwise the first request with reference or compare pays ~1 s for it.
    import threading

    threading.Thread(target=_warm_reference, args=(gr,), daemon=True).start()
    receiver = wire.Receiver(sock)
    try:
        # The context stays current on this thread, its only one: glraster's calls then
        # skip making it current and restoring the previous one (~0.1 ms per request).
        with ctx:
            while True:
                try:
                    header, body = receiver.recv()
                except (EOFError, OSError):
                    break   # the server is gone
                if header[0] == "stop":
                    break
                kind, meta = header
                result = handler.handle(kind, meta, body)
                wire.send(sock, (result.status, result.content_type, result.headers,
                                 result.cell_bytes), result.body)
                if handler.fatal:
                    break
    except (BrokenPipeError, EOFError, OSError):
        pass
    finally:
        try:
            ctx.release()
        except Exception:  # noqa: BLE001 - exiting anyway
            pass
