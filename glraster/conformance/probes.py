"""Probes that name a defect: tiny scenes, each testing one thing the conformance suite
relies on, with its expectation, the GL section it relies on and a one-line diagnosis.

``glraster check`` runs them before the catalog (with the rule detection of
:mod:`glraster.conformance.rules`). When a catalog scene fails, the failing probes whose
defect can produce that failure are named beside it ("explained by"), so a report says
*what* is broken (the triangle id is one too high; noperspective values of triangles
clipped by two planes are wrong), not only "N coverage mismatches".

A probe's status is "pass", "fail", "known" (a failure that matches a documented driver
deviation, e.g. Mesa's noperspective clipping defect, counted like the error model's
waivers and not failing the run), "skipped" (this context cannot run it, e.g. a GL 4.5
shader patch on a GL 3.3 context) or "error" (the probe raised).

Every probe draws through ``render(pos, tri, resolution, outputs, **multisample) -> Raster``
(``multisample``: ``samples`` and ``interpolation``), by default :func:`glraster.rasterize`
on the context, or a fault-injection mutant's render (tests/conformance/test_probes.py:
the tri_id_off_by_one mutant fails the id probe). The multisampling probes are in
:mod:`glraster.conformance.msaa_probes`.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from glraster import reference as _reference
from glraster.verify.compare import compare
from glraster.verify.tolerance import ErrorModel, mesa_noperspective_clip_bug

SPEC_RASTER = "GL 4.6 core §14.6.1 Basic Polygon Rasterization; GL 3.3 core §3.6.1"
SPEC_IDS = ("GL 4.6 core §15.2.2 Shader Inputs (gl_PrimitiveID counts the primitives of "
            "the drawing command from 0) and §11.1.3.9 (gl_VertexID); GL 3.3 core §3.9.2 "
            "and §2.11.7")
SPEC_CLIP = ("GL 4.6 core §13.7.1 Clipping Shader Outputs (a clipped vertex's outputs are "
             "those of the unclipped primitive; noperspective ones linear in window space, "
             "§14.6.1 eq. 14.10); GL 3.3 core §2.19.1")
SPEC_DEPTH = ("GL 4.6 core §14.6.1 eq. 14.10 (depth linear in window space), §8.5.1 "
              "(DEPTH_COMPONENT32F holds a 32-bit float), §17.3.6 Depth Buffer Test (LESS); "
              "GL 3.3 core §3.6.1, §3.8.3, §4.1.5")
SPEC_INT = ("GL 4.6 core §15.2.3 Shader Outputs (an int output to an integer color buffer "
            "is written unchanged), §8.5.1 (R32I is a 32-bit signed integer); GL 3.3 core "
            "§3.9.2, §3.8.3")
SPEC_FLOAT = ("GL 4.6 core §8.5.1 (R32F / RGB32F hold 32-bit floats) and §2.3.4.1 "
              "Floating-Point Computation; GL 3.3 core §3.8.3, §2.1.1")

ID_OFFSET = 1 << 24  # ids beyond the integers float32 holds exactly


@dataclass
class ProbeResult:
    """Outcome of one probe.

    name, spec : identifier and the GL sections it relies on
    expectation : what a conforming driver produces, in one sentence
    status : "pass", "fail", "known", "skipped" or "error"
    diagnosis : one line naming the defect (empty when it passes)
    detail : measured figures behind the verdict
    explains : names of the catalog scenes whose failures this defect can explain
    """

    name: str
    spec: str
    expectation: str
    status: str = "pass"
    diagnosis: str = ""
    detail: str = ""
    seconds: float = 0.0
    explains: list = field(default_factory=list)
    # failures of a scene this probe explains: a predicate set by the probe
    _explains: object = field(default=None, repr=False)
    threshold: int = 0  # smallest triangle count whose ids this defect breaks

    @property
    def ok(self) -> bool:
        """Passed, or failed only as a documented deviation, or could not run here."""
        return self.status in ("pass", "known", "skipped")

    @property
    def failed(self) -> bool:
        return self.status in ("fail", "known")

    def verdict(self, diagnosis: str, *words: str) -> ProbeResult:
        """Fail with ``diagnosis`` unless it is empty; either way the probe explains the
        failures of scenes whose messages mention any of ``words``."""
        if diagnosis:
            self.status, self.diagnosis = "fail", diagnosis
        self._explains = lambda _self, scene, f: _mentions(f, *words)
        return self

    def line(self) -> str:
        text = f"{self.name:<22}{self.status.upper():<8} {self.expectation}"
        if self.diagnosis:
            text += f"\n{'':<30}-> {self.diagnosis}"
        return text

    def explains_scene(self, scene, result) -> bool:
        """Whether this probe's defect can explain ``result`` (a failed SceneResult)."""
        if not self.failed or self._explains is None or result.ok:
            return False
        return bool(self._explains(self, scene, " | ".join(result.failures)))


# -- scene helpers ---------------------------------------------------------------------------

def _clip(window, resolution, w=None, z=None) -> np.ndarray:
    """(N, 4) float32 clip positions of window positions (N, 2) (float64), with clip w
    (default 1; the window position is kept) and NDC z (default 0)."""
    height, width = resolution
    window = np.asarray(window, np.float64).reshape(-1, 2)
    w = np.ones(len(window)) if w is None else np.broadcast_to(np.asarray(w, float), len(window))
    z = np.zeros(len(window)) if z is None else np.broadcast_to(np.asarray(z, float), len(window))
    x = (window[:, 0] * 2 / width - 1) * w
    y = (window[:, 1] * 2 / height - 1) * w
    return np.stack([x, y, z * w, w], 1).astype(np.float32)


def _cell_triangle(k: int, per_row: int = 8, size: int = 8):
    """Window vertices of a triangle well inside cell k (size x size px, row-major)."""
    x0, y0 = (k % per_row) * size, (k // per_row) * size
    return [(x0 + 0.3, y0 + 0.4), (x0 + size - 0.7, y0 + 0.9), (x0 + 1.1, y0 + size - 0.6)]


def _cell_ids(ids: np.ndarray, k: int, per_row: int = 8, size: int = 8) -> set:
    x0, y0 = (k % per_row) * size, (k // per_row) * size
    found = set(np.unique(ids[y0:y0 + size, x0:x0 + size]).tolist())
    found.discard(-1)
    return found


def _id_scene(visible, total, resolution=(64, 64)):
    """``total`` triangles of which those in ``visible`` (indices) are drawn in their own
    cells, the others collapsed onto one point (zero area: no fragment, but numbered).
    w alternates 1 and 2 per vertex so that the draw takes the perspective path."""
    cells = np.array([_cell_triangle(k) for k in range(len(visible))], np.float64)
    w = np.tile([1.0, 2.0, 1.0], len(visible))
    pos = np.concatenate([_clip(cells.reshape(-1, 2), resolution, w=w),
                          _clip([(0.5, 0.5)], resolution)])
    point = len(pos) - 1
    tri = np.full((total, 3), point, np.int32)
    tri[np.asarray(visible)] = np.arange(3 * len(visible), dtype=np.int32).reshape(-1, 3)
    return pos, tri, resolution


def _describe_ids(ids, visible, total) -> tuple[list, str]:
    """Per visible triangle what its cell holds; the wrong ones and a one-line summary."""
    wrong = []
    offsets = set()
    for k, t in enumerate(visible):
        found = _cell_ids(ids, k)
        if found != {int(t)}:
            wrong.append((int(t), sorted(found)))
            if len(found) == 1:
                offsets.add(next(iter(found)) - int(t))
    if not wrong:
        return [], ""
    shown = ", ".join(f"triangle {t} reads {f if f else 'nothing'}" for t, f in wrong[:4])
    if len(offsets) == 1 and len(wrong) == len(visible):
        d = offsets.pop()
        return wrong, f"every triangle id is off by {d:+d} ({shown})"
    return wrong, f"{len(wrong)} of {len(visible)} triangles of a {total}-triangle draw read " \
                  f"a wrong id ({shown})"


def probe_shared_edges(render, ctx) -> ProbeResult:
    p = ProbeResult("shared_edges", SPEC_RASTER + " (a center on an edge shared by two "
                    "triangles is covered by exactly one of them)",
                    "a 16x16-pixel grid of 128 triangles with every vertex on a pixel "
                    "center leaves no center inside it uncovered")
    res = (32, 32)
    n = 8
    xs = 4.5 + 2 * np.arange(n + 1)
    gx, gy = np.meshgrid(xs, xs)
    window = np.stack([gx.ravel(), gy.ravel()], 1)
    pos = _clip(window, res, w=np.where(np.arange(len(window)) % 2, 1.0, 2.0))
    v = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = v[:-1, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, :-1].ravel(), v[1:, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    ids = render(pos, tri, res, ("tri_id",)).tri_id
    inside = ids[5:20, 5:20]
    holes = int((inside < 0).sum())
    p.detail = f"{holes} of {inside.size} interior centers uncovered"
    diagnosis = (f"{holes} pixel centers on edges shared by two triangles are covered by "
                 "neither (holes along shared edges)") if holes else ""
    return p.verdict(diagnosis, "coverage", "triangle id")


def _mentions(text, *words) -> bool:
    return any(w in text for w in words)


# -- the probes ------------------------------------------------------------------------------

def probe_tri_id(render, ctx) -> ProbeResult:
    p = ProbeResult("tri_id_source", SPEC_IDS,
                    "each of 6 triangles writes its own index to the tri_id target")
    visible = list(range(6))
    pos, tri, res = _id_scene(visible, len(visible))
    r = render(pos, tri, res, ("tri_id",))
    wrong, text = _describe_ids(r.tri_id, visible, len(tri))
    diagnosis = (f"the triangle id source is wrong: {text}; the suite decodes tri_base + "
                 "gl_PrimitiveID + 1 as the index") if wrong else ""
    return p.verdict(diagnosis, "triangle id", "coverage")


@contextlib.contextmanager
def _small_batches(ctx, triangles: int):
    """Draw in batches of ``triangles`` on this context for a while (the storage-block
    size of the GL 4.3+ path, the vertex batch of the GL 3.3 path)."""
    from glraster.gpu import pipeline

    saved_block = getattr(ctx, "max_storage_block_size", 0)
    saved_vertex = getattr(pipeline, "VERTEX_BATCH_TRIANGLES", None)
    try:
        if saved_block:
            ctx.max_storage_block_size = triangles * 3 * 4
        if saved_vertex is not None:
            pipeline.VERTEX_BATCH_TRIANGLES = triangles
        yield
    finally:
        if saved_block:
            ctx.max_storage_block_size = saved_block
        if saved_vertex is not None:
            pipeline.VERTEX_BATCH_TRIANGLES = saved_vertex


# Triangles per batch when the probe forces batching: the positions (25 vertices, 400
# bytes) must still fit one storage block of BATCH * 12 bytes.
BATCH = 34


def probe_numbering(render, ctx) -> ProbeResult:
    p = ProbeResult("primitive_numbering", SPEC_IDS,
                    f"ids stay global across draws in batches of {BATCH} triangles and in "
                    "one draw of 2^18 + 3 triangles (gl_VertexID up to 786k)")
    problems = []
    visible = [0, BATCH - 1, BATCH, 2 * BATCH - 1, 2 * BATCH, 3 * BATCH - 1, 3 * BATCH,
               3 * BATCH + 4]
    pos, tri, res = _id_scene(visible, 3 * BATCH + 5)
    with _small_batches(ctx, BATCH):
        r = render(pos, tri, res, ("tri_id",))
    wrong, text = _describe_ids(r.tri_id, visible, len(tri))
    if wrong:
        problems.append(f"in batches of {BATCH}: {text}")
        p.threshold = BATCH
    total = (1 << 18) + 3
    visible = [0, 255, 256, 65535, 65536, 131072, total - 1]
    pos, tri, res = _id_scene(visible, total)
    r = render(pos, tri, res, ("tri_id",))
    wrong2, text = _describe_ids(r.tri_id, visible, total)
    if wrong2:
        problems.append(f"in one large draw: {text}")
        p.threshold = min(t for t, _ in wrong2) if not wrong else p.threshold
    if problems:
        p.status = "fail"
        p.diagnosis = "vertex / primitive numbering breaks " + "; ".join(problems)
    p._explains = lambda self, scene, f: (_mentions(f, "triangle id", "coverage")
                                          and len(scene.tri) > self.threshold)
    return p


def _clip_scene(crossing: str):
    """One triangle at 64x64 crossing the x = +w plane only ("x") or x = +w and the near
    plane ("x+near"); w differs per vertex."""
    if crossing == "x":
        pos = np.array([[-0.6, -0.7, 0.1, 1.0], [2.6, -0.2, 0.3, 2.0],
                        [0.2, 0.8, -0.2, 1.5]], np.float32)
    else:
        pos = np.array([[-0.6, -0.7, 0.1, 1.0], [2.6, -0.2, -2.5, 2.0],
                        [0.2, 0.8, -0.2, 1.5]], np.float32)
    return pos, np.array([[0, 1, 2]], np.int32), (64, 64)


def probe_noperspective_clip(render, ctx, earlier=()) -> ProbeResult:
    p = ProbeResult("noperspective_clip", SPEC_CLIP,
                    "noperspective barycentrics of clipped triangles equal the unclipped "
                    "triangle's (one x plane; an x plane and the near plane)")
    model = ErrorModel.for_context(ctx)
    model = ErrorModel(model.ulp_factor, model.position_error_px, waived_outputs=())
    worst = {}
    for crossing in ("x", "x+near"):
        pos, tri, res = _clip_scene(crossing)
        gpu = render(pos, tri, res, ("screen", "tri_id"))
        ref = _reference.rasterize(pos, tri, res, outputs=("screen", "tri_id"))
        rep = compare(gpu, ref, model=model)
        s = rep.values["screen"]
        nonfinite = int((~np.isfinite(gpu.screen[gpu.mask])).any(axis=-1).sum())
        worst[crossing] = (s.over_tolerance, s.max, nonfinite, s.pixels,
                           bool(mesa_noperspective_clip_bug(ref.triangles)[0]))
    p.detail = "; ".join(f"{c}: {o} of {n} px over tolerance, max error {m:.3g}, {nf} NaN/Inf"
                         for c, (o, m, nf, n, _) in worst.items())
    one, two = worst["x"], worst["x+near"]
    if any(r.name == "float_target" and r.failed for r in earlier):
        p.status = "skipped"
        p.detail += " (not judged: float_target failed, the barycentrics lack float32 precision)"
    elif one[0] or one[2]:
        p.status = "fail"
        p.diagnosis = (f"noperspective values are wrong even on a triangle clipped by one x "
                       f"plane ({one[0]} px, max error {one[1]:.3g})")
        p._explains = lambda self, scene, f: _mentions(f, "screen", "NaN")
    elif two[0] or two[2]:
        p.status = "known" if two[4] else "fail"
        p.diagnosis = (f"noperspective values of triangles clipped by an x plane and another "
                       f"plane are wrong ({two[0]} px, max error {two[1]:.3g}, {two[2]} "
                       "NaN/Inf): Mesa's draw clipper takes a 0/0 window-space blend factor "
                       "(docs/llvmpipe.md; tolerance.mesa_noperspective_clip_bug)")
        p._explains = lambda self, scene, f: (_mentions(f, "screen", "NaN", "persp")
                                              and _has_double_clip(scene))
    return p


def _has_double_clip(scene) -> bool:
    """Whether a scene holds a triangle crossing an x plane and another clip plane."""
    clip = np.asarray(scene.pos, np.float64)[np.asarray(scene.tri)]
    x, y, z, w = (clip[..., i] for i in range(4))
    outside = np.stack([x > w, x < -w, y > w, y < -w, z > w, z < -w], -1).any(1)
    return bool((outside[:, :2].any(1) & (outside.sum(1) >= 2)).any())


DEPTH_STEP = 1.25 * 2.0 ** -17   # just beyond the reference's DEPTH_TIE (2^-17)


def probe_depth(render, ctx, earlier=()) -> ProbeResult:
    p = ProbeResult("depth_precision", SPEC_DEPTH,
                    "window depth matches the reference within the error model, and LESS "
                    "orders triangles 1.25*2^-17 apart (beyond the suite's depth-tie "
                    "margin), keeping the earlier one on a tie")
    res = (64, 64)
    problems = []
    # (a) a sloped plane from z_w = 0.3 to 0.7 (w = 1: every input exact in float32)
    window = [(0.5, 0.5), (63.5, 0.5), (0.5, 63.5)]
    pos = _clip(window, res, z=np.array([-0.4, 0.4, 0.0]))
    tri = np.array([[0, 1, 2]], np.int32)
    gpu = render(pos, tri, res, ("depth", "tri_id"))
    ref = _reference.rasterize(pos, tri, res, outputs=("depth", "tri_id"))
    rep = compare(gpu, ref, model=ErrorModel.for_context(ctx))
    d = rep.values["depth"]
    p.detail = f"sloped depth: max error {d.max:.3g}, worst error/tolerance {d.worst_ratio:.3g}"
    if gpu.mask.any() and (gpu.depth[gpu.mask] == 1.0).all():
        problems.append("depth is not written (covered pixels read the cleared 1.0): the "
                        "depth test or depth writes are off")
    elif d.over_tolerance:
        bits = -np.log2(max(d.max, 2.0 ** -60))
        problems.append(f"window depth is off by up to {d.max:.3g} ({d.over_tolerance} px over "
                        f"tolerance): about {bits:.0f} bits, not a 32-bit float depth buffer")
    # (b) LESS in draw order: a far triangle, a nearer one DEPTH_STEP in front (must win),
    # a third at the nearer one's depth (a tie: must lose)
    big = [(2.0, 2.0), (62.0, 3.0), (3.0, 62.0)]
    z_far, z_near = 2 * DEPTH_STEP, 0.0          # z_w = 0.5 + DEPTH_STEP and 0.5
    pos = np.concatenate([_clip(big, res, z=np.full(3, z_far)),
                          _clip(big, res, z=np.full(3, z_near)),
                          _clip(big, res, z=np.full(3, z_near))])
    tri = np.arange(9, dtype=np.int32).reshape(3, 3)
    ids = render(pos, tri, res, ("tri_id",)).tri_id
    seen = set(np.unique(ids[ids >= 0]).tolist())
    if any(r.name == "tri_id_source" and r.failed for r in earlier):
        p.detail += "; draw order not judged (the ids are wrong, see tri_id_source)"
    elif seen != {1}:
        what = {0: "the farther first triangle (depth not resolved to 1.25*2^-17)",
                2: "the last one drawn (ties go to the later fragment: no LESS test)"}
        problems.append("the depth test keeps " + ", ".join(what.get(t, f"triangle {t}")
                                                             for t in sorted(seen))
                        + " where the nearer second of three triangles must win")
    return p.verdict("; ".join(problems), "depth", "triangle id")


def probe_integer_target(render, ctx) -> ProbeResult:
    p = ProbeResult("integer_target", SPEC_INT,
                    f"the R32I id target holds ids beyond 2^24 exactly ({ID_OFFSET} + k, "
                    "written by the real shader with a constant offset)")
    from glraster.conformance import mutants as _mutants

    offset = _mutants.Mutant("probe_id_offset", f"ids written {ID_OFFSET} higher", patches=(
        _mutants.Patch(_mutants.FRAG, "out_tri_id = tri_base + ",
                       f"out_tri_id = {ID_OFFSET} + tri_base + "),))
    visible = list(range(5))
    pos, tri, res = _id_scene(visible, len(visible))
    try:
        r = _mutants.render(offset, pos, tri, res, ctx=ctx, outputs=("persp", "tri_id"))
    except Exception as exc:  # e.g. GL 4.5 shaders on a GL 3.3 context
        p.status = "skipped"
        p.detail = f"the offset shader cannot run here: {type(exc).__name__}: {str(exc)[:120]}"
        return p
    got = r.tri_id.astype(np.int64)
    wrong = []
    for k in visible:
        x0, y0 = (k % 8) * 8, (k // 8) * 8
        cell = set(np.unique(got[y0:y0 + 8, x0:x0 + 8]).tolist()) - {-1}
        if cell != {ID_OFFSET + k}:
            wrong.append((k, sorted(cell)))
    shown = ", ".join(f"{ID_OFFSET + k} read as {c}" for k, c in wrong[:3])
    diagnosis = f"the integer id target does not hold 32-bit integers: {shown}" if wrong else ""
    return p.verdict(diagnosis, "triangle id", "coverage")


def probe_float_target(render, ctx) -> ProbeResult:
    p = ProbeResult("float_target", SPEC_FLOAT,
                    "barycentrics on a well-shaped triangle come back within 2^-16 of the "
                    "reference (32-bit float targets)")
    res = (64, 64)
    window = [(1.3, 2.1), (62.2, 5.4), (7.7, 61.6)]
    pos = _clip(window, res, w=np.array([1.0, 3.0, 2.0]))
    tri = np.array([[0, 1, 2]], np.int32)
    gpu = render(pos, tri, res, ("persp", "screen", "tri_id"))
    ref = _reference.rasterize(pos, tri, res, outputs=("persp", "screen", "tri_id"))
    both = gpu.mask & ref.mask
    errs = {n: float(np.abs(getattr(gpu, n)[both].astype(np.float64)
                            - getattr(ref, n)[both]).max()) if both.any() else np.inf
            for n in ("persp", "screen")}
    p.detail = ", ".join(f"{n} max error {e:.3g}" for n, e in errs.items())
    bad = {n: e for n, e in errs.items() if not e <= 2.0 ** -16}
    if bad:
        p.status = "fail"
        worst, names = max(bad.values()), ", ".join(bad)
        if 2.0 ** -13 <= worst < 2.0 ** -8:   # half-float rounding of values in [0, 1]
            p.diagnosis = (f"float targets lose precision: {names} off by up to {worst:.3g} "
                           "(about half-float rounding, 11 bits); the targets must hold "
                           "32-bit floats")
        else:   # R32F targets and an interpolation of float32 precision would hold 2^-16
            p.diagnosis = (f"{names} off by up to {worst:.3g}: less than float32 precision "
                           "from the driver's varying interpolation or its float targets")
    p._explains = lambda self, scene, f: _mentions(f, "persp", "screen")
    return p


# (name, probe); a probe taking ``earlier`` sees the results before it (a depth probe
# judged by ids does not blame the depth test for wrong ids).
PROBES = (("shared_edges", probe_shared_edges),
          ("tri_id_source", probe_tri_id), ("primitive_numbering", probe_numbering),
          ("integer_target", probe_integer_target), ("float_target", probe_float_target),
          ("noperspective_clip", probe_noperspective_clip), ("depth_precision", probe_depth))


def all_probes():
    """PROBES and the multisampling probes (glraster.conformance.msaa_probes)."""
    from glraster.conformance import msaa_probes

    return PROBES + msaa_probes.PROBES


def run(ctx, render=None) -> list[ProbeResult]:
    """Run every probe on ``ctx``; ``render(pos, tri, resolution, outputs) -> Raster``
    replaces the draw (default :func:`glraster.rasterize` with host culling off, so that
    the ids of zero-area triangles stay numbered by the driver)."""
    if render is None:
        from glraster.gpu.rasterize import rasterize

        def render(pos, tri, resolution, outputs, **multisample):
            return rasterize(pos, tri, resolution, ctx=ctx, outputs=outputs, cull=False,
                             **multisample)
    results = []
    for name, probe in all_probes():
        t = time.perf_counter()
        try:
            if "earlier" in probe.__code__.co_varnames:
                r = probe(render, ctx, earlier=tuple(results))
            else:
                r = probe(render, ctx)
        except Exception as exc:  # a probe that crashes must not stop the run
            r = ProbeResult(name, "", "", status="error",
                            diagnosis=f"the probe raised {type(exc).__name__}: {exc}")
        r.seconds = time.perf_counter() - t
        results.append(r)
    return results


def mutant_render(mutant, ctx):
    """A ``render`` for :func:`run` drawing with a fault-injection mutant."""
    from glraster.conformance import mutants as _mutants

    def render(pos, tri, resolution, outputs, **multisample):
        return _mutants.render(mutant, pos, tri, resolution, ctx=ctx, outputs=outputs,
                               **multisample)
    return render


def format_probes(results) -> list[str]:
    """Report lines, one per probe (two when it names a defect)."""
    return [r.line() for r in results]
