"""The conformance run behind ``glraster check``: every catalog scene on the current driver,
compared with the reference (per-pixel error model) and with its golden EXR.

Per scene, for one barycentric method (``method``, default "hw"):

1. render on the GPU (:func:`glraster.rasterize`) with the scene's outputs;
2. compute the float64 reference (:func:`glraster.conformance.golden.reference_for`);
3. :func:`glraster.compare`: coverage (exact where llvmpipe's fill rule is modeled, edge
   band elsewhere), triangle ids, and every value against its per-pixel tolerance from
   :meth:`glraster.verify.tolerance.glraster.gpu.methods.error_model` for this method and context;
4. non-finite GPU values on covered pixels are failures of their own;
5. the golden EXR must equal the reference bit for bit (:func:`glraster.conformance.golden.check_scene`),
   so the GPU is checked against the golden through the same tolerances; the largest
   |GPU - golden| is reported as a figure.

Pixels the error model waives (documented driver deviations, see
:class:`glraster.verify.tolerance.ErrorModel`) are counted and shown ("waived"), never hidden.

Before the catalog, the driver's rasterization rules are measured
(:mod:`glraster.conformance.rules`: subpixel bits, tie rule, snapping) and coverage is
judged against the detected rule exactly (the edge band where none is identified), and
the probes of :mod:`glraster.conformance.probes` run; a failing probe is named beside
every failed scene its defect can explain. The goldens stay llvmpipe's (driver
independent): on a driver with another rule their values are compared where the ids agree.

With ``mutants``, every mutant of :mod:`glraster.conformance.mutants` is rendered on the scenes that the
real shaders passed (cheapest first) until one scene catches it; the real shaders go
through the same mutant path as a control and must pass every one of those scenes.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from glraster.conformance import golden as _golden
from glraster.conformance import mutants as _mutants
from glraster.conformance import probes as _probes
from glraster.conformance import rules as _rules
from glraster.errors import ArgumentError
from glraster.verify.compare import compare, waived_pixels
from glraster.gpu.methods import METHODS, error_model
from glraster.gpu.rasterize import rasterize
from glraster.conformance.scenes import Scene, list_scenes, load_scene, with_samples
from glraster.geometry.samples import STANDARD_POSITIONS
from glraster.verify.tolerance import ErrorModel, mesa_noperspective_clip_bug

# References kept in memory for the mutant pass: scenes up to this many pixels.
REFERENCE_CACHE_PIXELS = 1 << 20


@dataclass
class SceneResult:
    """Outcome of one scene.

    status  : "pass", "fail" or "error" (an exception; ``error`` holds the message)
    report  : the :class:`glraster.verify.compare.Report` (None on error)
    golden  : :class:`glraster.conformance.golden.GoldenResult` (None when golden checking is off)
    nonfinite : covered GPU pixels with NaN/Inf in some (judged) output
    waived  : output -> pixels the error model did not judge (documented deviation)
    golden_max_error : largest |GPU - golden| over pixels both cover with the same triangle
    timings : seconds for "gpu", "reference", "compare", "golden"
    """

    name: str
    description: str
    resolution: tuple
    triangles: int
    samples: int = 1
    interpolation: str = "center"
    status: str = "pass"
    report: object = None
    golden: object = None
    nonfinite: int = 0
    waived: dict = field(default_factory=dict)
    golden_max_error: float = 0.0
    error: str = ""
    failures: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    explained_by: list = field(default_factory=list)  # (probe name, diagnosis) of failed probes

    @property
    def ok(self) -> bool:
        return self.status == "pass"

    @property
    def seconds(self) -> float:
        return sum(self.timings.values())

    @property
    def sampling(self) -> str:
        """"1", or samples and interpolation (e.g. "4 centroid"), for reports."""
        return "1" if self.samples == 1 else f"{self.samples} {self.interpolation}"


@dataclass
class Evaluation:
    """Outcome of :func:`evaluate`.

    report   : the :class:`glraster.verify.compare.Report`
    failures : list of str, why the raster fails (empty: it passes)
    nonfinite : covered GPU pixels with NaN/Inf in some judged output
    waived   : output -> pixels the error model did not judge (documented deviation)
    """

    report: object
    failures: list = field(default_factory=list)
    nonfinite: int = 0
    waived: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failures


@dataclass
class SceneArtifacts:
    """The arrays behind one scene's result, kept for reports (``run_scene(keep=True)``).

    gpu    : the GPU :class:`glraster.Raster`
    ref    : the :class:`glraster.reference.ReferenceRaster`
    report : the :class:`glraster.verify.compare.Report` of ``gpu`` against ``ref``
    """

    gpu: object
    ref: object
    report: object


@dataclass
class MutantResult:
    """Outcome of one mutant: caught by ``caught_by`` (a scene name) or escaped."""

    name: str
    fault: str
    caught_by: str | None = None
    reason: str = ""
    scenes_tried: int = 0
    error: str = ""
    seconds: float = 0.0

    @property
    def caught(self) -> bool:
        return self.caught_by is not None


@dataclass
class CheckResult:
    """A whole run: context description, per-scene results, and the mutant pass."""

    backend: str
    renderer: str
    gl_version: str
    method: str = "hw"
    scenes: list = field(default_factory=list)
    mutants: list | None = None
    control_failures: list = field(default_factory=list)  # scenes the control failed
    seconds: float = 0.0
    notes: list = field(default_factory=list)  # remarks for people (e.g. goldens skipped)
    shard: tuple | None = None  # (I, N) when this run is shard I of N (shard_scenes)
    rules: object = None   # the RuleDetection of glraster.conformance.rules (None: not run)
    probes: list = field(default_factory=list)  # ProbeResults of glraster.conformance.probes
    driver: str | None = None  # the fleet driver name (glraster.cluster); None: this machine's

    @property
    def ok(self) -> bool:
        scenes_ok = all(s.ok for s in self.scenes) and all(p.ok for p in self.probes)
        if self.mutants is None:
            return scenes_ok
        return scenes_ok and all(m.caught for m in self.mutants) and not self.control_failures


def evaluate(gpu, ref, ctx, model=None) -> Evaluation:
    """Compare a GPU raster with the reference (:func:`glraster.compare` with the context's
    error model) and add the non-finite rule: a NaN or Inf on a covered pixel fails, except
    in values the model waives."""
    model = model if model is not None else ErrorModel.for_context(ctx)
    rep = compare(gpu, ref, model=model)
    failures = []
    covered = gpu.mask if gpu.mask.ndim == 2 else gpu.mask.any(axis=2)
    pix = np.flatnonzero(covered)                # work on covered pixels only
    nonfinite = np.zeros(len(pix), bool)
    for name in ("persp", "screen", "depth"):
        a = getattr(gpu, name)
        if a is None:
            continue
        flat = a.reshape(a.shape[0] * a.shape[1], -1)[pix]
        if a.ndim > 2 + (name != "depth"):       # per sample: only the covered samples
            flat = np.where(gpu.mask.reshape(-1, gpu.samples, 1)[pix], flat.reshape(
                len(pix), gpu.samples, -1), 0).reshape(len(pix), -1)
        elif name == "depth" and a.ndim == 3:
            flat = np.where(gpu.mask.reshape(-1, gpu.samples)[pix], flat, 0)
        nf = ~np.isfinite(flat).all(axis=1)
        if name in model.waived_outputs and nf.any():
            if gpu.samples == 1:
                nf &= ~waived_pixels(ref.triangles, ref.tri_id, model).reshape(-1)[pix]
            elif ref.triangles is not None:
                ids = ref.tri_id.reshape(-1, gpu.samples)[pix]
                bug = mesa_noperspective_clip_bug(ref.triangles)
                nf &= ~np.where(ids >= 0, bug[np.maximum(ids, 0)], False).any(axis=1)
        nonfinite |= nf
    n_nonfinite = int(nonfinite.sum())
    if rep.coverage_mismatch:
        failures.append(f"{rep.coverage_mismatch} coverage mismatches outside the edge band")
    if rep.tri_id_mismatch:
        failures.append(f"{rep.tri_id_mismatch} triangle id mismatches")
    if n_nonfinite:
        failures.append(f"{n_nonfinite} covered pixels with NaN/Inf values")
    unit = "samples" if rep.samples > 1 else "pixels"
    for name, stats in rep.values.items():
        if stats.over_tolerance:
            failures.append(f"{name}: {stats.over_tolerance} {unit} over tolerance (worst "
                            f"error/tolerance {stats.worst_ratio:.3g}, max error {stats.max:.3g})")
    if rep.point is not None and rep.point.failures:
        p = rep.point
        failures.append(
            f"{rep.interpolation} values: {p.failures} pixels break GLSL's condition on the "
            f"point ({p.outside_pixel} outside the pixel, {p.outside_triangle} outside the "
            f"triangle, {p.persp_inconsistent} persp not perspective-correct there; worst "
            f"ratio {p.worst_ratio:.3g})")
    waived = {n: v.waived for n, v in rep.values.items() if getattr(v, "waived", 0)}
    return Evaluation(rep, failures, n_nonfinite, waived)


def _golden_max_error(gpu, g) -> float:
    """Largest |GPU - golden| over the golden's window, where both hold the same id
    (multisampled: per sample, when the driver's sample positions are the goldens'
    standard ones; NaN otherwise)."""
    arrays = {n: getattr(gpu, n) for n in ("persp", "screen", "depth", "tri_id")}
    if gpu.samples > 1:
        standard = np.array(STANDARD_POSITIONS.get(gpu.samples, ()), np.float64)
        if not np.array_equal(gpu.sample_positions, standard):
            return float("nan")
        arrays = _golden.folded(gpu, tuple(n for n, a in arrays.items() if a is not None))
    y0, y1, x0, x1 = g.window
    worst = 0.0
    same = None
    if g.tri_id is not None and arrays.get("tri_id") is not None:
        same = (arrays["tri_id"][y0:y1, x0:x1] == g.tri_id) & (g.tri_id >= 0)
    for name in ("persp", "screen", "depth"):
        a, b = arrays.get(name), getattr(g, name)
        if a is None or b is None:
            continue
        err = np.abs(a[y0:y1, x0:x1].astype(np.float64) - b)
        if err.ndim == 3:
            err = err.max(axis=2)
        if same is not None:
            err = err[same]
        err = err[np.isfinite(err)]
        if err.size:
            worst = max(worst, float(err.max()))
    return worst


def run_scene(scene: Scene, ctx, *, method="hw", golden_dir=None, check_golden=True, keep=False,
              ref=None, fill_rule=_golden.FILL_RULE, clip_defect=None,
              sample_persp_defect=None):
    """Check one scene rendered with ``method``. Returns (SceneResult, artifacts) where
    artifacts is a :class:`SceneArtifacts` when ``keep`` (for reports) else None. ``ref``: the
    scene's reference raster when already computed (from
    :func:`glraster.conformance.golden.reference_for` with ``fill_rule``). ``fill_rule``:
    the driver's rule the coverage is judged by (a FillRule, "llvmpipe", or None for the
    edge band); the golden is checked against llvmpipe's reference either way.
    Multisample scenes render with their ``samples`` and ``interpolation`` and are judged
    per sample against a reference at the positions the driver reports (the probe
    ``sample_positions`` checks those against the ones it uses)."""
    res = SceneResult(scene.name, scene.description, tuple(scene.resolution), len(scene.tri),
                      scene.samples, scene.interpolation)
    artifacts = None
    try:
        t = time.perf_counter()
        multisample = {"samples": scene.samples, "interpolation": scene.interpolation} \
            if scene.samples > 1 else {}
        gpu = rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=scene.outputs,
                        method=method, **multisample)
        res.timings["gpu"] = time.perf_counter() - t
        t = time.perf_counter()
        if ref is not None and scene.samples > 1 \
                and not np.array_equal(ref.sample_positions, gpu.sample_positions):
            ref = None
        ref = ref if ref is not None else _golden.reference_for(
            scene, fill_rule=fill_rule,
            sample_positions=gpu.sample_positions if scene.samples > 1 else None)
        res.timings["reference"] = time.perf_counter() - t
        t = time.perf_counter()
        ev = evaluate(gpu, ref, ctx, error_model(method, ctx, clip_defect, sample_persp_defect))
        res.report, res.nonfinite, res.waived = ev.report, ev.nonfinite, ev.waived
        res.failures = ev.failures
        res.timings["compare"] = time.perf_counter() - t
        if check_golden:
            t = time.perf_counter()
            golden_ref = ref if _is_llvmpipe_rule(fill_rule) else None  # None: recomputed
            res.golden = _golden.check_scene(scene, ref=golden_ref, directory=golden_dir)
            if res.golden.ok:
                res.golden_max_error = _golden_max_error(gpu, res.golden.raster)
            else:
                res.failures.append(f"golden: {res.golden.message}")
            res.golden.raster = None  # do not keep the arrays around
            res.timings["golden"] = time.perf_counter() - t
        res.status = "fail" if res.failures else "pass"
        if keep:
            artifacts = SceneArtifacts(gpu, ref, ev.report)
    except Exception as exc:  # a scene that crashes must not stop the run
        res.status = "error"
        res.error = f"{type(exc).__name__}: {exc}"
        res.failures.append(res.error)
    return res, artifacts


def _is_llvmpipe_rule(fill_rule) -> bool:
    from glraster.geometry.fill_rule import LLVMPIPE
    return fill_rule == "llvmpipe" or fill_rule == LLVMPIPE


def _reference_rule(detection):
    """The fill rule the references are made with: the detected one (llvmpipe's as
    "llvmpipe", so that the goldens' reference is shared), None when unidentified."""
    if detection is None:
        return _golden.FILL_RULE
    if detection.rule is None:
        return None
    return "llvmpipe" if _is_llvmpipe_rule(detection.rule) else detection.rule


def _cost(scene: Scene) -> float:
    h, w = scene.resolution
    return h * w + 20.0 * len(scene.tri)


def run_mutants(ctx, candidates, references, mutant_list=None, progress=None, probes=None,
                rules=None, model=None):
    """Run the control and each mutant over ``candidates`` (scenes the real shaders
    passed), cheapest first, using ``references`` (name -> reference raster). A mutant no
    scene catches is run through the probes; one that fails a probe the real shaders
    passed (``probes``: their ProbeResults) is caught by that probe ("probe NAME"), and
    one that draws the rule probe scene unlike the real shaders (``rules``: their
    RuleDetection) by "probe rules" (where coverage is judged by the edge band, a changed
    tie rule shows nowhere else).

    ``model``: the error model of the real shaders' run (default: the context's).

    Returns (list of MutantResult, list of scene names where the control failed)."""
    model = model if model is not None else error_model("hw", ctx)
    order = sorted(candidates, key=_cost)
    control_failures = []
    for scene in order:
        gpu = _mutants.render(None, scene.pos, scene.tri, scene.resolution, ctx=ctx,
                              outputs=scene.outputs, samples=scene.samples,
                              interpolation=scene.interpolation)
        if not evaluate(gpu, references[scene.name], ctx, model).ok:
            control_failures.append(scene.name)
    results = []
    for i, m in enumerate(mutant_list if mutant_list is not None else _mutants.MUTANTS):
        if progress:
            progress(i, m.name)
        mr = MutantResult(m.name, m.fault)
        t = time.perf_counter()
        for scene in order:
            mr.scenes_tried += 1
            try:
                gpu = _mutants.render(m, scene.pos, scene.tri, scene.resolution, ctx=ctx,
                                      outputs=scene.outputs, samples=scene.samples,
                                      interpolation=scene.interpolation)
            except Exception as exc:
                mr.error = f"{type(exc).__name__}: {exc}"
                break
            failures = evaluate(gpu, references[scene.name], ctx, model).failures
            if failures:
                mr.caught_by = scene.name
                mr.reason = "; ".join(failures)
                break
        if not mr.caught and not mr.error and probes:
            passed_before = {p.name for p in probes if p.status == "pass"}
            for p in _probes.run(ctx, _probes.mutant_render(m, ctx)):
                if p.status == "fail" and p.name in passed_before:
                    mr.caught_by, mr.reason = f"probe {p.name}", p.diagnosis
                    break
        if not mr.caught and not mr.error and rules is not None and rules.ids is not None:
            scene = _rules.probe_scene()
            ids = _mutants.render(m, scene.pos, scene.tri, scene.resolution, ctx=ctx,
                                  outputs=("tri_id",)).tri_id
            differ = int((ids != rules.ids).sum())
            if differ:
                mr.caught_by = "probe rules"
                mr.reason = (f"{differ} pixels of the rule probes differ from the real "
                             "shaders' (tie rule or snapping changed)")
        mr.seconds = time.perf_counter() - t
        results.append(mr)
    return results, control_failures


@dataclass
class DriverSetup:
    """What a check run measures on a driver before its scenes (:func:`setup_driver`).

    rules       : the RuleDetection of :mod:`glraster.conformance.rules` (None: not run)
    probes      : the ProbeResults of :mod:`glraster.conformance.probes` (empty: not run)
    rule        : the fill rule the references are made with (see :func:`run_scene`)
    clip_defect : whether Mesa's noperspective clipper defect is waived (None: llvmpipe only)
    sample_persp_defect : the same for the multisampled perspective defect (the
                  ``sample_perspective`` probe; ErrorModel.center_one_over_w)
    renderer, max_samples, sample_counts : the driver's (Context), which decide the
                  multisample scenes' sample counts (:func:`with_sample_counts`)
    """

    rules: object = None
    probes: list = field(default_factory=list)
    rule: object = _golden.FILL_RULE
    clip_defect: object = None
    sample_persp_defect: object = None
    renderer: str = ""
    max_samples: int = 1
    sample_counts: tuple = (1,)


def setup_driver(ctx, probes=True) -> DriverSetup:
    """Detect the driver's rules and run the probes on ``ctx`` (``probes=False``: neither;
    coverage is then judged by llvmpipe's rule). Every scene of a run on this driver is
    judged with the returned setup, whichever process renders it."""
    setup = DriverSetup()
    if probes:
        setup.rules = _rules.detect_on(ctx)
        setup.probes = _probes.run(ctx)
    setup.rule = _reference_rule(setup.rules)
    # Mesa's noperspective clipper defect and the multisampled perspective defect, where a
    # probe measured them, are waived (counted) on every driver that has them, as on
    # llvmpipe (None without probes: llvmpipe only)
    setup.clip_defect = _waived(setup.probes, "noperspective_clip")
    setup.sample_persp_defect = _waived(setup.probes, "sample_perspective")
    setup.renderer, setup.max_samples = ctx.renderer, ctx.max_samples
    setup.sample_counts = tuple(ctx.sample_counts)
    return setup


def _waived(probes, name: str):
    """Whether the defect probe ``name`` found is waived on this driver: True where the probe
    is "known", False where it passed, None where it did not run (llvmpipe's facts apply)."""
    probe = next((p for p in probes if p.name == name), None)
    return None if probe is None or probe.status not in ("pass", "known") \
        else probe.status == "known"


def explain(probes, scene, res) -> None:
    """Name the failed probes whose defect can explain ``res`` (a SceneResult of ``scene``):
    in ``res.explained_by`` and in each such probe's ``explains``."""
    failed = [p for p in probes if p.failed]
    res.explained_by = [(p.name, p.diagnosis) for p in failed if p.explains_scene(scene, res)]
    for p in failed:
        if p.explains_scene(scene, res):
            p.explains.append(scene.name)


def run(ctx, names=None, *, method="hw", golden_dir=None, check_golden=True, mutants=False,
        mutant_pattern=None, on_scene=None, progress=None, references=None,
        mutant_scenes=None, probes=True) -> CheckResult:
    """Check the scenes ``names`` (default: the whole catalog) on ``ctx``, rendered with
    ``method`` (one of :data:`glraster.gpu.rasterize.METHODS`). The mutants are faults injected
    into the "hw" shaders, so ``mutants`` requires method "hw".

    references: optional dict name -> reference raster, used and filled in (scenes up to
    REFERENCE_CACHE_PIXELS), so that several runs (e.g. one per backend) share them.

    on_scene(result, artifacts): called after each scene with its SceneResult and its
    :class:`SceneArtifacts` (None when the scene raised; e.g. to write report images);
    artifacts are dropped after.
    progress(index, total, label): called before each step.
    probes: detect the driver's rules and run the probes first (False: judge coverage by
    llvmpipe's rule, as without detection).
    mutant_scenes: optional scene names the mutant pass may also use beyond ``names`` (a
    sharded run checks only its share of the catalog, but its mutants need every scene
    that can catch them): they get a reference and the control run of the real shaders,
    and are not reported as scenes.
    """
    if method not in METHODS:
        raise ArgumentError("method", f"method must be one of {sorted(METHODS)}, got {method!r}")
    if mutants and method != "hw":
        raise ArgumentError(
            "mutants", f"mutants are faults in the hw shaders: method must be 'hw' with "
                       f"mutants, got {method!r}")
    t0 = time.perf_counter()
    names = list(names) if names is not None else list_scenes()
    out = CheckResult(ctx.backend, ctx.renderer, ctx.gl_version, method)
    explicit = golden_dir is not None or os.environ.get("GLRASTER_GOLDEN_DIR")
    if check_golden and not explicit and not _golden.golden_available():
        # An installed package has no golden/ folder: compare with the reference only and
        # say so. A folder named explicitly must exist (a missing file fails its scene).
        check_golden = False
        out.notes.append(f"no golden folder at {_golden.golden_dir()}: golden comparison "
                         "skipped (set GLRASTER_GOLDEN_DIR or --golden-dir)")
    if probes and progress:
        progress(0, len(names), "rules and probes")
    setup = setup_driver(ctx, probes=probes)
    out.rules, out.probes = setup.rules, setup.probes
    rule, clip_defect = setup.rule, setup.clip_defect
    key = (lambda n: n) if rule == _golden.FILL_RULE else (lambda n: (n, str(rule)))
    mutant_refs = {}
    passed = []
    mutant_list = _mutants.select(mutant_pattern) if mutants else []
    if len(ctx.sample_counts) < 2 and any(m.multisample_only for m in mutant_list):
        skipped = [m.name for m in mutant_list if m.multisample_only]
        mutant_list = [m for m in mutant_list if not m.multisample_only]
        out.notes.append(f"mutants {', '.join(skipped)} not run: their faults need "
                         f"multisampling, which {ctx.renderer} does not offer")
    scenes = with_sample_counts([load_scene(n) for n in names], setup, out.notes, method)
    total = len(scenes) + (len(mutant_list) if mutants else 0)
    for i, scene in enumerate(scenes):
        name = scene.name
        if progress:
            progress(i, total, name)
        cached = references.get(key(name)) if references is not None else None
        # goldens hold the catalog's sample count; other counts are judged by the reference
        own_count = name in names
        res, art = run_scene(scene, ctx, method=method, golden_dir=golden_dir,
                             check_golden=check_golden and own_count,
                             keep=bool(on_scene) or mutants or references is not None,
                             ref=cached, fill_rule=rule, clip_defect=clip_defect,
                             sample_persp_defect=setup.sample_persp_defect)
        explain(setup.probes, scene, res)
        h, w = scene.resolution
        if references is not None and art is not None and h * w <= REFERENCE_CACHE_PIXELS:
            references[key(name)] = art.ref
        out.scenes.append(res)
        if on_scene:
            on_scene(res, art)
        if mutants and res.ok and art is not None and h * w <= REFERENCE_CACHE_PIXELS:
            mutant_refs[name] = art.ref
            passed.append(scene)
        del art
    if mutants and mutant_scenes:
        for name in mutant_scenes:
            if name in names:
                continue
            scene = load_scene(name)
            h, w = scene.resolution
            if scene.samples > 1 and scene.samples not in ctx.sample_counts:
                continue
            if h * w <= REFERENCE_CACHE_PIXELS:
                cached = references.get(key(name)) if references is not None else None
                positions = _driver_positions(ctx, scene.samples) if scene.samples > 1 else None
                mutant_refs[name] = (cached if cached is not None
                                     else _golden.reference_for(scene, fill_rule=rule,
                                                                sample_positions=positions))
                passed.append(scene)
    if mutants:
        def mprog(j, label):
            if progress:
                progress(len(names) + j, total, f"mutant {label}")
        out.mutants, out.control_failures = run_mutants(
            ctx, passed, mutant_refs, mutant_list, mprog, out.probes, out.rules,
            model=error_model("hw", ctx, clip_defect, setup.sample_persp_defect))
    if progress:
        progress(total, total, "done")
    out.seconds = time.perf_counter() - t0
    return out


def _driver_positions(ctx, samples: int) -> np.ndarray:
    """(S, 2) the sample positions the driver reports for ``samples``."""
    full = np.array([[-1, -1, 0, 1], [3, -1, 0, 1], [-1, 3, 0, 1]], np.float32)
    return rasterize(full, [[0, 1, 2]], (1, 1), ctx=ctx, outputs=("tri_id",),
                     samples=samples).sample_positions


def with_sample_counts(scenes, driver, notes, method="hw") -> list:
    """The scenes to run: single-sample ones as they are, each multisample one at every
    sample count the driver offers (``driver.sample_counts``, of a Context or a
    :class:`DriverSetup`; the catalog's count keeps the scene's name, others are
    ``<name>@<S>x``, which :func:`load_scene` reads back); none where the driver offers no
    multisampling, nor those whose interpolation ``method`` does not offer (said in
    ``notes``)."""
    counts = [s for s in driver.sample_counts if s > 1]
    offered = METHODS[method].interpolations
    out, dropped, unoffered = [], [], []
    for scene in scenes:
        if scene.samples == 1:
            out.append(scene)
        elif not counts:
            dropped.append(scene.name)
        elif scene.interpolation not in offered:
            unoffered.append(scene.name)
        else:
            out += [with_samples(scene, s) for s in counts]
    if dropped:
        notes.append(f"{len(dropped)} multisample scenes not run: {driver.renderer} offers no "
                     f"multisampling (GL_MAX_SAMPLES {driver.max_samples})")
    if unoffered:
        notes.append(f"{len(unoffered)} multisample scenes not run: method {method!r} offers "
                     f"interpolation {offered} only ({', '.join(unoffered)})")
    return out


def shard_scenes(names, index: int, count: int) -> list:
    """The scenes of shard ``index`` (1-based) of ``count``: ``names`` split so that the
    shards' costs (pixels + 20 x triangles per scene) are balanced, by longest first onto
    the least loaded shard. Deterministic: every CI runner computes the same split from
    the same catalog, each scene lands in exactly one shard. Returned in catalog order."""
    if isinstance(index, bool) or isinstance(count, bool) or not (1 <= int(index) <= int(count)):
        raise ArgumentError("shard", f"shard must be I/N with 1 <= I <= N, got {index}/{count}")
    names = list(names)
    loads = [0.0] * int(count)
    owner = {}
    for name in sorted(names, key=lambda n: (-_cost(load_scene(n)), names.index(n))):
        k = min(range(int(count)), key=lambda j: (loads[j], j))
        loads[k] += _cost(load_scene(name))
        owner[name] = k
    return [n for n in names if owner[n] == int(index) - 1]


def to_dict(result: CheckResult) -> dict:
    """A :class:`CheckResult` as JSON-able data (the reports' figures, no arrays)."""
    def values(rep):
        if rep is None:
            return {}
        return {n: {"max": v.max, "p999": v.p999, "mean": v.mean, "worst_ratio": v.worst_ratio,
                    "over_tolerance": v.over_tolerance, "waived": v.waived}
                for n, v in rep.values.items()}

    scenes = []
    for s in result.scenes:
        rep = s.report
        scenes.append({
            "name": s.name, "description": s.description, "status": s.status,
            "resolution": list(s.resolution), "triangles": s.triangles,
            "samples": s.samples, "interpolation": s.interpolation,
            "failures": list(s.failures), "error": s.error, "seconds": s.seconds,
            "covered": rep.covered_gpu if rep else 0,
            "coverage_mismatch": rep.coverage_mismatch if rep else 0,
            "tri_id_mismatch": rep.tri_id_mismatch if rep else 0,
            "nonfinite": s.nonfinite, "waived": dict(s.waived), "values": values(rep),
            "golden": None if s.golden is None else ("exact" if s.golden.ok else "diff"),
            "golden_max_error": s.golden_max_error,
        })
    out = {"ok": result.ok, "driver": result.driver, "backend": result.backend,
           "renderer": result.renderer,
           "gl_version": result.gl_version, "method": result.method,
           "shard": f"{result.shard[0]}/{result.shard[1]}" if result.shard else None,
           "seconds": result.seconds, "passed": sum(s.ok for s in result.scenes),
           "scenes": scenes, "notes": list(result.notes), "mutants": None,
           "control_failures": list(result.control_failures)}
    if result.mutants is not None:
        out["mutants"] = [{"name": m.name, "fault": m.fault, "caught_by": m.caught_by,
                           "reason": m.reason, "scenes_tried": m.scenes_tried, "error": m.error,
                           "seconds": m.seconds} for m in result.mutants]
    return out


def format_table(result: CheckResult) -> str:
    """The per-scene table (and the mutant table when present) as plain text."""
    lines = [f"backend {result.backend} | {result.renderer} | GL {result.gl_version} | "
             f"method {result.method}", ""]
    if result.rules is not None:
        lines[1:1] = [result.rules.summary()]
    if result.probes:
        lines[-1:-1] = [f"probes ({sum(p.ok for p in result.probes)}/{len(result.probes)} ok):"] \
            + [f"  {line}" for p in result.probes for line in p.line().split("\n")]
    hdr = (f"{'scene':<28}{'HxW':>11}{'samples':>15}{'tris':>8}{'covered':>9}{'cov!':>6}{'id!':>5}"
           f"{'persp e/tol':>12}{'screen e/tol':>13}{'depth e/tol':>12}{'golden':>8}"
           f"{'secs':>7}  status")
    lines.append(hdr)
    lines.append("-" * len(hdr))
    for s in result.scenes:
        h, w = s.resolution
        rep = s.report
        def ratio(n):
            if rep is None or n not in rep.values:
                return "-"
            return f"{rep.values[n].worst_ratio:.3f}"
        gold = "-" if s.golden is None else ("exact" if s.golden.ok else "DIFF")
        status = s.status.upper()
        if s.waived:
            status += f" (waived {sum(s.waived.values())} px)"
        lines.append(
            f"{s.name:<28}{f'{h}x{w}':>11}{s.sampling:>15}{s.triangles:>8}"
            f"{(rep.covered_gpu if rep else 0):>9}{(rep.coverage_mismatch if rep else 0):>6}"
            f"{(rep.tri_id_mismatch if rep else 0):>5}{ratio('persp'):>12}{ratio('screen'):>13}"
            f"{ratio('depth'):>12}{gold:>8}{s.seconds:>7.2f}  {status}")
        for f in s.failures:
            lines.append(f"    - {f}")
        for probe, diagnosis in s.explained_by:
            lines.append(f"    explained by probe {probe}: {diagnosis}")
    n_ok = sum(s.ok for s in result.scenes)
    lines.append("")
    lines.append(f"{n_ok}/{len(result.scenes)} scenes pass")
    if result.mutants is not None:
        lines.append("")
        lines.append(f"{'mutant':<24}{'caught by':<28}{'tried':>6}{'secs':>7}  reason")
        for m in result.mutants:
            who = m.caught_by or ("ERROR" if m.error else "ESCAPED")
            lines.append(f"{m.name:<24}{who:<28}{m.scenes_tried:>6}{m.seconds:>7.2f}  "
                         f"{(m.reason or m.error)[:90]}")
        caught = sum(m.caught for m in result.mutants)
        lines.append(f"{caught}/{len(result.mutants)} mutants caught; control (real shaders "
                     f"via the mutant path): "
                     + ("no false alarm" if not result.control_failures
                        else f"FAILED on {', '.join(result.control_failures)}"))
    lines += [f"note: {n}" for n in result.notes]
    lines.append(f"total {result.seconds:.1f} s: " + ("PASS" if result.ok else "FAIL"))
    return "\n".join(lines)
