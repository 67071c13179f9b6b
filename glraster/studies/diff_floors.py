"""A floor for each differentiable op, and where the time of each fit's iteration goes.

    glraster study diff-floors                      # both parts, default sizes
    glraster study diff-floors --part ops --op-size 64 256
    glraster study diff-floors --part fits --fits cube4 cube16 pose256 texture

**Floors.** An op's floor is its GL work alone: the same shaders, programs, buffers,
dispatch sizes, draws and readbacks as a real call, replayed bare by
:mod:`glraster.gpu.gl_trace` (recorded from a real core call right before the replay,
inputs already uploaded, no Python wrapper, no validation, no allocation, ending with
glFinish). The op table times, in the same process and interleaved rounds, the op through
``glraster.torch`` (forward: the call; backward: ``torch.autograd.grad``), through its
``glraster.diff.ops`` core (``Op.core(float32).forward/backward`` on checked inputs) and
its floor, and gives each as a ratio to the floor. Scene: the 16 x 16 grid of quads of
the ``torch-overhead`` study (512 triangles) at N x N; interpolate with
``diff_attrs="all"``; texture linear-mipmap-linear with uv_da on a 256² RGB texture (the
forward floor includes the mip pyramid build, the backward floor the pyramid's
backward); antialias with a prebuilt topology hash. Every float input wants its gradient.

**Fits.** One iteration of each fit as its ``fit_*`` loop runs it (forward, loss,
backward, Adam step and schedule): the cube at 4x4 and 16x16 (4 views; as ``fit_cube``,
the context held current and the targets of 32 iterations rendered in one no-grad call
of each op, each iteration charged 1/32 of that call's time and floors: "target OP.ROLE"),
the pose fit at 256² (8 restarts) and the texture fit (128², 4 views,
linear-mipmap-linear, 256² texture). Per fit:

- the iteration's median (``--iterations`` per round, ``--rounds`` interleaved rounds);
- per op call: calls per iteration, the core's time (inclusive) and its floor: the
  median over one replay of the round's recorded iteration after every timed iteration
  (so floors and iterations are sampled alternately, in the same time window, as many
  of each: on a shared machine a floor measured apart from the iterations drifted from
  15 to 22 ms between runs of the texture fit);
- per phase, exclusive time in iterations run under :func:`phase_clock` (interleaved
  with the plain ones; "clocked ms" is their median, the timers' own cost included):
  python (the torch bridge's and the GPU cores' host code, NumPy included), validation
  (the ops' ``check``), context (making the GL context current and restoring the
  caller's), upload (buffer and texture writes), dispatch (compute runs, draws, clears,
  bindings, barriers), readback (buffer and framebuffer reads: on llvmpipe a read waits
  for the work before it, so much of the GL time shows here) and torch (everything
  else: torch, autograd, the optimizer and the fit's own code);
- the largest host-code functions under cProfile (``--profile-iterations``), as hints;
- the ratio iteration / (sum of its op calls' floors + the optimizer step): the median of
  the ratios of each timed iteration to the floor sample right after it (a load that
  slows both cancels), its goal "at most 1.5".

The environment-map fit (``envmap``) is ``fit envmap``'s defaults: 2 views at 256².

Timings on a shared machine are noisy: read medians and ratios.
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import json
import pstats
import statistics
import time
from contextlib import ExitStack, contextmanager

import numpy as np

from glraster.io.destinations import OutputFile

CORE_MODULES = ("rasterize", "interpolate", "texture", "antialias")
FITS = ("cube4", "cube16", "pose256", "texture", "envmap")
PHASES = ("python", "validation", "context", "upload", "dispatch", "readback", "torch")


# --------------------------------------------------------------------------- core hooks


@contextmanager
def core_hooks(on_call):
    """Route every GPU core call through ``on_call(name, function, args, kwargs)`` while
    active: ``name`` is "OP.forward" / "OP.backward"; the texture core's mip pyramid
    passes, which run inside its forward and backward, are "/mip build" and
    "/mip backward" (the leading "/": nested in the call that runs them)."""
    import importlib

    patched = []

    def wrap(module, attribute, name_of):
        original = getattr(module, attribute)

        @functools.wraps(original)
        def hooked(*args, **kwargs):
            return on_call(name_of(kwargs), original, args, kwargs)

        setattr(module, attribute, hooked)
        patched.append((module, attribute, original))

    try:
        for op in CORE_MODULES:
            module = importlib.import_module(f"glraster.diff.{op}")
            for role in ("forward", "backward"):
                wrap(module, role, lambda kw, n=f"{op}.{role}": n)
        texture = importlib.import_module("glraster.diff.texture")
        wrap(texture, "_pyramid_passes", lambda kw: "/mip backward"
             if kw.get("backward") else "/mip build")
        yield
    finally:
        for module, attribute, original in reversed(patched):
            setattr(module, attribute, original)


@contextmanager
def recording():
    """A :class:`glraster.gpu.gl_trace.Recorder` whose segments are the core calls."""
    from glraster.gpu.gl_trace import Recorder

    recorder = Recorder()

    def on_call(name, function, args, kwargs):
        if name.startswith("/"):
            name = recorder.current + name
        with recorder.segment(name):
            return function(*args, **kwargs)

    with recorder, core_hooks(on_call):
        yield recorder


@contextmanager
def core_timer(totals: dict):
    """Add each core call's inclusive seconds to ``totals[name]`` (nested mip passes
    are inside their op's time, not added)."""
    depth = [0]

    def on_call(name, function, args, kwargs):
        depth[0] += 1
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                totals[name] = totals.get(name, 0.0) + time.perf_counter() - start

    with core_hooks(on_call):
        yield


def floors_of(trace, ctx, repeats: int = 3) -> dict[str, float]:
    """Segment name -> floor seconds (median of ``repeats`` replays of the whole trace)."""
    runs = [trace.replay(ctx) for _ in range(repeats)]
    return {name: statistics.median(r[name] for r in runs) for name in runs[0]}


def op_floor(floors: dict, op_role: str) -> float:
    """The floor of "OP.ROLE" with its nested segments ("OP.ROLE/mip build")."""
    return sum(s for name, s in floors.items()
               if name == op_role or name.startswith(op_role + "/"))


# --------------------------------------------------------------------------- op cells


def _op_cases(size: int, glctx, texture_size: int = 256):
    """op -> (torch forward, torch backward, core forward, core backward)."""
    import torch

    import glraster.torch as dr
    from glraster.diff import ops
    from glraster.studies.torch_overhead import _scene

    ctx = glctx.context
    rng = np.random.default_rng(0)
    pos, tri, uv_attr = _scene()
    res = (size, size)
    tri_t = torch.from_numpy(tri)
    with torch.no_grad():
        rast, rast_db = dr.rasterize(glctx, torch.from_numpy(pos), tri_t, res)
        uv, uv_da = dr.interpolate(torch.from_numpy(uv_attr), rast, tri_t, rast_db=rast_db,
                                   diff_attrs="all", glctx=glctx)
    like = lambda shape: rng.uniform(0.5, 1.0, shape).astype(np.float32)  # noqa: E731
    image = lambda c: like(rast.shape[:3] + (c,))  # noqa: E731
    attr = rng.uniform(0, 1, (len(pos), 3)).astype(np.float32)
    tex = rng.uniform(0, 1, (1, texture_size, texture_size, 3)).astype(np.float32)
    th = dr.antialias_construct_topology_hash(tri_t)
    mip = "linear-mipmap-linear"
    specs = {
        "rasterize": (ops.RASTERIZE, [pos], dict(tri=tri, resolution=res),
                      [image(4), image(4)],
                      lambda t: dr.rasterize(glctx, t[0], tri_t, res)),
        "interpolate": (ops.INTERPOLATE, [attr, rast.numpy(), rast_db.numpy()],
                        dict(tri=tri, diff_attrs=(0, 1, 2)), [image(3), image(6)],
                        lambda t: dr.interpolate(t[0], t[1], tri_t, rast_db=t[2],
                                                 diff_attrs="all", glctx=glctx)),
        "texture": (ops.TEXTURE, [tex, uv.numpy(), uv_da.numpy()], dict(filter_mode=mip),
                    [image(3)],
                    lambda t: (dr.texture(t[0], t[1], t[2], filter_mode=mip, glctx=glctx),)),
        "antialias": (ops.ANTIALIAS, [image(3), rast.numpy(), pos],
                      dict(tri=tri, topology_hash=th), [image(3)],
                      lambda t: (dr.antialias(t[0], t[1].detach(), t[2], tri_t, th,
                                              glctx=glctx),)),
    }
    cases = {}
    for name, (op, inputs, params, grads, call) in specs.items():
        leaves = [torch.tensor(a, requires_grad=True) for a in inputs]
        grads_t = [torch.from_numpy(g) for g in grads]
        arrays, checked = op.check(*inputs, **params, ctx=ctx)
        core = op.core(np.float32)
        state = {}

        def torch_forward(call=call, leaves=leaves, state=state):
            state["outs"] = call(leaves)

        def torch_backward(leaves=leaves, grads_t=grads_t, state=state):
            outs = state.pop("outs")
            torch.autograd.grad([o for o, g in zip(outs, grads_t) if g.numel()], leaves,
                                [g for g in grads_t if g.numel()], allow_unused=True)

        def core_forward(core=core, arrays=arrays, checked=checked, state=state):
            state["saved"] = core.forward(*arrays, **checked)[1]

        def core_backward(core=core, grads=grads, state=state):
            core.backward(state.pop("saved"), *grads)

        cases[name] = (torch_forward, torch_backward, core_forward, core_backward)
    return cases


def measure_ops(glctx, sizes, rounds: int, calls: int) -> dict:
    """{size: {op: {"torch"|"core"|"floor": [fwd s, bwd s]}}}, medians over rounds x
    calls, the three paths interleaved call by call."""
    result = {}
    ctx = glctx.context
    for size in sizes:
        cases = _op_cases(size, glctx)
        samples = {op: {k: ([], []) for k in ("torch", "core", "floor")} for op in cases}
        for _ in range(rounds):
            for op, (t_fwd, t_bwd, c_fwd, c_bwd) in cases.items():
                t_fwd(), t_bwd()                       # warm: programs, buffers sized
                with recording() as rec:
                    c_fwd(), c_bwd()
                for _ in range(calls):
                    for path, fwd, bwd in (("torch", t_fwd, t_bwd), ("core", c_fwd, c_bwd)):
                        start = time.perf_counter()
                        fwd()
                        mid = time.perf_counter()
                        bwd()
                        end = time.perf_counter()
                        samples[op][path][0].append(mid - start)
                        samples[op][path][1].append(end - mid)
                    floors = rec.trace.replay(ctx)
                    samples[op]["floor"][0].append(op_floor(floors, f"{op}.forward"))
                    samples[op]["floor"][1].append(op_floor(floors, f"{op}.backward"))
        result[size] = {op: {path: [statistics.median(s) for s in pair]
                             for path, pair in paths.items()}
                        for op, paths in samples.items()}
    return result


def _ratio(time_s: float, floor_s: float) -> str:
    return f"{time_s / floor_s:.1f}x" if floor_s > 0 else "-"


def ops_table(result: dict) -> str:
    lines = ["| N | op | floor fwd / bwd ms | core fwd / bwd (x floor) | "
             "torch fwd / bwd (x floor) |", "|---|---|---|---|---|"]
    for size, ops in result.items():
        for op, paths in ops.items():
            f = paths["floor"]
            cells = [f"{1e3 * f[0]:.3f} / {1e3 * f[1]:.3f}"]
            for path in ("core", "torch"):
                p = paths[path]
                cells.append(f"{1e3 * p[0]:.3f} / {1e3 * p[1]:.3f} "
                             f"({_ratio(p[0], f[0])} / {_ratio(p[1], f[1])})")
            lines.append(f"| {size} | {op} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- fits


def _adam(params, lr):
    import torch

    opt = torch.optim.Adam(params, lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(opt, lambda it: 1.0)
    return opt, schedule


def _descend(loss, opt, schedule, project=None) -> float:
    """The fits' :func:`descend` with the step timed: seconds of step + schedule +
    project."""
    import torch

    opt.zero_grad(set_to_none=True)
    loss.backward()
    start = time.perf_counter()
    opt.step()
    schedule.step()
    if project is not None:
        with torch.no_grad():
            project()
    return time.perf_counter() - start


def _cube(glctx, resolution: int, views: int = 4):
    """The cube fit's iteration as :func:`glraster.torch.fitting.cube.fit_cube` runs it:
    the OpenGL context held current, the target images taken from a batch of
    :data:`~glraster.torch.fitting.cube.TARGET_BATCH` iterations' rendered in one no-grad
    call of each op by the fit's own ``_targets``. That batch call is the iteration's
    ``batched`` = (render the next batch, its iteration count): :func:`measure_fits`
    times it apart and charges each iteration its share (time and floors / count)."""
    import torch

    from glraster.fitting.scenes import DISTANCE, FOVY, cube
    from glraster.torch.fitting.common import (quaternion_matrices, random_quaternions,
                                               view_matrices)
    from glraster.torch.fitting.cube import TARGET_BATCH, _targets, render_cube
    from glraster.torch.fitting.render import topology_hash

    vertices, triangles, colors = cube()
    tri = torch.tensor(triangles, dtype=torch.int32)
    topology = topology_hash(tri)
    true_pos = torch.tensor(vertices, dtype=torch.float32)
    true_col = torch.tensor(colors, dtype=torch.float32)
    rng = np.random.default_rng(0)
    pos = torch.tensor(vertices + rng.uniform(-0.5, 0.5, vertices.shape), dtype=torch.float32,
                       requires_grad=True)
    col = torch.tensor(rng.uniform(0, 1, colors.shape), dtype=torch.float32,
                       requires_grad=True)
    opt, schedule = _adam([pos, col], 1e-2)
    batch = {}

    def render_batch() -> None:
        """The next TARGET_BATCH iterations' views and their targets (fit_cube's call)."""
        mvps = torch.tensor(view_matrices(quaternion_matrices(random_quaternions(
            rng, views * TARGET_BATCH)), distance=DISTANCE, fovy=FOVY),
            dtype=torch.float32).reshape(TARGET_BATCH, views, 4, 4)
        with glctx.context:
            targets = _targets(glctx, mvps, true_pos, true_col, tri, resolution, True,
                               topology)
        batch.update(mvps=mvps, targets=targets, next=0)

    def iteration() -> float:
        it = batch["next"] % TARGET_BATCH  # (past the batch: its views again, same work)
        batch["next"] += 1
        target = batch["targets"][it * views:][:views]
        with glctx.context:
            image = render_cube(glctx, batch["mvps"][it], pos, col, tri, resolution,
                                topology=topology)
            loss = torch.mean((image - target) ** 2)
            return _descend(loss, opt, schedule)

    render_batch()
    iteration.batched = (render_batch, TARGET_BATCH)
    return iteration


def _pose(glctx, resolution: int = 256, restarts: int = 8):
    import torch

    from glraster.fitting.scenes import cube
    from glraster.torch.fitting.common import mean_squares, random_quaternions
    from glraster.torch.fitting.pose import render_pose
    from glraster.torch.fitting.render import topology_hash

    topology = topology_hash(torch.tensor(cube()[1], dtype=torch.int32))
    rng = np.random.default_rng(0)
    with torch.no_grad():
        target = render_pose(glctx, torch.tensor(random_quaternions(rng, 1)), resolution,
                             topology=topology)
    q = torch.tensor(random_quaternions(rng, restarts), dtype=torch.float32,
                     requires_grad=True)
    opt, schedule = _adam([q], 3e-2)

    def iteration() -> float:
        image = render_pose(glctx, q, resolution, topology=topology)
        loss = mean_squares(image, target).sum()
        return _descend(loss, opt, schedule,
                        project=lambda: q.div_(q.norm(dim=1, keepdim=True)))

    return iteration


def _texture(glctx, resolution: int = 128, texture_size: int = 256, views: int = 4,
             pool: int = 8):
    import torch

    from glraster.fitting.scenes import procedural_texture
    from glraster.torch.fitting.texture import _mesh, make_views, masked_mse, render_texture

    truth = torch.tensor(procedural_texture(texture_size)[None], dtype=torch.float32)
    rng = np.random.default_rng(0)
    # a small pool at supersample 1: the targets' content does not change the timing
    train = make_views(glctx, rng, pool, resolution, truth, supersample=1)
    tex = torch.full_like(truth, 0.5).requires_grad_(True)
    opt, schedule = _adam([tex], 1e-2)
    mesh = _mesh()

    def iteration() -> float:
        pick = torch.tensor(rng.choice(pool, views, replace=False))
        image, _ = render_texture(glctx, train.mvp[pick], tex, resolution, mip=True,
                                  mesh=mesh)
        loss = masked_mse(image, train.target[pick], train.mask[pick])
        return _descend(loss, opt, schedule, project=lambda: tex.clamp_(0.0, 1.0))

    return iteration


def _envmap(glctx, resolution: int = 256, views: int = 2, mesh=(128, 120),
            env_size: int = 512):
    """The environment-map fit (material under the cube-map sky, ``fit envmap``'s
    defaults: 2 views at 256², the 30,720-triangle blob, a 6 x 512² cube map), its step
    :func:`glraster.torch.fitting.envmap.envmap_loss` as ``fit_envmap`` runs it."""
    import torch

    from glraster.torch.fitting import envmap
    from glraster.torch.fitting.common import random_quaternions

    scene = envmap.make_scene(glctx, mesh=mesh, env_size=env_size)
    rng = np.random.default_rng(0)
    kd = torch.tensor(rng.uniform(0.05, 0.95, 3), dtype=torch.float32, requires_grad=True)
    ks = torch.tensor(rng.uniform(0.05, 0.6, 3), dtype=torch.float32, requires_grad=True)
    log_p = torch.tensor(np.log(30.0), dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([{"params": [kd, ks]}, {"params": [log_p], "lr": 0.15}], lr=0.06)
    schedule = torch.optim.lr_scheduler.LambdaLR(opt, lambda it: 1.0)

    def project():
        kd.clamp_(0.0, 1.0)
        ks.clamp_(0.0, 1.0)

    def iteration() -> float:
        mvp, eye = envmap.view_setup(random_quaternions(rng, views))
        loss = envmap.envmap_loss(glctx, scene, mvp, eye, (kd, ks, torch.exp(log_p)),
                                  resolution)
        return _descend(loss, opt, schedule, project=project)

    return iteration


BUILDERS = {
    "cube4": lambda glctx: _cube(glctx, 4),
    "cube16": lambda glctx: _cube(glctx, 16),
    "pose256": lambda glctx: _pose(glctx, 256),
    "texture": _texture,
    "envmap": _envmap,
}


class PhaseClock:
    """Exclusive time per phase: regions (wrapped functions) push their phase, and the
    time between two events goes to the innermost open region's phase; time outside
    every region is "torch" (torch, autograd, the optimizer and the fit's own code)."""

    def __init__(self):
        self.totals = dict.fromkeys(PHASES, 0.0)
        self._stack = ["torch"]
        self._last = time.perf_counter()

    def _charge(self) -> None:
        now = time.perf_counter()
        self.totals[self._stack[-1]] += now - self._last
        self._last = now

    def reset(self) -> None:
        self.totals = dict.fromkeys(PHASES, 0.0)
        self._last = time.perf_counter()

    def read(self) -> dict[str, float]:
        self._charge()
        return dict(self.totals)

    def wrap(self, function, phase: str):
        @functools.wraps(function)
        def timed(*args, **kwargs):
            self._charge()
            self._stack.append(phase)
            try:
                return function(*args, **kwargs)
            finally:
                self._charge()
                self._stack.pop()
        return timed


# glraster's GL calls by phase: gl_trace's "upload" and "readback" kinds, the rest dispatch
_GL_PHASE = {"upload": "upload", "readback": "readback", "gl": "dispatch"}


@contextmanager
def phase_clock():
    """A :class:`PhaseClock` over glraster's layers while active: the moderngl calls that
    :mod:`glraster.gpu.gl_trace` records (upload, dispatch, readback), glraster's
    ``Context.__enter__/__exit__`` (context: making the context current and restoring
    the caller's), the ops' ``check`` (validation), and the torch bridge and GPU cores
    (python: their host code, NumPy included)."""
    from glraster.diff import ops
    from glraster.gpu import gl_trace
    from glraster.gpu.context import Context
    from glraster.torch import bridge

    clock = PhaseClock()
    undo = []

    def patch(owner, name, phase, raw=None):
        original = owner.__dict__[name] if raw is None else raw
        function = getattr(owner, name)
        undo.append((owner, name, original))
        wrapped = clock.wrap(function, phase)
        if isinstance(original, staticmethod):
            wrapped = staticmethod(wrapped)
        object.__setattr__(owner, name, wrapped) if raw is not None \
            else setattr(owner, name, wrapped)

    try:
        for cls, name, kind in gl_trace._PATCHED:
            patch(cls, name, _GL_PHASE[kind])
        patch(Context, "__enter__", "context")
        patch(Context, "__exit__", "context")
        patch(bridge.Call, "__init__", "python")
        patch(bridge.Call, "__call__", "python")
        patch(bridge._Function, "backward", "python")
        for op in ops.OPS.values():
            patch(op, "check", "validation", raw=op.check)
        with core_hooks(lambda name, function, args, kwargs:
                        clock.wrap(function, "python")(*args, **kwargs)):
            yield clock
    finally:
        for owner, name, original in reversed(undo):
            if isinstance(owner, type):
                setattr(owner, name, original)
            else:
                object.__setattr__(owner, name, original)


def host_hotspots(iteration, iterations: int, top: int = 4) -> list:
    """The ``top`` functions by own time under cProfile, outside torch and moderngl, as
    (share of the profiled time, "file:line(function)"): where the host code spends."""
    profile = cProfile.Profile()
    profile.enable()
    for _ in range(iterations):
        iteration()
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = sum(entry[2] for entry in stats.values()) or 1.0
    host = []
    for (filename, line, funcname), (_, _, tottime, _, callers) in stats.items():
        path = filename.replace("\\", "/")
        if ("/torch/" in path and "/glraster/" not in path) or "/moderngl/" in path \
                or "mgl." in funcname or "torch" in funcname \
                or (filename == "~" and any("/torch/" in c[0] for c in callers)):
            continue
        host.append((tottime / total, f"{path.split('/')[-1]}:{line}({funcname})"))
    return sorted(host, reverse=True)[:top]


def measure_fits(glctx, names, rounds: int, iterations: int, profile_iterations: int) -> dict:
    """{fit: {"iteration", "step", "floors": {segment: s}, "core": {segment: s},
    "calls": {segment: n}, "clocked": s, "phases": {phase: s}, "host": [...]}} (seconds
    per iteration, medians; "clocked" and "phases" from iterations under
    :func:`phase_clock`, interleaved with the plain ones). A fit whose iteration has
    ``batched`` = (function, count) (work its loop runs once for ``count`` iterations)
    has that function timed, recorded and clocked once a round, and each iteration
    charged a ``1/count`` share of it: its segments are "target OP.ROLE"."""
    ctx = glctx.context
    fits = {name: BUILDERS[name](glctx) for name in names}
    out = {}
    samples = {name: {"iteration": [], "step": [], "floors": [], "core": [], "phases": [],
                      "clocked": [], "shared": [], "shared clocked": [], "ratio": []}
               for name in fits}
    calls = {}
    for _ in range(rounds):
        for name, iteration in fits.items():
            batched, count = getattr(iteration, "batched", (None, 1))
            s = samples[name]
            iteration()                                   # warm
            with recording() as rec:
                iteration()
            calls[name] = rec.trace.counts()
            trace, shared_floors, shared_time = rec.trace, {}, 0.0
            if batched is not None:
                with recording() as rec:
                    batched()
                calls[name].update({f"target {k}": n / count
                                    for k, n in rec.trace.counts().items()})
                shared_floors = {f"target {k}": f / count
                                 for k, f in floors_of(rec.trace, ctx).items()}
                totals = {}
                with core_timer(totals):
                    start = time.perf_counter()
                    batched()
                    elapsed = time.perf_counter() - start
                shared_time = elapsed / count
                s["shared"].append((shared_time,
                                    {f"target {k}": t / count for k, t in totals.items()}))
            for _ in range(iterations):
                totals = {}
                with core_timer(totals):
                    start = time.perf_counter()
                    step = iteration()
                    elapsed = time.perf_counter() - start
                s["iteration"].append(elapsed)
                s["step"].append(step)
                s["core"].append(totals)
                # a floor sample after each timed iteration: the same time window
                floors = {**trace.replay(ctx), **shared_floors}
                s["floors"].append(floors)
                s["ratio"].append((elapsed + shared_time) / (sum(floors.values()) + step))
            with phase_clock() as clock:
                if batched is not None:
                    clock.reset()
                    start = time.perf_counter()
                    batched()
                    s["shared clocked"].append(
                        ((time.perf_counter() - start) / count,
                         {p: t / count for p, t in clock.read().items()}))
                for _ in range(iterations):
                    clock.reset()
                    start = time.perf_counter()
                    iteration()
                    s["clocked"].append(time.perf_counter() - start)
                    s["phases"].append(clock.read())
    for name, s in samples.items():
        segments = list(s["floors"][0])
        shared = [t for t, _ in s["shared"]] or [0.0]
        shared_core = [c for _, c in s["shared"]] or [{}]
        shared_clocked = [t for t, _ in s["shared clocked"]] or [0.0]
        shared_phases = [p for _, p in s["shared clocked"]] or [{}]
        core = {k: statistics.median(c.get(k, 0.0) for c in s["core"]) for k in segments}
        core.update({k: statistics.median(c.get(k, 0.0) for c in shared_core)
                     for k in segments if k.startswith("target ")})
        out[name] = {
            "iteration": statistics.median(s["iteration"]) + statistics.median(shared),
            "step": statistics.median(s["step"]),
            "ratio": statistics.median(s["ratio"]),
            "floors": {k: statistics.median(f.get(k, 0.0) for f in s["floors"])
                       for k in segments},
            "core": {k: t for k, t in core.items() if "/" not in k},
            "calls": calls[name],
            "clocked": statistics.median(s["clocked"]) + statistics.median(shared_clocked),
            "phases": {p: statistics.median(t[p] for t in s["phases"])
                       + statistics.median(t.get(p, 0.0) for t in shared_phases)
                       for p in PHASES},
            "host": host_hotspots(fits[name], profile_iterations),
        }
    return {name: out[name] for name in names}


def fit_ratio(fit: dict) -> float:
    """iteration / (floors + step): the median of the ratios of each timed iteration to
    the floor sample taken right after it (common load drift cancels in a pair), or, for
    figures without pairs, the ratio of the medians."""
    return fit["ratio"] if "ratio" in fit else fit["iteration"] / floor_sum(fit)


def floor_sum(fit: dict) -> float:
    """The sum of the iteration's op floors plus its optimizer step."""
    return sum(fit["floors"].values()) + fit["step"]


def _calls(n: float) -> str:
    """A call count per iteration: "2", or a batched call's share "1/32"."""
    return str(round(n)) if n >= 1 or n == 0 else f"1/{round(1 / n)}"


def fits_tables(result: dict) -> str:
    lines = ["| fit | iteration ms | floors + step ms | ratio | clocked ms | "
             + " | ".join(PHASES) + " |", "|---|---|---|---|---|" + "---|" * len(PHASES)]
    for name, fit in result.items():
        it = fit["iteration"]
        shares = " | ".join(f"{1e3 * fit['phases'][p]:.2f}" for p in PHASES)
        lines.append(f"| {name} | {1e3 * it:.2f} | {1e3 * floor_sum(fit):.2f} | "
                     f"{fit_ratio(fit):.2f} | {1e3 * fit['clocked']:.2f} | {shares} |")
    lines += ["", "| fit | op call | calls | core ms | floor ms | core / floor |",
              "|---|---|---|---|---|---|"]
    for name, fit in result.items():
        for seg in sorted(fit["core"]):
            floor = op_floor(fit["floors"], seg)
            core = fit["core"][seg]
            lines.append(f"| {name} | {seg} | {_calls(fit['calls'].get(seg, 0))} | "
                         f"{1e3 * core:.3f} | {1e3 * floor:.3f} | "
                         f"{_ratio(core, floor)} |")
        lines.append(f"| {name} | optimizer step | 1 | {1e3 * fit['step']:.3f} | | |")
    lines += ["", "| fit | largest host-code entries under cProfile, ms per iteration "
              "(share x iteration) |", "|---|---|"]
    for name, fit in result.items():
        top = "; ".join(f"`{where}` {1e3 * fit['iteration'] * share:.2f}"
                        for share, where in fit["host"])
        lines.append(f"| {name} | {top} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- main


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="glraster study diff-floors",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=("ops", "fits", "both"), default="both")
    parser.add_argument("--op-size", type=int, nargs="+", default=[64, 256],
                        help="image sizes N (N x N) of the op table")
    parser.add_argument("--fits", nargs="+", choices=FITS, default=list(FITS))
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds")
    parser.add_argument("--calls", type=int, default=5, help="op calls per round and path")
    parser.add_argument("--iterations", type=int, default=10,
                        help="timed fit iterations per round")
    parser.add_argument("--profile-iterations", type=int, default=10,
                        help="fit iterations under cProfile for the host-code hints")
    parser.add_argument("--backend", default=None, help="OpenGL backend (egl, osmesa)")
    parser.add_argument("--json", action=OutputFile,
                        default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    for option in ("rounds", "calls", "iterations", "profile_iterations"):
        if getattr(args, option) < 1:
            parser.error(f"--{option.replace('_', '-')} must be at least 1")
    if min(args.op_size) < 1:
        parser.error("--op-size must be at least 1")

    from glraster.torch.fitting.common import session

    figures = {}
    with ExitStack() as stack:
        glctx = stack.enter_context(session(backend=args.backend))
        print(f"# diff-floors on {glctx.context.renderer} ({glctx.context.backend})")
        if args.part in ("ops", "both"):
            figures["ops"] = measure_ops(glctx, args.op_size, args.rounds, args.calls)
            print("\n## Op floors (medians; x floor = time / floor)\n")
            print(ops_table(figures["ops"]))
        if args.part in ("fits", "both"):
            figures["fits"] = measure_fits(glctx, args.fits, args.rounds, args.iterations,
                                           args.profile_iterations)
            print("\n## One fit iteration: ratio = iteration / (op floors + optimizer "
                  "step), the median over iterations each paired with the floor sample "
                  "after it; phases (ms, exclusive) of the clocked iterations\n")
            print(fits_tables(figures["fits"]))
    if args.json:
        from glraster.io.atomic import write_text

        write_text(args.json, json.dumps(figures, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
