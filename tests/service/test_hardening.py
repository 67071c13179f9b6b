"""Hardening against a real server on loopback: bad requests (a table and a fuzzer driven by
the OpenAPI schema) get a 4xx naming the field and never a 5xx or a dead worker; tokens;
a worker killed or hung mid-request; a full queue; slow clients; shutdown under load."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import threading
import time
import zipfile

import numpy as np
import pytest

import glraster as gr
from glraster.client import ServiceError, ServiceUnavailable, decode_raster, encode_scene

from tests.service.conftest import Server, resume, sample, scrape

TRIANGLE = {"pos": [[-0.9, -0.9, 0.1, 1], [0.9, -0.8, 0.5, 2], [0, 0.9, 0.9, 1]],
            "tri": [[0, 1, 2]], "resolution": [32, 48]}


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _post(server, body, ctype="application/json", accept="application/json", path="/v1/rasterize",
          headers=None, query=""):
    """(status, headers, parsed JSON or bytes) without the client's error mapping."""
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=120)
    h = {"Accept": accept, **({"Content-Type": ctype} if ctype else {}), **(headers or {})}
    conn.request("POST", path + query, body=body, headers=h)
    resp = conn.getresponse()
    data = resp.read()
    conn.close()
    hdrs = {k.lower(): v for k, v in resp.getheaders()}
    if hdrs.get("content-type", "").startswith("application/json"):
        return resp.status, hdrs, json.loads(data)
    return resp.status, hdrs, data


def _scene(**changes):
    doc = dict(TRIANGLE)
    doc.update(changes)
    return json.dumps({k: v for k, v in doc.items() if v is not ...}).encode()


def _bomb() -> bytes:
    """An .npz whose pos member inflates to 64 MiB from a few kB."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("pos.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array(fh, np.zeros((1 << 22, 4), np.float32))
    return buf.getvalue()


def _pickled() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, pos=np.array([object()] * 4, dtype=object).reshape(1, 4),
             tri=np.zeros((0, 3), np.int32), resolution=np.array([4, 4]))
    return buf.getvalue()


BAD_REQUESTS = [
    # (id, body, content type, accept, query, method/path, expected status, field)
    ("not json", b"{pos:", "application/json", None, "", None, 400, "body"),
    ("json array", b"[1, 2]", "application/json", None, "", None, 400, "body"),
    ("NaN literal", b'{"pos": [[NaN, 0, 0, 1]]}', "application/json", None, "", None, 400, "body"),
    ("deep nesting", b'{"pos": ' + b"[" * 100000 + b"]" * 100000 + b"}", "application/json",
     None, "", None, 422, "pos"),
    ("deep nesting at the top", b"[" * 100000 + b"]" * 100000, "application/json", None, "",
     None, 400, "body"),
    ("missing pos", _scene(pos=...), "application/json", None, "", None, 422, "pos"),
    ("missing resolution", _scene(resolution=...), "application/json", None, "", None, 422,
     "resolution"),
    ("pos shape", _scene(pos=[[0, 0, 1]]), "application/json", None, "", None, 422, "pos"),
    ("pos ragged", _scene(pos=[[0, 0, 0, 1], [0, 1]]), "application/json", None, "", None, 422,
     "pos"),
    ("pos strings", _scene(pos=[["a", "b", "c", "d"]]), "application/json", None, "", None, 422,
     "pos"),
    ("pos beyond float32", _scene(pos=[[1e39, 0, 0, 1]] * 3), "application/json", None, "", None,
     422, "pos"),
    ("pos huge int", _scene(pos=[[10**400, 0, 0, 1]] * 3), "application/json", None, "", None,
     422, "pos"),
    ("pos not a list", _scene(pos={"a": 1}), "application/json", None, "", None, 422, "pos"),
    ("tri out of range", _scene(tri=[[0, 1, 3]]), "application/json", None, "", None, 422, "tri"),
    ("tri negative", _scene(tri=[[0, -1, 2]]), "application/json", None, "", None, 422, "tri"),
    ("tri floats", _scene(tri=[[0.5, 1, 2]]), "application/json", None, "", None, 422, "tri"),
    ("tri huge", _scene(tri=[[2**70, 1, 2]]), "application/json", None, "", None, 422, "tri"),
    ("resolution zero", _scene(resolution=[0, 5]), "application/json", None, "", None, 422,
     "resolution"),
    ("resolution over the limit", _scene(resolution=[1025, 5]), "application/json", None, "",
     None, 422, "resolution"),
    ("resolution float", _scene(resolution=[1.5, 3]), "application/json", None, "", None, 422,
     "resolution"),
    ("resolution three", _scene(resolution=[1, 2, 3]), "application/json", None, "", None, 422,
     "resolution"),
    ("resolution bool", _scene(resolution=[True, 3]), "application/json", None, "", None, 422,
     "resolution"),
    ("outputs unknown", _scene(outputs=["bogus"]), "application/json", None, "", None, 422,
     "outputs"),
    ("outputs empty", _scene(outputs=[]), "application/json", None, "", None, 422, "outputs"),
    ("method unknown", _scene(method="magic"), "application/json", None, "", None, 422, "method"),
    # "samples=64 is not offered by this driver": the field comes from the error's argument
    # (the message's first word, "samples=64", names no field)
    ("samples the driver lacks", _scene(samples=64), "application/json", None, "", None, 422,
     "samples"),
    ("compare not bool", _scene(compare=3), "application/json", None, "", None, 422, "compare"),
    ("reference with method", _scene(reference=True, method="divw"), "application/json", None,
     "", None, 422, "method"),
    ("unknown field", _scene(colour="red"), "application/json", None, "", None, 422, "colour"),
    ("unknown query", _scene(), "application/json", None, "?colour=red", None, 422, "colour"),
    ("query twice", _scene(), "application/json", None, "?method=hw&method=hw", None, 422,
     "method"),
    ("query and body", _scene(method="hw"), "application/json", None, "?method=hw", None, 422,
     "method"),
    ("bad deadline", _scene(), "application/json", None, "?deadline=-1", None, 422, "deadline"),
    ("deadline over the max", _scene(), "application/json", None, "?deadline=1e9", None, 422,
     "deadline"),
    ("deadline below the minimum", _scene(), "application/json", None, "?deadline=5e-324", None,
     422, "deadline"),
    ("compare yes in the query", _scene(), "application/json", None, "?compare=yes", None, 422,
     "compare"),
    ("content type", _scene(), "text/plain", None, "", None, 415, "content-type"),
    ("no content type", _scene(), None, None, "", None, 415, "content-type"),
    ("accept", _scene(), "application/json", "image/png", "", None, 406, "accept"),
    ("npz garbage", b"PK\x03\x04 not a zip", "application/x-npz", None, "", None, 400, "body"),
    ("npz missing resolution", _npz(pos=np.zeros((3, 4), np.float32), tri=np.zeros((1, 3), int)),
     "application/x-npz", None, "", None, 422, "resolution"),
    ("npz extra member", _npz(pos=np.zeros((3, 4)), tri=np.zeros((1, 3), int),
                              resolution=np.array([4, 4]), evil=np.zeros(3)),
     "application/x-npz", None, "", None, 422, "evil"),
    ("npz pickled objects", _pickled(), "application/x-npz", None, "", None, 422, "pos"),
    ("npz NaN", _npz(pos=np.full((3, 4), np.nan, np.float32), tri=np.array([[0, 1, 2]]),
                     resolution=np.array([4, 4])), "application/x-npz", None, "", None, 422, "pos"),
    ("npz bomb", _bomb(), "application/x-npz", None, "", None, 413, "pos"),
    ("npz too many vertices", _npz(pos=np.zeros((200001, 4), np.float32),
                                   tri=np.zeros((1, 3), np.int32), resolution=np.array([4, 4])),
     "application/x-npz", None, "", None, 413, "pos"),
    ("npz too many triangles", _npz(pos=np.zeros((3, 4), np.float32),
                                    tri=np.zeros((200001, 3), np.int32),
                                    resolution=np.array([4, 4])),
     "application/x-npz", None, "", None, 413, "tri"),
    ("npz resolution dtype", _npz(pos=np.zeros((3, 4), np.float32), tri=np.array([[0, 1, 2]]),
                                  resolution=np.array([4.0, 4.0])),
     "application/x-npz", None, "", None, 422, "resolution"),
    ("check not json", b"{", "application/json", None, "", "/v1/check", 400, "body"),
    ("check no scene matches", b'{"scenes": ["nothing_*"]}', "application/json", None, "",
     "/v1/check", 422, "scenes"),
    ("check method", b'{"method": "x"}', "application/json", None, "", "/v1/check", 422, "method"),
    ("check mutants with method", b'{"method": "divw", "mutants": true}', "application/json",
     None, "", "/v1/check", 422, "mutants"),
    ("check scenes empty", b'{"scenes": ""}', "application/json", None, "", "/v1/check", 422,
     "scenes"),
    ("check deadline below the minimum", b"{}", "application/json", None, "?deadline=2",
     "/v1/check", 422, "deadline"),
    ("check shard", b'{"shard": "3/2"}', "application/json", None, "", "/v1/check", 422, "shard"),
    ("check unknown field", b'{"everything": 1}', "application/json", None, "", "/v1/check", 422,
     "everything"),
    ("check bad mutant pattern", b'{"scenes": "tiny_viewport", "mutants": "zzz*"}',
     "application/json", None, "", "/v1/check", 422, "mutants"),
]


def test_bad_requests_get_4xx_naming_the_field(server):
    """Each bad request of the table: its 4xx, JSON naming the field; the worker survives."""
    before = server.info()["workers"][0]
    problems = []
    for name, body, ctype, accept, query, path, status, field in BAD_REQUESTS:
        got, headers, doc = _post(server, body, ctype, accept or "application/json",
                                  path or "/v1/rasterize", query=query)
        if got != status or not isinstance(doc, dict) or doc.get("field") != field \
                or doc.get("status") != status or not doc.get("error"):
            problems.append(f"{name}: expected {status} {field}, got {got} {doc!r:.300}")
    assert not problems, "\n".join(problems)
    after = server.info()["workers"][0]
    assert (after["pid"], after["restarts"]) == (before["pid"], before["restarts"])


def test_wrong_method_and_unknown_path_are_json(server):
    import http.client

    for method, path, status, field in (("GET", "/v1/rasterize", 405, "method"),
                                        ("DELETE", "/v1/info", 405, "method"),
                                        ("GET", "/v2/nothing", 404, "path")):
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
        conn.request(method, path)
        resp = conn.getresponse()
        doc = json.loads(resp.read())
        conn.close()
        assert (resp.status, doc["field"], doc["status"]) == (status, field, status)


# -- fuzzing from the OpenAPI schema ----------------------------------------------------------

def _resolve(node, doc):
    """The schema with local $refs inlined (hypothesis-jsonschema needs a closed schema)."""
    if isinstance(node, dict):
        if "$ref" in node:
            target = doc
            for part in node["$ref"].lstrip("#/").split("/"):
                target = target[part]
            return _resolve(target, doc)
        return {k: _resolve(v, doc) for k, v in node.items()}
    if isinstance(node, list):
        return [_resolve(v, doc) for v in node]
    return node


def _body_schema(doc, path):
    content = doc["paths"][path]["post"]["requestBody"]["content"]["application/json"]
    schema = _resolve(content["schema"], doc)
    schema.pop("description", None)
    return schema


def from_schema(schema, max_items=24):
    """A hypothesis strategy of the instances of a JSON schema, for the subset the service's
    schema uses (object, array, number, integer, string, boolean, enum, oneOf, anyOf, min/max
    items and values, exclusiveMinimum, uniqueItems, pattern)."""
    from hypothesis import strategies as st

    if "enum" in schema:
        return st.sampled_from(schema["enum"])
    for key in ("oneOf", "anyOf"):
        if key in schema:
            return st.one_of([from_schema(s, max_items) for s in schema[key]])
    kind = schema.get("type")
    if kind == "object":
        props = schema.get("properties", {})
        required = schema.get("required", [])
        return st.fixed_dictionaries(
            {k: from_schema(props[k], max_items) for k in required},
            optional={k: from_schema(v, max_items) for k, v in props.items() if k not in required})
    if kind == "array":
        lo = schema.get("minItems", 0)
        hi = schema.get("maxItems", max(lo, max_items))
        return st.lists(from_schema(schema.get("items", {}), max_items), min_size=lo,
                        max_size=hi, unique=bool(schema.get("uniqueItems")))
    if kind == "integer":
        return st.integers(min_value=schema.get("minimum"), max_value=schema.get("maximum"))
    if kind == "number":
        lo = schema.get("minimum", schema.get("exclusiveMinimum"))
        return st.floats(min_value=lo, max_value=schema.get("maximum"), allow_nan=False,
                         allow_infinity=False, exclude_min="exclusiveMinimum" in schema)
    if kind == "string":
        if "pattern" in schema:
            return st.from_regex(schema["pattern"], fullmatch=True)
        return st.text(min_size=schema.get("minLength", 0), max_size=12)
    if kind == "boolean":
        return st.booleans()
    return st.none() | st.booleans() | st.integers() | st.text(max_size=5)


def _assert_refused_properly(status, doc, what):
    assert status < 500, f"{what} -> {status} {doc!r:.500}"
    if status >= 400:
        assert isinstance(doc, dict) and doc.get("status") == status and doc.get("field") \
            and doc.get("error"), f"{what} -> {status} without a JSON error: {doc!r:.300}"


def test_fuzzed_requests_from_the_openapi_schema_never_get_5xx(server):
    """Bodies generated from the served schema (valid ones, and ones with a field replaced
    by arbitrary JSON, a required field dropped, raw bytes, odd .npz arrays): zero 5xx, a
    JSON error naming a field for every 4xx, and no worker restarted. Bounded: a few
    hundred examples, about half a minute per backend."""
    pytest.importorskip("hypothesis")
    from hypothesis import HealthCheck, given, settings, strategies as st
    from hypothesis.extra import numpy as hnp

    with server.client() as c:
        doc = json.loads(c.request("GET", "/openapi.json")[2])
    scene_schema = _body_schema(doc, "/v1/rasterize")
    # Keep valid examples cheap: small images (the server's limit is 1024 anyway).
    scene_schema["properties"]["resolution"]["items"]["maximum"] = 300
    json_values = st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
        lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=5), inner,
                                                                     max_size=4),
        max_leaves=20)
    fields = sorted(scene_schema["properties"])

    @st.composite
    def bodies(draw):
        instance = draw(from_schema(scene_schema))
        how = draw(st.sampled_from(["valid", "replace", "drop", "add"]))
        if how == "replace":
            instance[draw(st.sampled_from(fields))] = draw(json_values)
        elif how == "drop":
            instance.pop(draw(st.sampled_from(["pos", "tri", "resolution"])), None)
        elif how == "add":
            instance[draw(st.text(min_size=1, max_size=6))] = draw(json_values)
        return json.dumps(instance).encode()

    common = settings(max_examples=300, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))
    before = [(w["pid"], w["restarts"]) for w in server.info()["workers"]]

    @common
    @given(bodies())
    def json_bodies(body):
        status, _, doc = _post(server, body)
        _assert_refused_properly(status, doc, body[:300])

    @settings(common, max_examples=60)
    @given(st.binary(max_size=300), st.sampled_from(["application/json", "application/x-npz"]))
    def raw_bodies(body, ctype):
        status, _, doc = _post(server, body, ctype)
        _assert_refused_properly(status, doc, body[:100])

    dtypes = st.sampled_from([np.float32, np.float64, np.int32, np.int64, np.uint8, np.bool_,
                              np.float16, np.complex64, "<U3", ">f4"])

    @settings(common, max_examples=120)
    @given(hnp.arrays(dtypes, hnp.array_shapes(min_dims=0, max_dims=3, max_side=5)),
           hnp.arrays(dtypes, hnp.array_shapes(min_dims=0, max_dims=3, max_side=5)),
           hnp.arrays(dtypes, hnp.array_shapes(min_dims=0, max_dims=2, max_side=3)),
           st.sampled_from(["", "?outputs=depth", "?compare=true", "?method=solve4",
                            "?reference=true&outputs=tri_id", "?crop=maybe"]),
           st.sampled_from(["application/json", "application/x-npz", "image/x-exr"]))
    def npz_bodies(pos, tri, res, query, accept):
        status, _, doc = _post(server, _npz(pos=pos, tri=tri, resolution=res), "application/x-npz",
                               accept, query=query)
        if isinstance(doc, bytes):
            assert status == 200
            return
        _assert_refused_properly(status, doc, f"{pos!r:.80} {tri!r:.80} {res!r} {query}")

    check_schema = _body_schema(doc, "/v1/check")

    @st.composite
    def check_bodies(draw):
        instance = draw(from_schema(check_schema))
        # Valid check requests run scenes: keep them to the cheapest one.
        if draw(st.booleans()) or not isinstance(instance.get("scenes"), (str, list)):
            instance["scenes"] = "tiny_viewport"
        instance["golden"] = False
        if draw(st.booleans()):
            instance[draw(st.sampled_from(sorted(check_schema["properties"])))] = draw(json_values)
        return json.dumps(instance).encode()

    @settings(common, max_examples=40)
    @given(check_bodies())
    def check_requests(body):
        status, _, doc = _post(server, body, path="/v1/check")
        _assert_refused_properly(status, doc, body[:300])

    json_bodies()
    raw_bodies()
    npz_bodies()
    check_requests()
    after = [(w["pid"], w["restarts"]) for w in server.info()["workers"]]
    assert after == before, "a worker was restarted during the fuzzing"


# -- authentication ---------------------------------------------------------------------------

@pytest.fixture
def token_server(gl_backend, servers, tmp_path_factory):
    folder = tmp_path_factory.mktemp("token")
    path = folder / "tokens"
    path.write_text("# rotated tokens\nold-token-0123456789abcdef\nnew-token-0123456789abcdef\n")
    path.chmod(0o600)
    return servers.get(gl_backend, "--workers", "1", "--token-file", str(path),
                       token="new-token-0123456789abcdef")


def test_tokens_missing_wrong_and_right(token_server):
    s = token_server
    body = _scene()
    status, headers, doc = _post(s, body)
    assert (status, doc["field"]) == (401, "authorization")
    assert headers["www-authenticate"].startswith("Bearer")
    for header, want in (("Bearer wrong-token-0123456789abcdef", 403), ("Basic dXNlcjpwdw==", 401),
                         ("Bearer", 401), ("Bearer new-token-0123456789abcde", 403),
                         ("bearer new-token-0123456789abcdef", 200),
                         ("Bearer old-token-0123456789abcdef", 200)):
        status, _, doc = _post(s, body, headers={"Authorization": header})
        assert status == want, (header, status, doc)
        if want != 200:
            assert doc["field"] == "authorization"
    with s.client(token=None) as c:
        assert c.ready() and c.healthy()            # probes need no token
        for call in (c.info, c.metrics):
            with pytest.raises(ServiceError) as err:
                call()
            assert err.value.status == 401
        status, _, _ = c.request("GET", "/openapi.json")
        assert status == 200
    with s.client(token="wrong-token-0123456789abcdef") as c, pytest.raises(ServiceError) as err:
        c.check(scenes="tiny_viewport")
    assert err.value.status == 403
    with s.client() as c:
        assert c.info()["auth"] is True


def test_token_file_must_be_private(tmp_path, gl_backend):
    import subprocess
    import sys

    path = tmp_path / "tokens"
    path.write_text("a-token-long-enough-to-use\n")
    path.chmod(0o644)
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "serve", "--port", "0",
                          "--backend", gl_backend, "--token-file", str(path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "readable by every user" in run.stderr


# -- workers that crash or hang ---------------------------------------------------------------

def _in_thread(fn):
    box = {}

    def run():
        try:
            box["result"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["error"] = exc
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, box


@pytest.fixture
def lone_worker(gl_backend, tmp_path):
    """A server of its own: one worker, queue 1, deadlines up to 60 s."""
    s = Server(gl_backend, "--workers", "1", "--queue", "1", "--deadline", "60",
               log=tmp_path / "stderr.log")
    yield s
    for w in s.info()["workers"] if s.proc.poll() is None else []:
        if w["pid"]:
            resume(w["pid"])
    s.stop()


def test_worker_killed_mid_request_is_replaced_and_the_request_retried(lone_worker, ctx):
    s = lone_worker
    pos, tri = np.array(TRIANGLE["pos"], np.float32), np.array(TRIANGLE["tri"])
    old = s.worker_pids()[0]
    os.kill(old, signal.SIGSTOP)          # it takes the request and cannot answer ...
    t, box = _in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48)))
    s.wait_worker("busy")
    os.kill(old, signal.SIGKILL)          # ... and dies mid-request
    t.join(120)
    assert "error" not in box, box.get("error")
    remote = box["result"]
    assert remote.info["headers"]["x-glraster-retried"] == "1"
    local = gr.rasterize(pos, tri, (32, 48), ctx=ctx)
    assert remote.depth.tobytes() == local.depth.tobytes()
    worker = s.wait_worker("ready")
    assert worker["pid"] != old and worker["restarts"] == 1
    with s.client() as c:
        samples = scrape(c)
        assert sample(samples, "glraster_worker_restarts_total", reason="crash") == 1
        assert sample(samples, "glraster_worker_restarts_total", reason="deadline") == 0
        assert c.rasterize(pos, tri, (32, 48), result="json")["covered"] > 0


def test_worker_killed_holding_two_jobs_retries_the_one_it_rendered_and_resends_the_next(
        lone_worker, ctx):
    """A worker holds the job it renders and the next one (pool.PIPELINE): when it dies,
    the first is retried (X-Glraster-Retried: 1), the second, which never started, is
    simply sent to the replacement; both come back bit for bit."""
    s = lone_worker
    pos, tri = np.array(TRIANGLE["pos"], np.float32), np.array(TRIANGLE["tri"])
    old = s.worker_pids()[0]
    os.kill(old, signal.SIGSTOP)
    held = []
    for _ in range(2):
        held.append(_in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48))))
        end = time.monotonic() + 30
        while s.info()["workers"][0]["jobs"] < len(held) and time.monotonic() < end:
            time.sleep(0.01)    # in order: the first thread's request is the first job
    assert s.info()["workers"][0]["jobs"] == 2
    os.kill(old, signal.SIGKILL)
    local = gr.rasterize(pos, tri, (32, 48), ctx=ctx)
    for t, box in held:
        t.join(120)
        assert "error" not in box, box.get("error")
        assert box["result"].depth.tobytes() == local.depth.tobytes()
    retried = [box["result"].info["headers"].get("x-glraster-retried") for _, box in held]
    assert retried == ["1", None]
    worker = s.wait_worker("ready")
    assert worker["pid"] != old and worker["restarts"] == 1


def test_a_job_whose_deadline_passes_while_it_waits_in_a_worker_is_refused_by_it(lone_worker):
    """The second job a hung worker holds is not rendered after its deadline: the slot
    answers the first with 504 at its deadline and resends the second to the
    replacement, which refuses it (504) because its deadline has passed too."""
    s = lone_worker
    pos, tri = np.array(TRIANGLE["pos"], np.float32), np.array(TRIANGLE["tri"])
    old = s.worker_pids()[0]
    os.kill(old, signal.SIGSTOP)
    first = _in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48), deadline=2))
    end = time.monotonic() + 30
    while s.info()["workers"][0]["jobs"] < 1 and time.monotonic() < end:
        time.sleep(0.01)
    second = _in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48), deadline=1))
    for t, box in (first, second):
        t.join(120)
        err = box.get("error")
        assert isinstance(err, ServiceUnavailable) and err.status == 504, box
        assert err.field == "deadline"
    worker = s.wait_worker("ready")
    assert worker["pid"] != old
    with s.client() as c:
        assert c.rasterize(pos, tri, (32, 48), result="json")["covered"] > 0


def test_worker_dying_twice_answers_503(lone_worker):
    s = lone_worker
    first = s.worker_pids()[0]
    os.kill(first, signal.SIGSTOP)
    # a fullscreen triangle at 1024x1024 with compare: the float64 reference keeps the
    # replacement busy long enough (~0.3 s) to be killed in turn
    big = np.array([[-1, -1, 0.5, 1], [3, -1, 0.5, 1], [-1, 3, 0.5, 1]])
    t, box = _in_thread(lambda: s.client(retries=0).rasterize(
        big, np.array([[0, 1, 2]]), (1024, 1024), compare=True, result="json"))
    s.wait_worker("busy")
    os.kill(first, signal.SIGKILL)
    # the retry goes to the replacement: stop and kill that one too, once it has the job
    end = time.monotonic() + 60
    while time.monotonic() < end:
        w = s.info()["workers"][0]
        if w["pid"] not in (None, first) and w["state"] == "busy":
            os.kill(w["pid"], signal.SIGKILL)
            break
        if w["pid"] not in (None, first) and w["state"] == "ready" and "result" in box:
            pytest.fail("the retry finished before it could be killed")
        time.sleep(0.001)
    t.join(120)
    err = box.get("error")
    assert isinstance(err, ServiceUnavailable) and err.status == 503, box
    assert s.wait_worker("ready")["restarts"] == 2


def test_hung_worker_is_cancelled_at_the_deadline_and_replaced(lone_worker):
    s = lone_worker
    old = s.worker_pids()[0]
    os.kill(old, signal.SIGSTOP)
    t0 = time.monotonic()
    with s.client(retries=0) as c, pytest.raises(ServiceUnavailable) as err:
        c.rasterize(np.array(TRIANGLE["pos"]), np.array(TRIANGLE["tri"]), (32, 48), deadline=2)
    seconds = time.monotonic() - t0
    assert err.value.status == 504 and err.value.field == "deadline"
    assert 1.9 < seconds < 10, seconds     # answered at the deadline, not after a hang
    worker = s.wait_worker("ready")
    assert worker["pid"] != old
    with s.client() as c:
        assert c.rasterize(np.array(TRIANGLE["pos"]), np.array(TRIANGLE["tri"]), (32, 48),
                           result="json")["covered"] > 0
        samples = scrape(c)
        assert sample(samples, "glraster_worker_restarts_total", reason="deadline") == 1
        assert sample(samples, "glraster_worker_restarts_total", reason="crash") == 0
        assert sample(samples, "glraster_errors_total", endpoint="rasterize",
                      kind="deadline") == 1
        assert sample(samples, "glraster_requests_total", endpoint="rasterize",
                      status="504") == 1


def test_full_queue_is_429_with_retry_after(lone_worker):
    s = lone_worker
    pid = s.worker_pids()[0]
    os.kill(pid, signal.SIGSTOP)
    pos, tri = np.array(TRIANGLE["pos"]), np.array(TRIANGLE["tri"])
    # the worker holds two jobs (the one it renders and the next, pool.PIPELINE), the
    # queue one more; the fourth request is refused
    held = [_in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48), result="json"))
            for _ in range(2)]
    end = time.monotonic() + 30
    while s.info()["workers"][0]["jobs"] < 2 and time.monotonic() < end:
        time.sleep(0.01)
    queued = _in_thread(lambda: s.client(retries=0).rasterize(pos, tri, (32, 48), result="json"))
    while s.info()["queue_depth"] < 1 and time.monotonic() < end:
        time.sleep(0.01)
    with s.client() as c:                  # the event loop answers while the worker is stopped
        held_now = scrape(c)
    assert sample(held_now, "glraster_queue_depth") == 1
    assert sample(held_now, "glraster_inflight_requests") == 2
    assert sample(held_now, "glraster_workers", state="busy") == 1
    status, headers, doc = _post(s, _scene())
    assert (status, doc["field"]) == (429, "queue")
    assert int(headers["retry-after"]) >= 1
    os.kill(pid, signal.SIGCONT)
    for t, box in (*held, queued):
        t.join(60)
        assert box["result"]["covered"] > 0, box
    with s.client() as c:
        samples = scrape(c)
    assert sample(samples, "glraster_errors_total", endpoint="rasterize", kind="rejected") == 1
    assert sample(samples, "glraster_requests_total", endpoint="rasterize", status="429") == 1
    assert sample(samples, "glraster_requests_total", endpoint="rasterize", status="200") == 3
    assert sample(samples, "glraster_queue_depth") == 0


# -- slow clients -----------------------------------------------------------------------------

@pytest.fixture
def impatient_server(gl_backend, servers):
    return servers.get(gl_backend, "--workers", "1", "--body-timeout", "1", "--max-resolution",
                       "1024", "--max-body", "0.0625")


def _raw(port, data: bytes) -> bytes:
    """Send ``data`` on a fresh connection and read the answer's head and JSON body."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    sock.sendall(data)
    answer = b""
    while True:
        chunk = sock.recv(65536)
        if not chunk:
            break
        answer += chunk
        head, sep, rest = answer.partition(b"\r\n\r\n")
        if sep and b"content-length:" in head.lower():
            length = int(head.lower().split(b"content-length:")[1].split(b"\r\n")[0])
            if len(rest) >= length:
                break
    sock.close()
    return answer


def test_body_size_limit_by_header_and_while_streaming(impatient_server):
    """Content-Length above the limit is refused before a byte of body is read; a chunked
    body is cut off as soon as it passes the limit. Both 413 naming the body."""
    port = impatient_server.port
    limit = impatient_server.info()["limits"]["max_body_bytes"]
    answer = _raw(port, b"POST /v1/rasterize HTTP/1.1\r\nHost: x\r\nContent-Type: "
                        b"application/json\r\nContent-Length: " + str(limit + 1).encode()
                  + b"\r\n\r\n")
    assert answer.startswith(b"HTTP/1.1 413") and b'"field": "body"' in answer, answer[:300]
    chunk = b"x" * 4096
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk)
                      for _ in range(limit // len(chunk) + 1))
    answer = _raw(port, b"POST /v1/rasterize HTTP/1.1\r\nHost: x\r\nContent-Type: "
                        b"application/json\r\nTransfer-Encoding: chunked\r\n\r\n" + chunks)
    assert answer.startswith(b"HTTP/1.1 413") and b'"field": "body"' in answer, answer[:300]


def test_slow_client_gets_408_without_holding_up_others(impatient_server):
    s = impatient_server
    slow = socket.create_connection(("127.0.0.1", s.port), timeout=30)
    slow.sendall(b"POST /v1/rasterize HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                 b"Content-Length: 1000\r\n\r\n{\"pos\": [")
    t0 = time.monotonic()
    with s.client() as c:          # others are served while the slow body trickles
        for _ in range(5):
            assert c.rasterize(np.array(TRIANGLE["pos"]), np.array(TRIANGLE["tri"]), (32, 48),
                               result="json")["covered"] > 0
    answer = b""
    while b"\r\n\r\n" not in answer:
        chunk = slow.recv(4096)
        if not chunk:
            break
        answer += chunk
    slow.close()
    assert answer.startswith(b"HTTP/1.1 408"), answer[:200]
    assert 0.9 < time.monotonic() - t0 < 10


def test_client_that_does_not_read_its_result_holds_up_nobody(impatient_server):
    s = impatient_server
    body = encode_scene(np.array([[-1, -1, 0.5, 1], [3, -1, 0.5, 1], [-1, 3, 0.5, 1]]),
                        np.array([[0, 1, 2]]), (1024, 1024))
    lazy = socket.create_connection(("127.0.0.1", s.port), timeout=30)
    lazy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    lazy.sendall(b"POST /v1/rasterize HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-npz\r\n"
                 b"Accept: application/x-npz\r\nContent-Length: " + str(len(body)).encode()
                 + b"\r\n\r\n" + body)
    time.sleep(1.0)                # its 28 MB result waits in the server's send buffer
    with s.client() as c:
        for _ in range(5):
            r = c.rasterize(np.array(TRIANGLE["pos"]), np.array(TRIANGLE["tri"]), (32, 48))
            assert r.mask.any()
        assert c.info()["workers"][0]["state"] == "ready"
    lazy.close()


def _read_response(sock) -> tuple[bytes, bytes]:
    """(head, body) of one HTTP response with a Content-Length."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(1 << 20)
    head, _, body = data.partition(b"\r\n\r\n")
    length = int(head.lower().split(b"content-length:")[1].split(b"\r\n")[0])
    chunks, have = [body], len(body)
    while have < length:
        chunk = sock.recv(1 << 20)
        assert chunk, "the server closed the connection mid-body"
        chunks.append(chunk)
        have += len(chunk)
    return head, b"".join(chunks)


def test_results_held_by_slow_clients_keep_their_cells_and_the_rest_use_the_pipe(
        impatient_server, ctx):
    """A large .npz result is answered from one of the worker's shared-memory cells, which
    stays the response's until it has been sent: with every cell held by clients that do
    not read, the next results go through the pipe; every result comes back bit for bit,
    and the cells are free again once the slow clients have read theirs."""
    from glraster.service.cells import CELLS

    s = impatient_server
    pos = np.array([[-1, -1, 0.5, 1], [3, -1, 0.5, 2], [-1, 3, 0.5, 1]])
    tri, res = np.array([[0, 1, 2]]), (1024, 1024)
    local = gr.rasterize(pos, tri, res, ctx=ctx)
    body = encode_scene(pos, tri, res)
    request = (b"POST /v1/rasterize HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-npz\r\n"
               b"Accept: application/x-npz\r\nContent-Length: " + str(len(body)).encode()
               + b"\r\n\r\n" + body)
    before = s.info()["workers"][0]["requests"]
    lazies = []
    for _ in range(CELLS + 1):      # one more than the cells: that one takes the pipe
        # (the kernel's socket buffers take a few MB of the 28 MB result; the rest waits)
        lazy = socket.create_connection(("127.0.0.1", s.port), timeout=60)
        lazy.sendall(request)
        lazies.append(lazy)
    end = time.monotonic() + 60
    while s.info()["workers"][0]["requests"] < before + len(lazies) and time.monotonic() < end:
        time.sleep(0.05)
    assert s.info()["workers"][0]["free_cells"] == 0
    with s.client() as c:           # served through the pipe meanwhile
        r = c.rasterize(pos, tri, res)
        assert r.persp.tobytes() == local.persp.tobytes()
    for lazy in lazies:
        head, data = _read_response(lazy)
        lazy.close()
        assert head.startswith(b"HTTP/1.1 200"), head[:200]
        r = decode_raster(data)
        for name in ("persp", "screen", "depth", "tri_id", "mask"):
            assert getattr(r, name).tobytes() == getattr(local, name).tobytes(), name
    end = time.monotonic() + 30
    while s.info()["workers"][0]["free_cells"] < CELLS and time.monotonic() < end:
        time.sleep(0.05)
    assert s.info()["workers"][0]["free_cells"] == CELLS


# -- shutdown ---------------------------------------------------------------------------------

def test_shutdown_under_load_drains_in_flight_requests(gl_backend, tmp_path, ctx):
    """SIGTERM with requests in flight and queued: every accepted request is answered 200,
    then the server exits 0, its workers are gone and the port is closed."""
    from glraster.studies.loadtest import make_scene

    s = Server(gl_backend, "--workers", "2", "--queue", "16", log=tmp_path / "stderr.log")
    pos, tri, res = make_scene("1024")
    local = gr.rasterize(pos, tri, res, ctx=ctx, outputs=("depth",))
    n = 10
    threads = [_in_thread(lambda: s.client(retries=0).rasterize(pos, tri, res, outputs=("depth",)))
               for _ in range(n)]
    end = time.monotonic() + 60
    while time.monotonic() < end:
        info = s.info()
        done = sum("result" in box or "error" in box for _, box in threads)
        if info["queue_depth"] + info["inflight"] + done >= n and info["inflight"]:
            break
        time.sleep(0.005)
    pids = s.worker_pids()
    s.proc.send_signal(signal.SIGTERM)
    for t, _ in threads:
        t.join(120)
    errors = [box.get("error") for _, box in threads if "error" in box]
    assert not errors, errors
    for _, box in threads:
        assert box["result"].depth.tobytes() == local.depth.tobytes()
    assert s.stop(timeout=60) == 0, s.stderr()
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", s.port), timeout=2).close()
    assert "Traceback" not in s.stderr()
