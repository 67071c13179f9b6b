"""The service's wire formats: parsing requests and encoding results (runs in a worker).

Everything here works on bytes and plain values, never on paths taken from a request:
a request cannot name a file to read or write. Every problem with a request is a
:class:`RequestError` carrying the HTTP status and the name of the field at fault, which the
app turns into ``{"error": message, "field": name, "status": code}``.

Request bodies of ``POST /v1/rasterize`` (docs/service.md, docs/openapi.json):

- ``application/json``: ``{"pos": [[x, y, z, w], ...], "tri": [[i, j, k], ...],
  "resolution": [H, W]}`` plus the options below;
- ``application/x-npz``: arrays ``pos`` (V, 4), ``tri`` (T, 3), ``resolution`` (2,); the
  options come as query parameters (``?outputs=persp,depth&compare=true``).

The JSON body and the query parameters are decoded into the types of
:mod:`glraster.service.models`, which the OpenAPI schema is generated from; an option is
given in the body or in the query, not both.

Options: ``outputs`` (subset of persp, screen, depth, tri_id; default all), ``method``
(hw, divw, homogeneous, homogeneous64, solve4), ``reference`` (return the float64
reference instead of the GPU raster), ``compare`` (compare the GPU raster with the reference
under the method's error model), ``cull_backfaces``, ``crop`` (EXR: store only the covered
pixels' bounding box), ``samples`` (per pixel, 1 or a count the driver offers) and
``interpolation`` (center, centroid, sample): multisampled results carry per-sample arrays
(a sample axis after W) and ``sample_positions`` in the .npz, and have no EXR form.

Results by ``Accept``: ``application/json`` (statistics, the comparison), ``application/x-npz``
(the arrays, bit for bit as :func:`glraster.rasterize` returns them, plus ``mask``),
``image/x-exr`` (the multi-channel EXR of :mod:`glraster.io.exr`).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from msgspec import UNSET

from glraster import validate
from glraster.errors import ArgumentError
from glraster.io.npz import NpzError, npz_nbytes, read_npz, write_npz_into

from glraster.service.models import (  # the names of fields and options, re-exported
    ARRAY_FIELDS,
    CHECK_FIELDS,
    METHOD_NAMES,
    OPTION_FIELDS,
    OUTPUT_NAMES,
    ModelError,
    models,
)

JSON = "application/json"
NPZ = "application/x-npz"
EXR = "image/x-exr"
JUNIT = "application/xml"
RESULT_TYPES = {"json": JSON, "npz": NPZ, "exr": EXR}

# Rows of the arrays a request may hold, and their columns (for .npz member sizes).
_COLUMNS = {"pos": 4, "tri": 3}
_MAX_NPZ_MEMBERS = 8


class RequestError(Exception):
    """A request the service refuses: HTTP ``status`` (4xx), the ``field`` at fault, a
    message for people."""

    def __init__(self, status: int, field: str, message: str, headers: dict | None = None):
        super().__init__(message)
        self.status = int(status)
        self.field = field
        self.message = message
        self.headers = headers or {}

    def body(self) -> dict:
        return {"error": self.message, "field": self.field, "status": self.status}


def error_json(status: int, field: str, message: str) -> bytes:
    return json.dumps({"error": message, "field": field, "status": status}).encode()


# glraster's argument names (ArgumentError.argument) -> the request field that carries the
# value: glraster.rasterize and glraster.reference.rasterize take the request's fields
# under the same names; sample_positions is what the worker passes the reference for the
# request's samples. Any other argument is set by the service, not the client: "body".
ARGUMENT_FIELDS = {**{name: name for name in ARRAY_FIELDS + OPTION_FIELDS},
                   "sample_positions": "samples"}


def invalid(exc: ValueError, status: int = 422) -> "RequestError":
    """The :class:`RequestError` for a glraster ValueError about a request's values: the
    field of its ``.argument`` (:data:`ARGUMENT_FIELDS`; "body" when it names none)."""
    field_name = ARGUMENT_FIELDS.get(getattr(exc, "argument", None), "body")
    return RequestError(status, field_name, str(exc)[:500])


# -- options --------------------------------------------------------------------------------

_BOOL_OPTIONS = ("reference", "compare", "cull_backfaces", "crop")


def _refused(exc: ModelError) -> "RequestError":
    return RequestError(400 if exc.malformed else 422, exc.field, exc.message)


def query_options(query) -> dict:
    """The options given in a ``RasterizeQuery`` (strings, already checked against the
    model) as values: outputs a list, booleans bool."""
    out = {}
    for name in OPTION_FIELDS:
        value = getattr(query, name)
        if value is UNSET:
            continue
        if name == "outputs":
            value = value.split(",")
        elif name in _BOOL_OPTIONS:
            value = value == "true"
        out[name] = value
    return out


@dataclass
class RasterizeRequest:
    """A parsed, limit-checked ``POST /v1/rasterize``: arrays as given (validated in full
    by :func:`glraster.rasterize`), options checked."""

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple
    outputs: tuple = OUTPUT_NAMES
    method: str = "hw"
    reference: bool = False
    compare: bool = False
    cull_backfaces: bool = False
    crop: bool = False
    samples: int = 1
    interpolation: str = "center"


def _options(body_options: dict, query_options: dict) -> dict:
    """Options from the body and the query (an option in both is refused: which one would
    the client mean?), outputs in canonical order without repeats."""
    for key in query_options:
        if key in body_options:
            raise RequestError(422, key, f"{key} is given both in the body and as a query "
                                         "parameter; give it once")
    out = {**body_options, **query_options}
    if "outputs" in out:
        out["outputs"] = tuple(n for n in OUTPUT_NAMES if n in out["outputs"])
    return out


# -- the body -------------------------------------------------------------------------------

def _rows_limit(name: str, rows: int, limits) -> None:
    limit = {"pos": limits.max_vertices, "tri": limits.max_triangles}.get(name)
    if limit is not None and rows > limit:
        what = "vertices" if name == "pos" else "triangles"
        raise RequestError(413, name, f"{name} has {rows} rows, above this server's limit of "
                                      f"{limit} {what}")


def _npz_arrays(body, limits) -> dict:
    """The arrays of an .npz body (:func:`glraster.io.npz.read_npz`: stored members are
    read in place, deflated ones inflated). Every member's name, dtype and shape is checked
    against the limits before a byte of data is touched, so a zip bomb costs nothing."""

    def check(name, dtype, shape):
        if name not in ARRAY_FIELDS:
            raise RequestError(422, name[:40], f"unexpected array {name[:40]!r} in the .npz; "
                                               "expected pos, tri and resolution")
        if dtype.kind not in "biuf":
            raise RequestError(422, name, f"{name} must hold numbers, got dtype {dtype}")
        if shape:
            _rows_limit(name, int(shape[0]), limits)
        cap = limits.max_body_bytes if name != "resolution" else 4096
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > cap:
            raise RequestError(413, name, f"{name} takes {nbytes} bytes, above this server's "
                                          f"limit of {cap}")

    try:
        return read_npz(body, check=check, max_members=_MAX_NPZ_MEMBERS)
    except NpzError as exc:
        # the archive itself is unreadable: 400; a member of it is: 422 naming the member
        if exc.member is None:
            raise RequestError(400, "body", f"body is not a readable .npz: {exc.message}"[:300]) \
                from None
        raise RequestError(422, exc.member[:40] or "body", str(exc)[:300]) from None


def _resolution(value, limits, driver_max: int | None) -> tuple:
    """(height, width) from the request (glraster.validate's check), each at most the
    server's configured and the driver's maximum."""
    try:
        height, width = validate.resolution(value)
    except ArgumentError as exc:
        raise invalid(exc) from None
    limit = limits.max_resolution if driver_max is None else min(limits.max_resolution, driver_max)
    for axis, v in (("height", height), ("width", width)):
        if v > limit:
            raise RequestError(422, "resolution",
                               f"resolution {axis} {v} exceeds this server's maximum of {limit} "
                               f"(configured {limits.max_resolution}, driver "
                               f"{driver_max if driver_max is not None else 'unknown'})")
    return height, width


def _rows_error(exc: ModelError, limits) -> None:
    """msgspec's "pos: expected `array` of length <= N" is the vertex (triangle) limit: 413,
    as for .npz bodies."""
    if exc.field in ("pos", "tri") and exc.message.startswith(f"{exc.field}: expected "
                                                              "`array` of length <="):
        limit, what = ((limits.max_vertices, "vertices") if exc.field == "pos"
                       else (limits.max_triangles, "triangles"))
        raise RequestError(413, exc.field, f"{exc.field} has more than {limit} rows, this "
                                           f"server's limit of {what}")


def parse_rasterize(content_type: str, body: bytes, query: dict, limits,
                    driver_max: int | None = None) -> RasterizeRequest:
    """A :class:`RasterizeRequest` from a body (``application/json`` or
    ``application/x-npz``) and its query options (name -> string); RequestError naming the
    field. The JSON body is decoded straight into the request model
    (:mod:`glraster.service.models`), the one the OpenAPI schema is generated from."""
    m = models(limits)
    try:
        given_query = query_options(m.query("rasterize", query.items()))
    except ModelError as exc:
        raise _refused(exc) from None
    if content_type == JSON:
        try:
            scene = m.decode_rasterize(body)
        except ModelError as exc:
            _rows_error(exc, limits)
            raise _refused(exc) from None
        body_options = {k: getattr(scene, k) for k in OPTION_FIELDS
                        if getattr(scene, k) is not UNSET}
        pos = np.array(scene.pos, np.float64).reshape(-1, 4)
        tri = np.array(scene.tri, np.int64).reshape(-1, 3)
        resolution = scene.resolution
    elif content_type == NPZ:
        arrays = _npz_arrays(body, limits)
        for key in ARRAY_FIELDS:
            if key not in arrays:
                raise RequestError(422, key, f"missing array {key!r} in the .npz")
        pos, tri, resolution = arrays["pos"], arrays["tri"], arrays["resolution"]
        body_options = {}
    else:  # the app negotiates the content type first
        raise RequestError(415, "content-type", f"unsupported content type {content_type!r}")
    resolution = _resolution(resolution, limits, driver_max)
    req = RasterizeRequest(pos, tri, resolution, **_options(body_options, given_query))
    if req.reference and req.cull_backfaces:
        raise RequestError(422, "cull_backfaces", "cull_backfaces applies to the GPU raster; "
                                                  "the reference draws every triangle")
    if req.reference and req.method != "hw":
        raise RequestError(422, "method", "method chooses how the GPU computes barycentrics; "
                                          "it cannot be combined with reference")
    return req


@dataclass
class CheckRequest:
    """A parsed ``POST /v1/check``."""

    scenes: list
    method: str = "hw"
    golden: bool = True
    mutants: str | None = None
    shard: tuple | None = None


def parse_shard(value) -> tuple[int, int]:
    """``"I/N"`` as (I, N) with 1 <= I <= N; RequestError naming ``shard``."""
    try:
        i, n = (int(v) for v in str(value).split("/"))
    except ValueError:
        raise RequestError(422, "shard", f"shard must be I/N (e.g. 2/4), got {value!r}"[:200]) from None
    if not (1 <= i <= n <= 10_000):
        raise RequestError(422, "shard", f"shard I/N needs 1 <= I <= N, got {value!r}")
    return i, n


def parse_check(body: bytes, catalog: list, limits=None) -> CheckRequest:
    """A :class:`CheckRequest` from a JSON body (empty: the whole catalog), decoded into
    the model the OpenAPI schema is generated from."""
    import fnmatch

    from glraster.service.config import Limits

    body = bytes(body)
    try:
        doc = models(limits or Limits()).decode_check(body if body.strip() else b"{}")
    except ModelError as exc:
        raise _refused(exc) from None
    scenes = doc.scenes
    if scenes is UNSET:
        names = list(catalog)
    else:
        if isinstance(scenes, str):
            scenes = [s.strip() for s in scenes.split(",") if s.strip()]
        names = [n for n in catalog if any(fnmatch.fnmatchcase(n, p) for p in scenes)]
        if not names:
            raise RequestError(422, "scenes", f"no catalog scene matches {scenes[:8]}"[:300])
    mutants = doc.mutants
    mutants = "all" if mutants is True else (mutants or None)
    if mutants and doc.method != "hw":
        raise RequestError(422, "mutants", "mutants are faults in the hw shaders: use method hw")
    shard = parse_shard(doc.shard) if doc.shard is not None else None
    return CheckRequest(names, doc.method, doc.golden, mutants, shard)


# -- results --------------------------------------------------------------------------------

def _finite_list(values) -> list:
    return [float(v) if math.isfinite(v) else None for v in np.atleast_1d(values).tolist()]


def raster_stats(raster) -> dict:
    """Cheap statistics of a raster for the JSON result: covered pixels and, per output, the
    smallest and largest value over the whole frame and all channels (empty pixels hold
    barycentrics 0, depth 1, id -1); ``finite`` is false when some value is NaN or Inf
    (min / max are then null). Flat reductions only: well under a millisecond per MiB."""
    covered = int(np.count_nonzero(raster.mask))
    values = {}
    for name in OUTPUT_NAMES:
        a = getattr(raster, name)
        if a is None:
            continue
        lo, hi = a.min(), a.max()
        if name == "tri_id":
            values[name] = {"min": int(lo), "max": int(hi), "dtype": str(a.dtype)}
            continue
        finite = bool(np.isfinite(lo) and np.isfinite(hi))
        values[name] = {"min": float(lo) if finite else None,
                        "max": float(hi) if finite else None, "finite": finite,
                        "dtype": str(a.dtype)}
    return {"covered": covered, "values": values}


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return str(value)


def comparison_dict(evaluation) -> dict:
    """A :class:`glraster.conformance.check.Evaluation` as JSON-able data."""
    rep = evaluation.report
    return {
        "ok": bool(evaluation.ok),
        "failures": list(evaluation.failures),
        "covered_gpu": int(rep.covered_gpu), "covered_reference": int(rep.covered_ref),
        "coverage_mismatch": int(rep.coverage_mismatch),
        "coverage_mismatch_in_band": int(rep.coverage_mismatch_in_band),
        "tri_id_mismatch": int(rep.tri_id_mismatch),
        "nonfinite": int(evaluation.nonfinite),
        "values": {n: _jsonable(vars(v)) for n, v in rep.values.items()},
        "summary": rep.summary(),
    }


def encode_npz(raster, outputs, extra: dict | None = None, into=None):
    """The requested outputs of ``raster`` and its mask as an uncompressed .npz (arrays
    unchanged: bit for bit what the rasterizer returned); ``extra`` entries are stored as
    0-d JSON strings (e.g. ``comparison``). Written into ``into`` (a uint8 array the caller
    reuses) when it is large enough, else into a fresh one; returns a memoryview of the
    archive's bytes."""
    arrays = {n: getattr(raster, n) for n in outputs if getattr(raster, n) is not None}
    arrays["mask"] = raster.mask
    if getattr(raster, "samples", 1) > 1:
        arrays["sample_positions"] = raster.sample_positions
    for key, value in (extra or {}).items():
        arrays[key] = np.array(json.dumps(_jsonable(value)))
    size = npz_nbytes(arrays)
    out = into if into is not None and len(into) >= size else np.empty(size, np.uint8)
    write_npz_into(arrays, out)
    return memoryview(out)[:size]


_TMP = None


def _private_tmp() -> Path:
    """A folder only this worker writes to (EXR encoding goes through a file; its name
    never comes from the request)."""
    global _TMP
    if _TMP is None:
        base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
        _TMP = Path(tempfile.mkdtemp(prefix="glraster-service-", dir=base))
    return _TMP


def encode_exr(raster, outputs, crop: bool, metadata: dict) -> bytes:
    """The requested outputs as a glraster EXR (:func:`glraster.io.exr.write_raster`)."""
    from glraster.io import exr

    kept = {n: getattr(raster, n) for n in outputs if getattr(raster, n) is not None}
    path = _private_tmp() / f"result-{os.getpid()}-{time.monotonic_ns()}.exr"
    try:
        exr.write_raster(path, **kept, window="covered" if crop else "full", metadata=metadata)
        return path.read_bytes()
    finally:
        path.unlink(missing_ok=True)


def decode_npz_result(data) -> dict:
    """The arrays of an .npz result (for clients and tests): name -> array; ``comparison``
    decoded from JSON."""
    out = read_npz(data)
    if "comparison" in out:
        out["comparison"] = json.loads(str(out["comparison"]))
    return out


@dataclass
class Result:
    """What a worker answers: status, content type, extra headers, body bytes."""

    status: int
    content_type: str
    body: bytes
    headers: dict = field(default_factory=dict)
    cell_bytes: int = 0     # > 0: the body is in the job's shared-memory cell, not here
