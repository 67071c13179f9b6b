"""Connecting to Ray: a local cluster sized to this machine, or a running one by address.

Placement is by Ray resources. Every node advertises one custom resource per OpenGL driver
its GL comes up with, ``driver:<name>`` (``driver:llvmpipe``, ``driver:softpipe``,
``driver:radeonsi``, ...), as found by ``glraster info`` (:func:`node_resources`). An actor
asks for one unit of the driver it needs and one CPU, so Ray puts it on a node that has the
driver; a GPU driver's actor also asks for a GPU.

A real node is started with its resources::

    ray start --address HEAD:6379 --resources "$(glraster info --ray-resources)"

Without an address (no ``--ray ADDRESS``, no ``RAY_ADDRESS``) :func:`connect` starts a local
cluster with ``ray.init()`` on all of this machine's CPUs, probes the Mesa drivers
(:data:`SIMULATED_DRIVERS`) and advertises those that come up, so one machine runs a
several-driver fleet: each actor selects its driver with ``GALLIUM_DRIVER`` in its
``runtime_env`` (:func:`driver_env`). The local object store is kept small
(:data:`OBJECT_STORE_BYTES`, ``GLRASTER_RAY_OBJECT_STORE_MB``): tasks pass scene names and
file paths, and results (reports, manifests) are small; rasters go to shard files.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

from glraster.errors import ArgumentError

# Mesa's gallium drivers that any machine with Mesa can select by GALLIUM_DRIVER; zink
# (GL on Vulkan) comes up only where a Vulkan driver does.
SIMULATED_DRIVERS = ("llvmpipe", "softpipe", "zink")

# Object store of a local cluster: small, beside other work on the machine.
OBJECT_STORE_BYTES = int(os.environ.get("GLRASTER_RAY_OBJECT_STORE_MB", "128")) << 20

RESOURCE_PREFIX = "driver:"

# Seconds a driver probe (a `glraster info` subprocess) may take.
PROBE_TIMEOUT_S = 120


def driver_name(renderer: str, vendor: str = "") -> str:
    """The driver's short name from GL_RENDERER / GL_VENDOR: "llvmpipe (LLVM 15.0.6, 256
    bits)" -> "llvmpipe", "softpipe" -> "softpipe", "zink (...)" -> "zink", "AMD Radeon RX
    6800 (radeonsi, navi21, ...)" -> "radeonsi", an NVIDIA renderer -> "nvidia", "Mesa Intel(R)
    ..." -> "iris"; otherwise
    the renderer's first word, lower case."""
    text = renderer.strip()
    low = text.lower()
    for name in SIMULATED_DRIVERS:
        if low.startswith(name):
            return name
    if "nvidia" in (vendor or "").lower() or low.startswith("nvidia"):
        return "nvidia"
    if low.startswith("mesa intel"):  # Mesa's Intel renderers name no driver (iris, Gen8+)
        return "iris"
    inner = re.search(r"\(([A-Za-z0-9_]+)[,)]", text)
    if inner and inner.group(1).lower() not in ("llvm", "tm", "r"):
        return inner.group(1).lower()
    word = re.match(r"[A-Za-z0-9_]+", text)
    return word.group(0).lower() if word else "unknown"


def driver_env(driver: str) -> dict:
    """The environment an actor of ``driver`` starts with: GALLIUM_DRIVER for Mesa's gallium
    drivers (a node's default would be llvmpipe), nothing for a hardware driver."""
    if driver in SIMULATED_DRIVERS:
        env = {"GALLIUM_DRIVER": driver}
        if driver == "zink":
            env["MESA_LOADER_DRIVER_OVERRIDE"] = "zink"
        return env
    return {}


def check_driver_names(drivers) -> list:
    """``drivers`` ("llvmpipe,softpipe" or a list) as a list of names; ValueError on an
    empty list or a name that is not a driver name."""
    if isinstance(drivers, str):
        drivers = [d.strip() for d in drivers.split(",")]
    drivers = list(drivers)
    if not drivers or any(not d for d in drivers):
        raise ArgumentError(
            "drivers", f"drivers must be a comma-separated list of driver names, got "
                       f"{','.join(drivers)!r}")
    for d in drivers:
        if not re.fullmatch(r"[a-z0-9_]+", d):
            raise ArgumentError(
                "drivers", f"drivers: {d!r} is not a driver name (lower case letters, digits, "
                           "_; e.g. llvmpipe, softpipe, zink, radeonsi)")
    if len(set(drivers)) != len(drivers):
        raise ArgumentError("drivers", f"drivers: {','.join(drivers)!r} names a driver twice")
    return drivers


def probe_driver(driver: str | None, backend: str | None = None) -> dict:
    """Whether GL comes up with ``driver`` (None: the node's default) in a fresh process
    (Mesa reads GALLIUM_DRIVER once, when it loads). Returns ``{"driver", "ok", "facts"
    (glraster info --json), "error"}``; a driver whose context names another renderer (Mesa
    falls back to llvmpipe when zink finds no Vulkan device) is not ok."""
    env = dict(os.environ)
    env.update(driver_env(driver) if driver else {})
    cmd = [sys.executable, "-m", "glraster.cli", "info", "--json"]
    if backend:
        cmd += ["--backend", backend]
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True,
                              timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"driver": driver, "ok": False, "facts": None,
                "error": f"glraster info did not finish in {PROBE_TIMEOUT_S} s"}
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        return {"driver": driver, "ok": False, "facts": None,
                "error": lines[-1] if lines else f"glraster info exited {proc.returncode}"}
    facts = json.loads(proc.stdout)
    found = driver_name(facts["renderer"], facts.get("vendor", ""))
    if driver and found != driver:
        return {"driver": driver, "ok": False, "facts": facts,
                "error": f"asked for {driver}, GL came up as {facts['renderer']!r}"}
    return {"driver": driver or found, "ok": True, "facts": facts, "error": ""}


def node_resources(drivers=None, backend: str | None = None) -> dict:
    """The custom resources this node advertises: ``{"driver:<name>": CPUs}`` for every
    driver of ``drivers`` (default: the node's own driver and :data:`SIMULATED_DRIVERS`)
    whose GL comes up here. Probes run in parallel subprocesses."""
    names = list(drivers) if drivers is not None else [None, *SIMULATED_DRIVERS]
    if not names:
        return {}
    with ThreadPoolExecutor(max_workers=len(names)) as pool:
        probes = list(pool.map(lambda d: probe_driver(d, backend), names))
    cpus = os.cpu_count() or 1
    return {RESOURCE_PREFIX + p["driver"]: float(cpus) for p in probes if p["ok"]}


def _ray():
    try:
        import ray
    except ModuleNotFoundError:
        raise ModuleNotFoundError("glraster.cluster needs Ray: pip install 'glraster[ray]'",
                                  name="ray") from None
    return ray


def connect(address: str | None = None, drivers=None, *, num_cpus: int | None = None):
    """Connect to Ray and return the ``ray`` module.

    address : a cluster's address ("ray://host:10001", "host:6379", "auto"); None: the
        ``RAY_ADDRESS`` environment variable, else a new local cluster on this machine's CPUs
        (``num_cpus`` to use fewer) advertising the drivers of ``drivers`` (default
        :data:`SIMULATED_DRIVERS`) that come up here.
    An already connected session is reused as it is.
    """
    ray = _ray()
    if ray.is_initialized():
        return ray
    address = address or os.environ.get("RAY_ADDRESS") or None
    # Workers need glraster importable exactly as here (a checkout run with PYTHONPATH).
    import logging

    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address:
        ray.init(address=address, **quiet)
        return ray
    names = list(drivers) if drivers is not None else list(SIMULATED_DRIVERS)
    resources = node_resources(names)
    ray.init(num_cpus=num_cpus or os.cpu_count() or 1, resources=resources,
             object_store_memory=OBJECT_STORE_BYTES, include_dashboard=False, **quiet)
    return ray


def shutdown() -> None:
    """Disconnect from Ray (and stop the local cluster :func:`connect` started)."""
    ray = _ray()
    if ray.is_initialized():
        ray.shutdown()


def driver_nodes(ray) -> dict:
    """``{driver: [node, ...]}`` over the cluster's live nodes, node = ``{"id", "name",
    "address", "cpus", "gpus", "slots"}``; slots: how many actors of that driver it takes
    (its ``driver:<name>`` resource)."""
    out: dict = {}
    for n in ray.nodes():
        if not n.get("Alive"):
            continue
        res = n.get("Resources", {})
        for key, amount in res.items():
            if key.startswith(RESOURCE_PREFIX):
                out.setdefault(key[len(RESOURCE_PREFIX):], []).append({
                    "id": n["NodeID"], "name": n.get("NodeManagerHostname", n["NodeID"][:8]),
                    "address": n.get("NodeManagerAddress", ""),
                    "cpus": int(res.get("CPU", 0)), "gpus": int(res.get("GPU", 0)),
                    "slots": int(amount)})
    return out
