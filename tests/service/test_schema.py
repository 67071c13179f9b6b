"""The OpenAPI schema and the parser come from one model (glraster.service.models): a
request part the schema calls valid is accepted, one it calls invalid is refused with a
4xx naming its field. In process, no GL and no server (test_schemathesis.py runs
schemathesis against real servers)."""

from __future__ import annotations

import json

import pytest

from glraster.service import protocol
from glraster.service.config import Limits, ServiceConfig
from glraster.service.models import MIN_DEADLINE, ModelError, for_config
from glraster.service.openapi import schema

jsonschema_rs = pytest.importorskip("jsonschema_rs")   # comes with schemathesis

LIMITS = Limits(max_vertices=8, max_triangles=8, max_resolution=64)
CONFIG = ServiceConfig(limits=LIMITS)
TRI3 = [[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]]


def _validator(doc, name):
    """A validator of components/schemas/NAME of the OpenAPI document."""
    return jsonschema_rs.validator_for({**doc["components"]["schemas"][name],
                                        "$defs": doc["components"]["schemas"]})


def _param_validator(doc, path, name):
    params = doc["paths"][path]["post"]["parameters"]
    return jsonschema_rs.validator_for(next(p for p in params if p["name"] == name)["schema"])


# (body, schema-valid): bodies the old hand-written schema and parser disagreed on, and
# the edges of every constraint the model states
SCENES = [
    ({"pos": [], "resolution": [1, 1], "tri": []}, True),      # an empty scene: empty raster
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [64, 64]}, True),
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [65, 64]}, False),
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [0, 4]}, False),
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [4, 4, 4]}, False),
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [4.0, 4]}, True),   # 4.0 is an integer
    ({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [4.5, 4]}, False),
    ({"pos": TRI3, "tri": [[0, 1.0, 2]], "resolution": [4, 4]}, True),
    ({"pos": TRI3, "tri": [[0, -1, 2]], "resolution": [4, 4]}, False),
    ({"pos": TRI3, "tri": [[0, 8, 2]], "resolution": [4, 4]}, False),    # index >= max_vertices
    ({"pos": [[0, 0, 1]], "tri": [], "resolution": [4, 4]}, False),
    ({"pos": [[4e38, 0, 0, 1]], "tri": [], "resolution": [4, 4]}, False),  # beyond float32
    ({"pos": [[3.4e38, 0, 0, 1]], "tri": [], "resolution": [4, 4]}, True),
    ({"pos": [["0", 0, 0, 1]], "tri": [], "resolution": [4, 4]}, False),
    ({"pos": TRI3 * 3, "tri": [], "resolution": [4, 4]}, False),          # 9 > max_vertices
    ({"pos": TRI3, "tri": [[0, 1, 2]] * 9, "resolution": [4, 4]}, False),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "outputs": []}, False),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "outputs": ["depth", "depth"]}, True),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "outputs": ["colour"]}, False),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "method": "solve4"}, True),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "method": "magic"}, False),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "compare": "true"}, False),
    ({"pos": TRI3, "tri": [], "resolution": [4, 4], "colour": "red"}, False),
    ({"tri": [], "resolution": [4, 4]}, False),
]


@pytest.mark.parametrize("body,valid", SCENES, ids=[json.dumps(b)[:60] for b, _ in SCENES])
def test_rasterize_body_is_accepted_exactly_when_the_schema_says_valid(body, valid):
    doc = schema(CONFIG)
    assert _validator(doc, "Scene").is_valid(body) == valid
    try:
        req = protocol.parse_rasterize(protocol.JSON, json.dumps(body).encode(), {}, LIMITS)
    except protocol.RequestError as exc:
        assert not valid, f"schema-valid body refused: {exc.status} {exc.message}"
        assert 400 <= exc.status < 500
        assert exc.field in body or exc.field in protocol.ARRAY_FIELDS, exc.field
        return
    assert valid, f"schema-invalid body accepted: {req}"
    assert req.pos.shape == (len(body["pos"]), 4) and req.tri.shape == (len(body["tri"]), 3)


QUERIES = [
    ("deadline", "5e-324", False), ("deadline", "0", False), ("deadline", "nan", False),
    ("deadline", str(MIN_DEADLINE), True), ("deadline", "30", True), ("deadline", "30.5", False),
    ("deadline", "soon", False), ("compare", "true", True), ("compare", "yes", False),
    ("compare", "1", False), ("outputs", "depth,tri_id", True), ("outputs", "", False),
    ("outputs", "depth,", False), ("method", "divw", True), ("method", "HW", False),
]


@pytest.mark.parametrize("name,value,valid", QUERIES)
def test_query_parameter_is_accepted_exactly_when_the_schema_says_valid(name, value, valid):
    doc = schema(CONFIG)
    instance = value
    if name == "deadline":
        try:
            instance = float(value)
        except ValueError:
            pass
    assert _param_validator(doc, "/v1/rasterize", name).is_valid(instance) == valid
    try:
        for_config(CONFIG).query("rasterize", [(name, value)])
    except ModelError as exc:
        assert not valid and exc.field == name, exc.message
        return
    assert valid


def test_deadline_below_the_minimum_is_a_422_naming_deadline():
    """?deadline=5e-324 was a 504 (the request expired before a worker could take it): a
    client's impossible request is now refused before it is queued."""
    with pytest.raises(ModelError) as err:
        for_config(CONFIG).query("rasterize", [("deadline", "5e-324")])
    assert err.value.field == "deadline" and "1" in err.value.message


def test_option_in_both_body_and_query_is_refused_naming_it():
    body = json.dumps({"pos": TRI3, "tri": [[0, 1, 2]], "resolution": [4, 4],
                       "method": "hw"}).encode()
    with pytest.raises(protocol.RequestError) as err:
        protocol.parse_rasterize(protocol.JSON, body, {"method": "hw"}, LIMITS)
    assert (err.value.status, err.value.field) == (422, "method")
    assert "both" in err.value.message
    doc = schema(CONFIG)
    assert "not both" in doc["components"]["schemas"]["Scene"]["description"]


@pytest.mark.parametrize("body,valid", [
    ({"scenes": ""}, False), ({"scenes": " , "}, False), ({"scenes": "tiny_viewport"}, True),
    ({"scenes": []}, False), ({"scenes": ["tiny_*"]}, True), ({"shard": "1/2"}, True),
    ({"shard": "0/2"}, False), ({"shard": "a/b"}, False), ({"mutants": ""}, False),
    ({"mutants": True}, True), ({"golden": "no"}, False), ({}, True),
])
def test_check_body_is_accepted_exactly_when_the_schema_says_valid(body, valid):
    doc = schema(CONFIG)
    assert _validator(doc, "CheckRequest").is_valid(body) == valid
    catalog = ["tiny_viewport", "torus"]
    try:
        protocol.parse_check(json.dumps(body).encode(), catalog, LIMITS)
    except protocol.RequestError as exc:
        assert not valid and exc.status == 422 and exc.field in body, exc.message
        return
    assert valid


def test_bearer_auth_is_declared_only_when_the_server_has_tokens():
    without = schema(ServiceConfig())
    assert "security" not in without and "securitySchemes" not in without["components"]
    assert "401" not in without["paths"]["/v1/rasterize"]["post"]["responses"]
    with_tokens = schema(ServiceConfig(tokens=("a-token-of-16-chars",)))
    assert with_tokens["security"] == [{"bearer": []}]
    assert with_tokens["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    assert "401" in with_tokens["paths"]["/v1/rasterize"]["post"]["responses"]
    assert with_tokens["paths"]["/healthz"]["get"]["security"] == []


def test_schema_states_the_servers_limits():
    doc = schema(ServiceConfig(limits=Limits(max_vertices=100, max_triangles=50,
                                             max_resolution=512, max_deadline=90)))
    scene = doc["components"]["schemas"]["Scene"]["properties"]
    assert scene["pos"]["maxItems"] == 100 and scene["tri"]["maxItems"] == 50
    assert scene["tri"]["items"]["items"]["maximum"] == 99
    assert scene["resolution"]["items"]["maximum"] == 512
    deadline = next(p for p in doc["paths"]["/v1/rasterize"]["post"]["parameters"]
                    if p["name"] == "deadline")["schema"]
    assert (deadline["minimum"], deadline["maximum"]) == (MIN_DEADLINE, 90)


def test_rows_above_the_limit_in_json_are_413_naming_the_array():
    body = json.dumps({"pos": TRI3 * 3, "tri": [], "resolution": [4, 4]}).encode()
    with pytest.raises(protocol.RequestError) as err:
        protocol.parse_rasterize(protocol.JSON, body, {}, LIMITS)
    assert (err.value.status, err.value.field) == (413, "pos")


@pytest.mark.parametrize("changes, argument", [
    ({"deadline": float("inf")}, "deadline"),        # the request models need a finite bound
    ({"check_deadline": float("nan")}, "check_deadline"),
    ({"body_timeout": 0.0}, "body_timeout"),
    ({"limits": Limits(max_deadline=-1.0)}, "max_deadline"),
    ({"limits": Limits(max_deadline=float("inf"))}, "max_deadline"),
    ({"drain_timeout": -2.0}, "drain_timeout"),
    ({"drain_timeout": float("nan")}, "drain_timeout"),
])
def test_a_config_with_a_time_that_is_not_a_finite_positive_number_is_refused(changes,
                                                                               argument):
    from glraster.errors import ArgumentError

    with pytest.raises(ArgumentError, match=f"{argument} must be") as info:
        ServiceConfig(**changes)
    assert info.value.argument == argument
    assert ServiceConfig(drain_timeout=0.0).effective_drain_timeout == 0.0   # 0: no drain
