"""The service's OpenAPI 3.1 schema, served at ``/openapi.json`` and checked in as
docs/openapi.json (``glraster serve --print-openapi > docs/openapi.json``, the schema of a
server with the default flags; a test asserts the two are equal).

The request bodies and query parameters are generated from the request models of
:mod:`glraster.service.models`, the same types the parser decodes into, with this server's
limits in them (maximum vertices, triangles, resolution and deadline). Bearer
authentication is declared only when the server has tokens.
"""

from __future__ import annotations

from glraster._version import __version__
from glraster.service.models import for_config, json_schema_components

_ERROR = {"$ref": "#/components/responses/Error"}


def _parameters(query_schema: dict) -> list:
    """OpenAPI query parameters, one per property of a query model's JSON schema."""
    out = []
    for name, prop in query_schema["properties"].items():
        prop = dict(prop)
        description = prop.pop("description", None)
        param = {"name": name, "in": "query", "required": False, "schema": prop}
        if description:
            param["description"] = description
        out.append(param)
    return out


def schema(config=None) -> dict:
    """The OpenAPI document of a server with this
    :class:`~glraster.service.config.ServiceConfig` (default: the default flags; a fresh
    dict)."""
    from glraster.service.config import ServiceConfig

    config = config or ServiceConfig()
    bodies, queries = json_schema_components(for_config(config))
    auth = bool(config.tokens)
    refusals = ("400", *(("401", "403") if auth else ()), "406", "408", "413", "415", "422",
                "429", "503", "504")
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
            **({"securitySchemes": {"bearer": {
                "type": "http", "scheme": "bearer",
                "description": "This server has a token file: every endpoint but /healthz, "
                               "/readyz and /openapi.json needs Authorization: Bearer TOKEN "
                               "(401 missing or malformed, 403 not accepted)."}}}
               if auth else {}),
            "schemas": {**bodies, "Error": error, "RasterStats": stats},
            "responses": {"Error": {"description": "Refused; the body names the field.",
                                    "content": {"application/json": {
                                        "schema": {"$ref": "#/components/schemas/Error"}}}}},
        },
        **({"security": [{"bearer": []}]} if auth else {}),
        "paths": {
            "/v1/rasterize": {"post": {
                "operationId": "rasterize",
                "summary": "Rasterize a scene on the server's driver.",
                "description": "The scene as JSON or as an .npz of pos, tri and resolution "
                               "(options then as query parameters). The result by Accept: "
                               "JSON statistics, the arrays as .npz (bit for bit as "
                               "glraster.rasterize returns them, plus mask) or a glraster "
                               "EXR. " + limits_doc,
                "parameters": _parameters(queries["RasterizeQuery"]),
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
                    **{code: _ERROR for code in refusals},
                }}},
            "/v1/check": {"post": {
                "operationId": "check",
                "summary": "Run the conformance catalog (or chosen scenes) on the server's "
                           "driver.",
                "parameters": _parameters(queries["CheckQuery"]),
                "requestBody": {"required": False, "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/CheckRequest"}}}},
                "responses": {
                    "200": {"description": "The check result as JSON (with the JUnit XML "
                                           "in 'junit'), or JUnit XML for Accept "
                                           "application/xml.",
                            "content": {"application/json": {"schema": {"type": "object"}},
                                        "application/xml": {"schema": {"type": "string"}}}},
                    **{code: _ERROR for code in refusals},
                }}},
            "/v1/info": {"get": {
                "operationId": "info", "summary": "Driver, limits, workers and queue.",
                "responses": {"200": {"description": "Facts about this replica.",
                                      "content": {"application/json": {
                                          "schema": {"type": "object"}}}},
                              **({"401": _ERROR, "403": _ERROR} if auth else {})}}},
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
                              **({"401": _ERROR, "403": _ERROR} if auth else {})}}},
            "/openapi.json": {"get": {
                "operationId": "openapi", "summary": "This schema.", "security": [],
                "responses": {"200": {"description": "OpenAPI 3.1.", "content": {
                    "application/json": {"schema": {"type": "object"}}}}}}},
        },
    }
