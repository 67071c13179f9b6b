"""``glraster check --ray``: the conformance catalog x methods x drivers as Ray tasks.

The run, on the head (the process that calls :func:`run_check`):

1. connect (:func:`glraster.cluster.runtime.connect`) and list the nodes that advertise each
   requested driver (``driver:<name>`` resources);
2. start :class:`glraster.cluster.workers.GLWorker` actors on every such node (as many per
   node and driver as its CPUs allow); an actor whose GL does not come up is reported with
   its node's name and left out;
3. per driver, one actor measures the rules and runs the probes once
   (:func:`glraster.conformance.check.setup_driver`); every scene of that driver is judged
   with that setup, so each driver's verdicts are those of its own sequential
   ``glraster check``;
4. one task per (driver, method, scene), one at a time per actor, on the actors of its
   driver; results are kept by that key, so a retried task is counted once;
5. one :class:`glraster.conformance.check.CheckResult` per (driver, method), in catalog order:
   merged JUnit (every case named ``...check.<driver>.<backend>[.<method>]``) and an HTML
   report with a driver matrix.

Multisample scenes run at every sample count the driver offers (:func:`_plan`, as the
sequential check picks them); see docs/cluster.md.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

from glraster.cluster import runtime
from glraster.cluster.workers import MAX_TASK_RETRIES, remote_worker
from glraster.errors import ArgumentError

# Seconds an actor may take to start and make its context.
START_TIMEOUT_S = 300
# Times a task is moved to another actor when its actor's node is lost (not: when its
# worker process crashed; Ray restarts that one and retries, MAX_TASK_RETRIES).
MAX_MOVES = 2


@dataclass
class NodeReport:
    """One actor slot: ``driver`` on node ``node`` (host name) and whether GL came up."""

    driver: str
    node: str
    ok: bool
    error: str = ""
    renderer: str = ""


@dataclass
class FleetResult:
    """A fleet check: ``runs`` = [(driver, method, CheckResult)], driver-major in the
    requested order; ``nodes``: every actor slot's report; ``missing``: driver -> why no
    node ran it (no node advertises it, or GL came up on none)."""

    runs: list = field(default_factory=list)
    nodes: list = field(default_factory=list)
    missing: dict = field(default_factory=dict)
    seconds: float = 0.0
    tasks: int = 0
    retried: int = 0  # tasks that crashed their worker every time (reported as errors)
    images: dict = field(default_factory=dict)  # (driver, method, scene) -> (info, {file: PNG})

    @property
    def ok(self) -> bool:
        return bool(self.runs) and not self.missing and all(r.ok for _, _, r in self.runs)


def _scene_error(name: str, message: str):
    from glraster.conformance.check import SceneResult
    from glraster.conformance.scenes import load_scene

    scene = load_scene(name)
    res = SceneResult(scene.name, scene.description, tuple(scene.resolution), len(scene.tri))
    res.status, res.error = "error", message
    res.failures.append(message)
    return res


def _actor_slots(nodes_by_driver, drivers):
    """[(driver, node, num_cpus, num_gpus)]: per node, its CPUs shared by the requested
    drivers it has; at least one actor per (node, driver), never more CPUs asked than the
    node has; an actor of a hardware driver on a node with GPUs takes one GPU."""
    per_node: dict = {}
    for d in drivers:
        for node in nodes_by_driver.get(d, []):
            per_node.setdefault(node["id"], (node, []))[1].append(d)
    slots = []
    for node, ds in per_node.values():
        cpus = max(node["cpus"], 1)
        count = max(1, cpus // len(ds))
        share = min(1.0, cpus / (len(ds) * count))
        for d in ds:
            n = min(count, max(1, node["slots"]))
            gpus = 0.0
            if d not in runtime.SIMULATED_DRIVERS and node["gpus"]:  # a GPU's driver
                n = min(n, node["gpus"])
                gpus = 1.0
            slots += [(d, node, share, gpus)] * n
    return slots


def run_check(names=None, *, drivers=None, methods=("hw",), address=None, backend=None,
              golden_dir=None, check_golden=True, probes=True, images=False, progress=None,
              on_nodes=None) -> FleetResult:
    """Check the catalog scenes ``names`` (default: all) with every method of ``methods`` on
    every driver of ``drivers`` (default: every driver the cluster advertises).

    address: Ray address (None: ``RAY_ADDRESS`` or a local cluster).
    backend: the GL backend of every worker (None: each node's ``GLRASTER_BACKEND`` or auto).
    images: bring back each scene's report images (for :func:`write_html`).
    progress(i, total, label): after each finished task.
    on_nodes(list of NodeReport): once the actors are up (e.g. to print them).
    """
    from glraster.conformance.check import CheckResult, explain
    from glraster.conformance.scenes import list_scenes, load_scene
    from glraster.gpu.methods import METHODS

    t0 = time.perf_counter()
    names = list(names) if names is not None else list_scenes()
    methods = list(methods)
    for m in methods:
        if m not in METHODS:
            raise ArgumentError(
                "methods", f"methods: {m!r} is not a method; known: {', '.join(METHODS)}")
    if drivers is not None:
        drivers = runtime.check_driver_names(drivers)
    ray = runtime.connect(address, drivers)
    nodes_by_driver = runtime.driver_nodes(ray)
    if drivers is None:
        drivers = sorted(nodes_by_driver)
    out = FleetResult()
    for d in drivers:
        if d not in nodes_by_driver:
            out.missing[d] = (f"no node advertises driver:{d} (its GL did not come up, or "
                              f"the node was started without it)")
    slots = _actor_slots(nodes_by_driver, drivers)
    actors = []
    for d, node, share, gpus in slots:
        actors.append((d, node, remote_worker(ray, d, backend=backend, node_id=node["id"],
                                              num_cpus=share, gpus=gpus)))
    live: dict = {d: [] for d in drivers}
    facts: dict = {}
    describe = [a.describe.remote() for _, _, a in actors]
    for (d, node, actor), ref in zip(actors, describe):
        try:
            info = ray.get(ref, timeout=START_TIMEOUT_S)
        except Exception as exc:  # the actor could not even start
            out.nodes.append(NodeReport(d, node["name"], False, f"{type(exc).__name__}: {exc}"))
            ray.kill(actor)
            continue
        out.nodes.append(NodeReport(d, info["node"], info["ok"], info["error"],
                                    info["renderer"] or ""))
        if info["ok"]:
            live[d].append(actor)
            facts.setdefault(d, info)
        else:
            ray.kill(actor)
    if on_nodes:
        on_nodes(out.nodes)
    setups = {}
    for d in drivers:
        if d in out.missing:
            continue
        if not live[d]:
            bad = sorted({f"{n.node}: {n.error}" for n in out.nodes if n.driver == d})
            out.missing[d] = "GL did not come up on any node: " + "; ".join(bad)
            continue
    setup_refs = {d: live[d][0].setup.remote(probes) for d in drivers if live[d]}
    for d, ref in setup_refs.items():
        try:
            setups[d] = ray.get(ref)
        except Exception as exc:
            out.missing[d] = f"the rules and probes could not run: {type(exc).__name__}: {exc}"
    plans = {(d, m): _plan(names, setups[d], m) for d in setups for m in methods}
    results, pictures = _schedule(ray, plans, setups, live, golden_dir, check_golden,
                                  images, progress, out)
    for d in drivers:
        if d not in setups:
            continue
        info = facts[d]
        for k, m in enumerate(methods):
            setup = copy.deepcopy(setups[d])
            r = CheckResult(info["backend"], info["renderer"], info["gl_version"], m, driver=d)
            r.rules, r.probes = setup.rules, setup.probes
            scene_names, r.notes = plans[(d, m)]
            for name in scene_names:
                res = results[(d, m, name)]
                explain(setup.probes, load_scene(name), res)
                r.scenes.append(res)
            r.seconds = sum(s.seconds for s in r.scenes)
            out.runs.append((d, m, r))
    out.images = pictures
    for _, _, actor in actors:
        ray.kill(actor)
    out.seconds = time.perf_counter() - t0
    return out


def _plan(names, setup, method):
    """The scene names one (driver, method) run checks, and its notes: the catalog scenes
    ``names``, each multisample one at every sample count the driver offers
    (``<name>@<S>x``), exactly as :func:`glraster.conformance.check.run` picks them."""
    from glraster.conformance.check import with_sample_counts
    from glraster.conformance.scenes import load_scene

    notes: list = []
    scenes = with_sample_counts([load_scene(n) for n in names], setup, notes, method)
    return [s.name for s in scenes], notes


def _schedule(ray, plans, setups, live, golden_dir, check_golden, images, progress, out):
    """Run every (driver, method, scene) task of ``plans`` ({(driver, method): (scene
    names, notes)}) on the actors of its driver, one in flight per actor. Returns
    ({key: SceneResult}, {key: images})."""
    from ray.exceptions import GetTimeoutError, RayActorError, RayTaskError

    pending = {d: [(m, n) for (dd, m), (scene_names, _) in plans.items() if dd == d
                   for n in scene_names] for d in setups}
    setup_refs = {d: ray.put(setups[d]) for d in setups}  # stored once, not once per task
    moves: dict = {}
    idle = {d: list(live[d]) for d in setups}
    inflight = {}
    results, pictures = {}, {}
    total = sum(len(v) for v in pending.values())
    out.tasks = total
    done = 0
    while any(pending.values()) or inflight:
        for d in setups:
            while idle[d] and pending[d]:
                actor = idle[d].pop()
                m, n = pending[d].pop(0)
                ref = actor.check_scene.remote(n, m, setup_refs[d], golden_dir, check_golden,
                                               images)
                inflight[ref] = (d, m, n, actor)
            if pending[d] and not idle[d] and not any(v[0] == d for v in inflight.values()):
                for m, n in pending[d]:  # every actor of this driver is lost
                    results[(d, m, n)] = _scene_error(n, f"no worker of driver {d} left")
                pending[d] = []
        if not inflight:
            break
        ready, _ = ray.wait(list(inflight), num_returns=1)
        ref = ready[0]
        d, m, n, actor = inflight.pop(ref)
        key = (d, m, n)
        try:
            res, pics = ray.get(ref)
            if pics is not None:
                pictures[key] = pics
            idle[d].append(actor)
        except RayActorError as exc:
            try:  # Ray restarted the worker: the scene crashed it every time
                ray.get(actor.describe.remote(), timeout=START_TIMEOUT_S)
                idle[d].append(actor)
                res = _scene_error(n, f"the scene crashed its worker {1 + MAX_TASK_RETRIES} "
                                      f"times (driver {d}): {str(exc).splitlines()[0]}")
                out.retried += 1
            except (RayActorError, GetTimeoutError):  # the node is gone: move the task
                moves[key] = moves.get(key, 0) + 1
                if moves[key] <= MAX_MOVES:
                    pending[d].insert(0, (m, n))
                    continue
                res = _scene_error(n, f"lost {moves[key]} workers of driver {d} on this scene")
        except RayTaskError as exc:  # a bug on the worker, not in the scene's GL
            res = _scene_error(n, f"worker error: {str(exc).splitlines()[0]}")
            idle[d].append(actor)
        if key not in results:
            results[key] = res
            done += 1
            if progress:
                progress(done, total, f"{d} {m} {n}")
    return results, pictures


def run_label(driver: str, method: str) -> str:
    """The name of one (driver, method) run in reports: "softpipe", "llvmpipe-divw"."""
    return driver if method == "hw" else f"{driver}-{method}"


def to_junit(fleet: FleetResult):
    """One JUnit tree: each (driver, method) run's suites (probes once per driver), and a
    ``glraster.cluster.fleet`` suite with a case per node and driver (skipped where GL did
    not come up: the run went on without it) and an error per driver no node could run."""
    import xml.etree.ElementTree as ET

    from glraster.conformance import junit

    trees, seen = [], set()
    for d, _m, r in fleet.runs:
        tree = junit.to_xml(r)
        if d in seen:  # the probes belong to the driver, reported with its first method
            root = tree.getroot()
            for suite in root.findall("testsuite"):
                if suite.get("name") == "glraster.conformance.probes":
                    root.remove(suite)
        seen.add(d)
        trees.append(tree)
    suite = ET.Element("testsuite", name="glraster.cluster.fleet")
    errors = skipped = 0
    for k, n in enumerate(fleet.nodes):
        case = ET.SubElement(suite, "testcase", classname=f"glraster.cluster.fleet.{n.driver}",
                             name=f"{n.node}#{k}", time="0.000")
        if n.ok:
            ET.SubElement(case, "system-out").text = f"GL up: {n.renderer}"
        else:
            skipped += 1
            ET.SubElement(case, "skipped", message=f"GL did not come up on {n.node}: "
                          f"{n.error}"[:500])
    for d, why in fleet.missing.items():
        errors += 1
        case = ET.SubElement(suite, "testcase", classname=f"glraster.cluster.fleet.{d}",
                             name="driver", time="0.000")
        ET.SubElement(case, "error", message=why[:500], type="error").text = why
    suite.set("tests", str(len(fleet.nodes) + len(fleet.missing)))
    suite.set("failures", "0")
    suite.set("errors", str(errors))
    suite.set("skipped", str(skipped))
    suite.set("time", "0.000")
    root = ET.Element("testsuites")
    root.append(suite)
    trees.append(ET.ElementTree(root))
    return junit.merge(trees)


def write_html(fleet: FleetResult, directory):
    """The HTML report: ``directory/index.html`` with the driver matrix (a row per scene, a
    column per driver and method, each cell linked to that run's details in
    ``directory/<run>/index.html``), the nodes, and each run's own report. Returns the
    index path."""
    from pathlib import Path

    from glraster.conformance.html_report import HtmlReport, write_driver_matrix

    directory = Path(directory)
    columns = []
    for d, m, r in fleet.runs:
        label = run_label(d, m)
        with HtmlReport(directory / label) as report:
            for s in r.scenes:
                if (d, m, s.name) in fleet.images:
                    info, files = fleet.images[(d, m, s.name)]
                    report.add_images(s.name, info, files)
            report.finish(r)
        columns.append((label, f"{label}/index.html", r))
    nodes = [(n.driver, n.node, n.ok, n.error or n.renderer) for n in fleet.nodes]
    return write_driver_matrix(directory, columns, nodes, fleet.missing, fleet.seconds)
