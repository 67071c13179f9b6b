"""schemathesis hooks for tests/service/test_schemathesis.py (``SCHEMATHESIS_HOOKS``).

The service's schema states everything JSON Schema can (glraster.service.models); a few
rules join two fields and cannot be stated there, and the schema's descriptions list them
(``models.CROSS_FIELD_RULES``, ``models.CHECK_RULES``). A case schemathesis generates as
*valid* (positive mode) is mapped inside those rules here, and only those; negative cases
and every check are untouched. Also mapped, for the same reason: an ``application/x-npz``
body (the schema can only say "binary": a valid case gets a real .npz scene), and the scenes
of a valid conformance check (the catalog's cheapest scene and one mutant, so that a valid
check runs in a fraction of a second instead of minutes for the whole catalog).
"""

from __future__ import annotations

import io

import numpy as np
import schemathesis

import json
import os

from glraster.service.models import OPTION_FIELDS as OPTIONS

# the sample counts the server's driver offers (the test reads them from GET /v1/info)
SAMPLE_COUNTS = json.loads(os.environ.get("GLRASTER_TEST_SAMPLE_COUNTS", "[1]"))
# the methods that offer every interpolation (glraster.gpu.methods: the others center only)
ALL_INTERPOLATIONS = ("hw", "divw")
CHEAP_SCENE = "tiny_viewport"     # 0.13 s with its golden comparison
CHEAP_MUTANT = "z_for_w"          # one mutant instead of all eleven (1.7 s)


def _npz_scene() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, pos=np.array([[-0.9, -0.9, 0.1, 1], [0.9, -0.8, 0.5, 2], [0, 0.9, 0.9, 1]],
                               np.float32),
             tri=np.array([[0, 1, 2]], np.int32), resolution=np.array([16, 24], np.int64))
    return buf.getvalue()


def _rasterize(case) -> None:
    query = case.query if isinstance(case.query, dict) else {}
    body = case.body if isinstance(case.body, dict) else None
    if case.media_type == "application/x-npz":
        case.body = _npz_scene()
        body = {}
    if body is not None and "pos" in body and "tri" in body:
        # every index of tri is below the number of rows of pos
        rows = len(body["pos"])
        body["tri"] = [[i % rows for i in t] for t in body["tri"]] if rows else []
    if body is not None:
        # an option in the JSON body or as a query parameter, not both
        for key in OPTIONS:
            if key in body:
                query.pop(key, None)
    # samples is a count the driver offers; interpolation other than center needs hw or
    # divw; samples above 1 has no EXR form
    samples = 1
    for where, as_text in ((body, False), (query, True)):   # query values are text
        if where is not None and "samples" in where:
            given = int(float(where["samples"]))
            samples = given if given in SAMPLE_COUNTS else 1
            where["samples"] = str(samples) if as_text else samples
    method = (body or {}).get("method") or query.get("method") or "hw"
    if method not in ALL_INTERPOLATIONS:
        for where in (body, query):
            if where is not None and "interpolation" in where:
                where["interpolation"] = "center"
    if samples > 1 and case.headers and "exr" in case.headers.get("Accept", ""):
        case.headers["Accept"] = "application/x-npz"
    # reference excludes cull_backfaces and a method other than hw
    reference = (body or {}).get("reference") is True or query.get("reference") == "true"
    if reference:
        for where, false in ((body, False), (query, "false")):
            if where is not None and "cull_backfaces" in where:
                where["cull_backfaces"] = false
            if where is not None and "method" in where:
                where["method"] = "hw"


def _check(case) -> None:
    body = case.body if isinstance(case.body, dict) else None
    if body is None:
        case.body = body = {}
    body["scenes"] = CHEAP_SCENE
    if body.get("mutants"):
        body["mutants"] = CHEAP_MUTANT   # a pattern that matches a mutant
        body["method"] = "hw"            # mutants needs method hw
    shard = body.get("shard")
    if isinstance(shard, str) and "/" in shard:   # shard I/N has 1 <= I <= N
        i, n = sorted(int(v) for v in shard.split("/"))
        body["shard"] = f"{i}/{n}"


@schemathesis.hook
def map_case(context, case):
    meta = case.meta
    if meta is None or not meta.generation.mode.is_positive:
        return case
    if case.operation.path == "/v1/rasterize":
        _rasterize(case)
    elif case.operation.path == "/v1/check":
        _check(case)
    return case
