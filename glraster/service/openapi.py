"""The service's OpenAPI 3.1 schema, served at ``/openapi.json`` and checked in as
docs/openapi.json (``glraster serve --print-openapi > docs/openapi.json``; a test asserts the
two are equal). Written by hand so that it says exactly what the handlers accept."""

from __future__ import annotations

from glraster._version import __version__
from glraster.service.protocol import CHECK_FIELDS, METHOD_NAMES, OUTPUT_NAMES

_ERROR = {"$ref": "#/components/responses/Error"}

_OPTIONS = {
    "outputs": {"type": "array", "items": {"type": "string", "enum": list(OUTPUT_NAMES)},
                "minItems": 1, "uniqueItems": True,
                "description": "Outputs to render and return (default: all four)."},
    "method": {"type": "string", "enum": list(METHOD_NAMES), "default": "hw",
               "description": "How the GPU computes barycentrics (README, Methods)."},
    "reference": {"type": "boolean", "default": False,
                  "description": "Return the float64 reference raster instead of the GPU's "
                                 "(rounded to float32 in EXR)."},
    "compare": {"type": "boolean", "default": False,
                "description": "Compare the GPU raster with the float64 reference under the "
                               "method's per-pixel error model; the report is in the JSON "
                               "result, the .npz entry 'comparison' and the "
                               "X-Glraster-Comparison header."},
    "cull_backfaces": {"type": "boolean", "default": False,
                       "description": "Drop clockwise triangles (GPU only)."},
    "crop": {"type": "boolean", "default": False,
             "description": "EXR: store only the covered pixels' bounding box (lossless)."},
    "samples": {"type": "integer", "minimum": 1, "maximum": 64, "default": 1,
                "description": "Samples per pixel: 1 or a count the driver offers (README, "
                               "Multisampling); per-sample arrays have a sample axis after W "
                               "and the .npz holds sample_positions. No EXR form."},
    "interpolation": {"type": "string", "enum": ["center", "centroid", "sample"],
                      "default": "center",
                      "description": "Where multisampled barycentrics are evaluated."},
}

_QUERY_OPTIONS = [
    {"name": "outputs", "in": "query", "required": False,
     "description": "Comma-separated outputs (bodies in .npz carry their options here).",
     "schema": {"type": "string"}},
    {"name": "method", "in": "query", "required": False,
     "schema": {"type": "string", "enum": list(METHOD_NAMES)}},
    *({"name": n, "in": "query", "required": False,
       "schema": {"type": "string", "enum": ["true", "false"]}}
      for n in ("reference", "compare", "cull_backfaces", "crop")),
    {"name": "samples", "in": "query", "required": False, "schema": {"type": "integer"}},
    {"name": "interpolation", "in": "query", "required": False,
     "schema": {"type": "string", "enum": ["center", "centroid", "sample"]}},
]

_DEADLINE = {"name": "deadline", "in": "query", "required": False,
             "description": "Seconds from arrival after which the request is cancelled (504) "
                            "and its worker replaced; at most the server's maximum.",
             "schema": {"type": "number", "exclusiveMinimum": 0}}


def schema() -> dict:
    """The OpenAPI document (a fresh dict)."""
    scene = {
        "type": "object",
        "required": ["pos", "tri", "resolution"],
        "additionalProperties": False,
        "properties": {
            "pos": {"type": "array", "description": "(V, 4) clip-space positions.",
                    "items": {"type": "array", "items": {"type": "number"},
                              "minItems": 4, "maxItems": 4}},
            "tri": {"type": "array", "description": "(T, 3) vertex indices.",
                    "items": {"type": "array", "items": {"type": "integer", "minimum": 0},
                              "minItems": 3, "maxItems": 3}},
            "resolution": {"type": "array", "description": "(height, width) in pixels.",
                           "items": {"type": "integer", "minimum": 1},
                           "minItems": 2, "maxItems": 2},
            **_OPTIONS,
        },
    }
    check = {
        "type": "object", "additionalProperties": False,
        "properties": {
            "scenes": {"description": "Catalog scene names or fnmatch patterns (default: all).",
                       "oneOf": [{"type": "string"},
                                 {"type": "array", "items": {"type": "string"}, "minItems": 1}]},
            "method": {"type": "string", "enum": list(METHOD_NAMES), "default": "hw"},
            "golden": {"type": "boolean", "default": True,
                       "description": "Also compare with the golden EXRs (where the server has "
                                      "them)."},
            "mutants": {"description": "Also run the fault-injection mutants (true, or a name "
                                       "pattern); method hw only.",
                        "oneOf": [{"type": "boolean"}, {"type": "string", "minLength": 1}]},
            "shard": {"type": "string", "pattern": "^[0-9]+/[0-9]+$",
                      "description": "Check only shard I/N of the chosen scenes."},
        },
    }
    assert set(check["properties"]) == set(CHECK_FIELDS)
    error = {
        "type": "object", "required": ["error", "field", "status"],
        "properties": {"error": {"type": "string", "description": "What is wrong."},
                       "field": {"type": "string",
                                 "description": "The field, parameter or header at fault."},
                       "status": {"type": "integer"}},
    }
    stats = {
        "type": "object",
        "required": ["resolution", "triangles", "vertices", "outputs", "covered", "values"],
        "properties": {
            "resolution": {"type": "array", "items": {"type": "integer"}},
            "vertices": {"type": "integer"}, "triangles": {"type": "integer"},
            "outputs": {"type": "array", "items": {"type": "string"}},
            "method": {"type": "string"}, "source": {"type": "string",
                                                     "enum": ["gpu", "reference"]},
            "covered": {"type": "integer", "description": "Pixels covered."},
            "values": {"type": "object", "description": "Per output: min / max over covered "
                                                        "pixels, non-finite count."},
            "info": {"type": "object"}, "timings": {"type": "object"},
            "backend": {"type": "string"}, "renderer": {"type": "string"},
            "gl_version": {"type": "string"},
            "comparison": {"type": "object", "description": "With compare: ok, failures, "
                                                            "coverage and value statistics."},
        },
    }
    binary = {"type": "string", "format": "binary"}
    limits_doc = ("Limits: body size, vertices, triangles and resolution (the configured and "
                  "the driver's maximum) are in GET /v1/info; exceeding one is 413 or 422 "
                  "naming the field.")
    return {
        "openapi": "3.1.0",
        "info": {"title": "glraster rendering service", "version": __version__,
                 "description": "Headless rasterization of triangle meshes on the server's "
                                "OpenGL driver, checked against float64 math "
                                "(docs/service.md). Every error is JSON naming the field."},
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer",
                                           "description": "Required when the server has a "
                                                          "token file (401 missing, 403 wrong)."}},
            "schemas": {"Scene": scene, "CheckRequest": check, "Error": error,
                        "RasterStats": stats},
            "responses": {"Error": {"description": "Refused; the body names the field.",
                                    "content": {"application/json": {
                                        "schema": {"$ref": "#/components/schemas/Error"}}}}},
        },
        "security": [{"bearer": []}],
        "paths": {
            "/v1/rasterize": {"post": {
                "operationId": "rasterize",
                "summary": "Rasterize a scene on the server's driver.",
                "description": "The scene as JSON or as an .npz of pos, tri and resolution "
                               "(options then as query parameters). The result by Accept: "
                               "JSON statistics, the arrays as .npz (bit for bit as "
                               "glraster.rasterize returns them, plus mask) or a glraster "
                               "EXR. " + limits_doc,
                "parameters": [*_QUERY_OPTIONS, _DEADLINE],
                "requestBody": {"required": True, "content": {
                    "application/json": {"schema": {"$ref": "#/components/schemas/Scene"}},
                    "application/x-npz": {"schema": binary}}},
                "responses": {
                    "200": {"description": "The result.",
                            "headers": {"X-Glraster-Comparison": {
                                "description": "pass or fail, with compare",
                                "schema": {"type": "string"}}},
                            "content": {
                                "application/json": {"schema": {
                                    "$ref": "#/components/schemas/RasterStats"}},
                                "application/x-npz": {"schema": binary},
                                "image/x-exr": {"schema": binary}}},
                    **{code: _ERROR for code in ("400", "401", "403", "406", "408", "413",
                                                 "415", "422", "429", "503", "504")},
                }}},
            "/v1/check": {"post": {
                "operationId": "check",
                "summary": "Run the conformance catalog (or chosen scenes) on the server's "
                           "driver.",
                "parameters": [_DEADLINE],
                "requestBody": {"required": False, "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/CheckRequest"}}}},
                "responses": {
                    "200": {"description": "The check result as JSON (with the JUnit XML "
                                           "in 'junit'), or JUnit XML for Accept "
                                           "application/xml.",
                            "content": {"application/json": {"schema": {"type": "object"}},
                                        "application/xml": {"schema": {"type": "string"}}}},
                    **{code: _ERROR for code in ("400", "401", "403", "406", "408", "413",
                                                 "415", "422", "429", "503", "504")},
                }}},
            "/v1/info": {"get": {
                "operationId": "info", "summary": "Driver, limits, workers and queue.",
                "responses": {"200": {"description": "Facts about this replica.",
                                      "content": {"application/json": {
                                          "schema": {"type": "object"}}}},
                              "401": _ERROR, "403": _ERROR}}},
            "/healthz": {"get": {
                "operationId": "healthz", "summary": "Liveness: the server answers.",
                "security": [],
                "responses": {"200": {"description": "Alive.", "content": {
                    "application/json": {"schema": {"type": "object"}}}}}}},
            "/readyz": {"get": {
                "operationId": "readyz",
                "summary": "Readiness: a worker holds a context that rendered its probe.",
                "security": [],
                "responses": {"200": {"description": "Ready.", "content": {
                    "application/json": {"schema": {"type": "object"}}}},
                    "503": {"description": "Not ready (starting, no working context, or "
                                           "draining).", "content": {
                        "application/json": {"schema": {"type": "object"}}}}}}},
            "/metrics": {"get": {
                "operationId": "metrics", "summary": "Prometheus text metrics.",
                "responses": {"200": {"description": "Exposition format 0.0.4.",
                                      "content": {"text/plain": {"schema": {"type": "string"}}}},
                              "401": _ERROR, "403": _ERROR}}},
            "/openapi.json": {"get": {
                "operationId": "openapi", "summary": "This schema.", "security": [],
                "responses": {"200": {"description": "OpenAPI 3.1.", "content": {
                    "application/json": {"schema": {"type": "object"}}}}}}},
        },
    }
