"""Every endpoint of a real server on loopback, and results bit for bit as in-process."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import glraster as gr
from glraster.client import ServiceError, encode_scene
from glraster.conformance.scenes import list_scenes, load_scene
from glraster.io import exr
from glraster.service.metrics import BUCKETS

from tests.service.conftest import sample, scrape

ROOT = Path(__file__).resolve().parents[2]

# Every catalog scene the shared server accepts (its max resolution is 1024): all but
# the 4096x4096 one, whose 470 MB result would only time the transfer.
SCENES = [n for n in list_scenes() if max(load_scene(n).resolution) <= 1024]


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal shape, dtype and bytes (NaN payloads and -0.0 included)."""
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_healthz_readyz_info_openapi(server):
    with server.client() as c:
        status, _, body = c.request("GET", "/healthz")
        assert status == 200 and json.loads(body)["status"] == "alive"
        status, _, body = c.request("GET", "/readyz")
        assert status == 200 and json.loads(body)["status"] == "ready"
        info = c.info()
        assert info["driver"]["backend"] in ("egl", "osmesa")
        assert info["limits"]["max_resolution"] == 1024   # min(configured, driver's)
        assert info["limits"]["driver_max_resolution"] >= 1024
        assert [w["state"] for w in info["workers"]] == ["ready"]
        status, _, body = c.request("GET", "/openapi.json")
        assert json.loads(body)["openapi"].startswith("3.")


def test_metrics_count_known_requests(server):
    """/metrics, parsed by prometheus_client: the counters move by exactly the requests made
    between two scrapes (the shared server has served other tests before: deltas), the
    gauges state an idle pool of one ready worker."""
    with server.client() as c:
        before = scrape(c)
        c.rasterize(*_tiny(), result="json")
        c.rasterize(*_tiny(), result="json")
        with pytest.raises(ServiceError) as err:
            c.request("POST", "/v1/rasterize", b"{not json", content_type="application/json")
        assert err.value.status == 400
        with pytest.raises(ServiceError) as err:
            c.request("GET", "/no/such/path")
        assert err.value.status == 404
        c.request("GET", "/openapi.json")
        after = scrape(c)

    def delta(name, **labels):
        return (sample(after, name, **labels) or 0.0) - (sample(before, name, **labels) or 0.0)

    assert delta("glraster_requests_total", endpoint="rasterize", status="200") == 2
    assert delta("glraster_requests_total", endpoint="rasterize", status="400") == 1
    assert delta("glraster_requests_total", endpoint="other", status="404") == 1
    assert delta("glraster_requests_total", endpoint="metrics", status="200") == 1  # `before`
    assert delta("glraster_requests_total", endpoint="openapi", status="200") == 1
    assert delta("glraster_errors_total", endpoint="rasterize", kind="client") == 1
    assert delta("glraster_errors_total", endpoint="other", kind="client") == 1
    assert delta("glraster_errors_total", endpoint="rasterize", kind="server") == 0
    # the histogram counts each rasterize answer once, in cumulative buckets up to +Inf
    assert delta("glraster_request_duration_seconds_count", endpoint="rasterize") == 3
    assert delta("glraster_request_duration_seconds_bucket", endpoint="rasterize",
                 le="+Inf") == 3
    buckets = [v for (name, labels), v in after.items()
               if name == "glraster_request_duration_seconds_bucket"
               and ("endpoint", "rasterize") in labels]
    assert buckets == sorted(buckets) and len(buckets) == len(BUCKETS) + 1
    assert delta("glraster_request_duration_seconds_sum", endpoint="rasterize") > 0
    for reason in ("crash", "deadline", "error", "startup"):
        assert delta("glraster_worker_restarts_total", reason=reason) == 0
    assert sample(after, "glraster_queue_depth") == 0
    assert sample(after, "glraster_queue_capacity") == 8              # SHARED_ARGS --queue
    assert sample(after, "glraster_inflight_requests") == 0
    assert {state: sample(after, "glraster_workers", state=state)
            for state in ("starting", "ready", "busy", "failed", "stopped")} == {
        "starting": 0, "ready": 1, "busy": 0, "failed": 0, "stopped": 0}
    assert sample(after, "glraster_worker_resident_bytes", worker="0") > 2**20
    assert sample(after, "process_resident_memory_bytes") > 2**20


def test_openapi_schema_is_checked_in():
    """docs/openapi.json is the schema of a server with the default flags (regenerate:
    glraster serve --print-openapi > docs/openapi.json)."""
    from glraster.service.config import ServiceConfig
    from glraster.service.openapi import schema

    assert schema(ServiceConfig()) == json.loads((ROOT / "docs" / "openapi.json").read_text())


def test_served_schema_is_the_one_of_its_flags(server):
    """The served schema states this server's limits: it equals --print-openapi with the
    same flags (SHARED_ARGS), and has no bearer auth (the shared server has no token)."""
    import subprocess
    import sys

    from tests.service.conftest import SHARED_ARGS

    with server.client() as c:
        served = json.loads(c.request("GET", "/openapi.json")[2])
    printed = subprocess.run([sys.executable, "-m", "glraster.cli", "serve", *SHARED_ARGS,
                              "--print-openapi"], capture_output=True, text=True, check=True)
    assert served == json.loads(printed.stdout)
    scene = served["components"]["schemas"]["Scene"]["properties"]
    assert scene["resolution"]["items"]["maximum"] == 1024
    assert scene["pos"]["maxItems"] == 200000
    assert "security" not in served and "securitySchemes" not in served["components"]


def _tiny():
    pos = np.array([[-0.9, -0.9, 0.1, 1], [0.9, -0.8, 0.5, 2], [0, 0.9, 0.9, 1]], np.float32)
    return pos, np.array([[0, 1, 2]]), (32, 48)


@pytest.mark.parametrize("name", SCENES)
def test_npz_result_is_bit_identical_to_in_process_rasterize(server, ctx, name):
    """The service's arrays are the in-process glraster.rasterize arrays, byte for byte
    (same driver, same backend): no tolerance."""
    scene = load_scene(name)
    local = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=scene.outputs)
    with server.client() as c:
        remote = c.rasterize(scene.pos, scene.tri, scene.resolution, outputs=scene.outputs)
    for out in scene.outputs + ("mask",):
        assert _same_bits(getattr(remote, out), getattr(local, out)), out


@pytest.mark.parametrize("name", ["basic_perspective_triangle", "behind_camera", "slivers"])
def test_json_body_gives_the_same_bits_as_npz(server, ctx, name):
    """A JSON scene (float32 values printed as shortest float64 repr) rounds back to the
    same float32 positions, so its result is bit for bit the in-process one."""
    scene = load_scene(name)
    local = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx)
    body = json.dumps({"pos": scene.pos.tolist(), "tri": scene.tri.tolist(),
                       "resolution": list(scene.resolution)}).encode()
    with server.client() as c:
        _, headers, data = c.request("POST", "/v1/rasterize", body,
                                     content_type="application/json", accept="application/x-npz")
    from glraster.client import decode_raster

    remote = decode_raster(data, headers)
    for out in ("persp", "screen", "depth", "tri_id", "mask"):
        assert _same_bits(getattr(remote, out), getattr(local, out)), out


def test_exr_result_holds_the_in_process_raster(server, ctx, tmp_path):
    scene = load_scene("torus")
    local = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx)
    with server.client() as c:
        data = c.rasterize(scene.pos, scene.tri, scene.resolution, result="exr")
    path = tmp_path / "r.exr"
    path.write_bytes(data)
    back = exr.read_raster(path)
    assert back.resolution == scene.resolution
    for out in ("persp", "screen", "depth"):
        assert _same_bits(back.full(out), getattr(local, out)), out
    assert np.array_equal(back.full("tri_id"), local.tri_id)
    assert "llvmpipe" in back.metadata["producer"] or back.metadata["producer"]


def test_reference_result_is_the_float64_reference(server):
    scene = load_scene("fan_offcenter")
    local = gr.reference.rasterize(scene.pos, scene.tri, scene.resolution)
    with server.client() as c:
        remote = c.rasterize(scene.pos, scene.tri, scene.resolution, reference=True)
    assert remote.info["headers"]["x-glraster-source"] == "reference"
    for out in ("persp", "screen", "depth", "tri_id", "mask"):
        assert _same_bits(getattr(remote, out), getattr(local, out)), out


def test_json_stats_and_comparison(server):
    scene = load_scene("icosphere")
    with server.client() as c:
        stats = c.rasterize(scene.pos, scene.tri, scene.resolution, result="json", compare=True)
        raster = c.rasterize(scene.pos, scene.tri, scene.resolution, compare=True,
                             outputs=("persp", "tri_id"))
    assert stats["resolution"] == [256, 256] and stats["triangles"] == 1280
    assert stats["covered"] > 0 and stats["values"]["tri_id"]["max"] < 1280
    assert stats["comparison"]["ok"], stats["comparison"]["summary"]
    assert stats["comparison"]["coverage_mismatch"] == 0
    assert raster.info["comparison"]["ok"] and raster.info["headers"]["x-glraster-comparison"] == "pass"
    assert raster.screen is None and raster.depth is None and raster.persp is not None


@pytest.mark.parametrize("method", ["divw", "homogeneous", "homogeneous64", "solve4"])
def test_methods_match_in_process(server, ctx, method):
    scene = load_scene("basic_perspective_triangle")
    local = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, method=method)
    with server.client() as c:
        remote = c.rasterize(scene.pos, scene.tri, scene.resolution, method=method)
    for out in ("persp", "screen", "depth", "tri_id"):
        assert _same_bits(getattr(remote, out), getattr(local, out)), out


def test_check_endpoint_json_and_junit(server):
    with server.client() as c:
        doc = c.check(scenes=["basic_*", "tiny_viewport"])
        xml = c.check(scenes="tiny_viewport", junit=True)
        sharded = c.check(scenes=["basic_*"], shard="2/2")
    names = [s["name"] for s in doc["scenes"]]
    assert names == [n for n in list_scenes() if n.startswith("basic_")] + ["tiny_viewport"]
    assert doc["ok"] and all(s["status"] == "pass" for s in doc["scenes"])
    def scene_suite(text):   # the root also holds the probe suite of the run
        return next(s for s in ET.fromstring(text).iter("testsuite")
                    if s.get("name") == "glraster.conformance.check")

    assert scene_suite(doc["junit"]).get("tests") == str(len(names))
    assert [t.get("name") for t in scene_suite(xml.encode()).iter("testcase")] == ["tiny_viewport"]
    assert sharded["shard"] == "2/2" and 0 < len(sharded["scenes"]) < 3


def test_render_command_with_server_matches_local_render(server, gl_backend, tmp_path):
    """`glraster render --server URL` writes the EXR a local render writes (same arrays)."""
    def render(*extra, out):
        return subprocess.run([sys.executable, "-m", "glraster.cli", "render", "torus", "-o",
                               str(out), *extra], capture_output=True, text=True, timeout=300)
    remote = render("--server", server.url, out=tmp_path / "remote.exr")
    assert remote.returncode == 0, remote.stderr
    local = render("--backend", gl_backend, out=tmp_path / "local.exr")
    assert local.returncode == 0, local.stderr
    a, b = exr.read_raster(tmp_path / "remote.exr"), exr.read_raster(tmp_path / "local.exr")
    for out in ("persp", "screen", "depth", "tri_id"):
        assert _same_bits(a.full(out), b.full(out)), out
    assert server.url in a.metadata["producer"]
    ref = render("--server", server.url, "--reference", out=tmp_path / "ref.exr")
    assert ref.returncode == 0, ref.stderr
    assert "reference" in exr.read_raster(tmp_path / "ref.exr").metadata["producer"]


def test_render_command_with_server_renders_a_multisampled_scene_as_locally(server, gl_backend,
                                                                            tmp_path):
    """A multisampled scene's .npz through the service: the per-sample arrays, mask and
    positions of a local render, bit for bit (NaN where the local one has NaN); the
    reference's float64 not said to be rounded."""
    def render(*extra, out):
        return subprocess.run([sys.executable, "-m", "glraster.cli", "render",
                               "ms_fan_offcenter", "-o", str(out), *extra],
                              capture_output=True, text=True, timeout=300)
    for extra, local_extra in ((["--server", server.url], ["--backend", gl_backend]),
                               (["--server", server.url, "--reference"], ["--reference"])):
        remote = render(*extra, out=tmp_path / "remote.npz")
        assert remote.returncode == 0, remote.stderr
        local = render(*local_extra, out=tmp_path / "local.npz")
        assert local.returncode == 0, local.stderr
        with np.load(tmp_path / "remote.npz") as a, np.load(tmp_path / "local.npz") as b:
            for key in ("persp", "screen", "depth", "tri_id", "mask", "sample_positions"):
                assert a[key].shape == b[key].shape and a[key].dtype == b[key].dtype, key
                assert np.array_equal(a[key], b[key], equal_nan=True), key
            producer = json.loads(str(a["metadata"]))["producer"]
        assert server.url in producer and "rounded" not in producer


def test_render_command_exit_codes_with_server(server, tmp_path):
    """A refused request is exit 2 (bad input), an unreachable service exit 3."""
    too_big = tmp_path / "big.json"
    too_big.write_text(json.dumps({"pos": [[-1, -1, 0, 1], [3, -1, 0, 1], [-1, 3, 0, 1]],
                                   "tri": [[0, 1, 2]], "resolution": [2048, 16]}))
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "render", str(too_big), "-o",
                          str(tmp_path / "x.exr"), "--server", server.url],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "resolution" in run.stderr, run.stderr
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "render", "torus", "-o",
                          str(tmp_path / "x.exr"), "--server", "http://127.0.0.1:9"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 3, run.stderr
    assert not (tmp_path / "x.exr").exists()


def test_client_error_names_the_field(server):
    pos, tri, res = _tiny()
    with server.client() as c, pytest.raises(ServiceError) as err:
        c.request("POST", "/v1/rasterize", encode_scene(pos, np.array([[0, 1, 7]]), res),
                  content_type="application/x-npz")
    assert err.value.status == 422 and err.value.field == "tri"


def test_multisampled_npz_result_is_the_in_process_raster(server, ctx):
    """samples / interpolation in the request: per-sample arrays (a sample axis after W)
    and sample_positions, bit for bit as in-process; EXR is refused with 406."""
    if len(ctx.sample_counts) < 2:
        pytest.skip("the driver offers no multisampling")
    samples = ctx.sample_counts[-1]
    scene = load_scene("ms_perspective_centroid")
    for interpolation in ("centroid", "sample"):
        local = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx,
                             samples=samples, interpolation=interpolation)
        with server.client() as c:
            remote = c.rasterize(scene.pos, scene.tri, scene.resolution, samples=samples,
                                 interpolation=interpolation)
        assert remote.samples == samples and remote.interpolation == interpolation
        assert remote.resolution == scene.resolution
        for out in ("persp", "screen", "depth", "tri_id", "mask", "sample_positions"):
            assert _same_bits(getattr(remote, out), getattr(local, out)), out
    with server.client() as c:
        with pytest.raises(ServiceError) as err:
            c.rasterize(scene.pos, scene.tri, scene.resolution, samples=samples, result="exr")
        assert err.value.status == 406 and err.value.field == "samples"
        with pytest.raises(ServiceError) as err:
            c.rasterize(scene.pos, scene.tri, scene.resolution, samples=3)
        assert err.value.status == 422 and err.value.field == "samples"
        with pytest.raises(ServiceError) as err:
            c.rasterize(scene.pos, scene.tri, scene.resolution, samples=samples,
                        interpolation="middle")
        assert err.value.status == 422 and err.value.field == "interpolation"
