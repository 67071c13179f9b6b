"""The service's request models: one msgspec type per request part, the single source of
both the OpenAPI schema (:mod:`glraster.service.openapi`) and the parser
(:mod:`glraster.service.protocol`), so that a request the schema calls valid is accepted
and one it calls invalid is refused with a 4xx naming its field.

The types depend on the server's limits (the schema a server publishes states its own
maximum vertex and triangle counts, resolution and deadline), so they are built per
:class:`~glraster.service.config.Limits` by :func:`models` and cached.

Parts of a request and their types:

- ``RasterizeBody``: the ``application/json`` body of ``POST /v1/rasterize``: ``pos``
  (V, 4) numbers within float32's range, ``tri`` (T, 3) integers in [0, max_vertices),
  ``resolution`` [H, W] integers in [1, max_resolution], and the options;
- ``RasterizeQuery``: its query parameters (the options of ``.npz`` bodies, as strings, and
  ``deadline``);
- ``CheckBody`` / ``CheckQuery``: ``POST /v1/check``.

What JSON Schema cannot state is checked after decoding, with the same 4xx and field, and
said in the schema's descriptions (:data:`CROSS_FIELD_RULES`).
"""

from __future__ import annotations

import functools
import re
from typing import Annotated, Literal, Union

import msgspec
from msgspec import UNSET, Meta, UnsetType

OUTPUT_NAMES = ("persp", "screen", "depth", "tri_id")
METHOD_NAMES = ("hw", "divw", "homogeneous", "homogeneous64", "solve4")
INTERPOLATION_NAMES = ("center", "centroid", "sample")
OPTION_FIELDS = ("outputs", "method", "reference", "compare", "cull_backfaces", "crop",
                 "samples", "interpolation")
# The largest sample count a request may name; whether the driver offers it is
# glraster.rasterize's to say (422 naming samples).
MAX_SAMPLES = 64
ARRAY_FIELDS = ("pos", "tri", "resolution")
CHECK_FIELDS = ("scenes", "method", "golden", "mutants", "shard")

# The largest finite float32: pos is converted to float32 once (DESIGN, Conventions), so a
# larger magnitude would become infinity.
FLOAT32_MAX = 3.4028234663852886e38

# The shortest deadline a request may ask for, seconds. A request that misses its deadline
# costs its worker (killed and replaced: a new context and probe, a second or more), so a
# deadline below this would cost the service more than the request; it is a guard against
# a hung driver, not a latency target.
MIN_DEADLINE = 1.0
# A conformance check runs at least one scene, its reference and its golden comparison:
# seconds, not milliseconds.
MIN_CHECK_DEADLINE = 10.0

# Rules between fields that JSON Schema cannot state; the parser enforces each (422 naming
# the field) and the schema's descriptions say them.
CROSS_FIELD_RULES = (
    "every index of tri is below the number of rows of pos",
    "an option is given in the JSON body or as a query parameter, not both",
    "reference excludes cull_backfaces and a method other than hw (they choose how the GPU "
    "renders)",
    "samples is 1 or a count the server's driver offers (GET /v1/info, driver.sample_counts)",
    "interpolation other than center needs method hw or divw",
    "samples above 1 has no EXR form (406)",
)
CHECK_RULES = (
    "scenes match at least one catalog scene",
    "mutants needs method hw, and a mutant pattern matches at least one mutant",
    "shard I/N has 1 <= I <= N",
)

Output = Literal["persp", "screen", "depth", "tri_id"]
Method = Literal["hw", "divw", "homogeneous", "homogeneous64", "solve4"]
Interpolation = Literal["center", "centroid", "sample"]
QueryBool = Literal["true", "false"]

_OUTPUT_LIST = "(persp|screen|depth|tri_id)(,(persp|screen|depth|tri_id))*"
# a list of names or fnmatch patterns, comma-separated: at least one non-empty name
_SCENE_LIST = r"[^,\s]"
_SHARD = r"^[1-9][0-9]{0,3}/[1-9][0-9]{0,3}$"


def _doc(text: str, default=UNSET, **meta) -> Meta:
    extra = {} if default is UNSET else {"default": default}
    return Meta(description=text, extra_json_schema=extra or None, **meta)


_OPTION_DOCS = {
    "outputs": "Outputs to render and return (default: all four).",
    "method": "How the GPU computes barycentrics (README, Methods).",
    "reference": "Return the float64 reference raster instead of the GPU's (rounded to "
                 "float32 in EXR).",
    "compare": "Compare the GPU raster with the float64 reference under the method's "
               "per-pixel error model; the report is in the JSON result, the .npz entry "
               "'comparison' and the X-Glraster-Comparison header.",
    "cull_backfaces": "Drop clockwise triangles (GPU only).",
    "crop": "EXR: store only the covered pixels' bounding box (lossless).",
    "samples": "Samples per pixel: 1 or a count the driver offers (README, Multisampling); "
               "per-sample arrays have a sample axis after W and the .npz holds "
               "sample_positions. No EXR form (406).",
    "interpolation": "Where multisampled barycentrics are evaluated: the pixel centre, a "
                     "centroid or every sample (GLSL's qualifiers).",
}


class Models:
    """The request types of one server's limits (attributes are msgspec types)."""

    def __init__(self, limits, max_deadline: float, max_check_deadline: float):
        self.limits = limits
        coord = Annotated[float, Meta(ge=-FLOAT32_MAX, le=FLOAT32_MAX)]
        index = Annotated[int, Meta(ge=0, le=max(0, limits.max_vertices - 1))]
        side = Annotated[int, Meta(ge=1, le=limits.max_resolution)]
        pos = Annotated[list[Annotated[list[coord], Meta(min_length=4, max_length=4)]],
                        _doc("(V, 4) clip-space positions (x, y, z, w), V <= "
                             f"{limits.max_vertices}.", max_length=limits.max_vertices)]
        tri = Annotated[list[Annotated[list[index], Meta(min_length=3, max_length=3)]],
                        _doc("(T, 3) vertex indices into pos, T <= "
                             f"{limits.max_triangles}.", max_length=limits.max_triangles)]
        resolution = Annotated[list[side], _doc("(height, width) in pixels.", min_length=2,
                                                max_length=2)]
        samples = Annotated[int, _doc(_OPTION_DOCS["samples"], 1, ge=1, le=MAX_SAMPLES)]
        interpolation = Annotated[Interpolation, _doc(_OPTION_DOCS["interpolation"], "center")]
        body_options = {
            "outputs": Annotated[list[Output], _doc(_OPTION_DOCS["outputs"],
                                                    list(OUTPUT_NAMES), min_length=1)],
            "method": Annotated[Method, _doc(_OPTION_DOCS["method"], "hw")],
            **{n: Annotated[bool, _doc(_OPTION_DOCS[n], False)]
               for n in ("reference", "compare", "cull_backfaces", "crop")},
            "samples": samples,
            "interpolation": interpolation,
        }
        self.RasterizeBody = msgspec.defstruct(
            "Scene",
            [("pos", pos), ("tri", tri), ("resolution", resolution),
             *((name, Union[kind, UnsetType], UNSET) for name, kind in body_options.items())],
            forbid_unknown_fields=True)
        self.RasterizeBody.__doc__ = (
            "A scene and its options. Rules the schema cannot state: "
            + "; ".join(CROSS_FIELD_RULES) + ".")

        max_deadline = max(max_deadline, MIN_DEADLINE)
        deadline = Annotated[float, _doc(
            "Seconds from arrival after which the request is cancelled (504) and its worker "
            f"replaced; at least {MIN_DEADLINE:g}, at most this server's maximum.",
            ge=MIN_DEADLINE, le=max_deadline)]
        check_deadline = Annotated[float, _doc(
            "Seconds from arrival after which the check is cancelled (504) and its worker "
            f"replaced; at least {MIN_CHECK_DEADLINE:g}.", ge=MIN_CHECK_DEADLINE,
            le=max(max_check_deadline, MIN_CHECK_DEADLINE))]
        query_options = {
            "outputs": Annotated[str, _doc("Comma-separated outputs (for .npz bodies; JSON "
                                           "bodies may carry the options themselves).",
                                           "persp,screen,depth,tri_id",
                                           pattern=f"^{_OUTPUT_LIST}$")],
            "method": Annotated[Method, _doc(_OPTION_DOCS["method"], "hw")],
            **{n: Annotated[QueryBool, _doc(_OPTION_DOCS[n], "false")]
               for n in ("reference", "compare", "cull_backfaces", "crop")},
            "samples": samples,
            "interpolation": interpolation,
        }
        self.RasterizeQuery = msgspec.defstruct(
            "RasterizeQuery",
            [*((name, Union[kind, UnsetType], UNSET) for name, kind in query_options.items()),
             ("deadline", Union[deadline, UnsetType], UNSET)],
            forbid_unknown_fields=True)
        self.CheckQuery = msgspec.defstruct(
            "CheckQuery", [("deadline", Union[check_deadline, UnsetType], UNSET)],
            forbid_unknown_fields=True)

        scenes = Union[
            Annotated[str, Meta(pattern=_SCENE_LIST)],
            Annotated[list[Annotated[str, Meta(min_length=1)]], Meta(min_length=1)]]
        self.CheckBody = msgspec.defstruct(
            "CheckRequest",
            [("scenes", Annotated[Union[scenes, UnsetType], _doc(
                "Catalog scene names or fnmatch patterns, a list or comma-separated "
                "(default: every scene).")], UNSET),
             ("method", Annotated[Method, _doc("How the GPU computes barycentrics.", "hw")],
              "hw"),
             ("golden", Annotated[bool, _doc("Also compare with the golden EXRs (where the "
                                             "server has them).", True)], True),
             ("mutants", Annotated[Union[bool, Annotated[str, Meta(min_length=1)]], _doc(
                 "Also run the fault-injection mutants (true, or a name pattern); method hw "
                 "only.", False)], False),
             ("shard", Annotated[Union[Annotated[str, Meta(pattern=_SHARD)], None], _doc(
                 "Check only shard I/N of the chosen scenes (1 <= I <= N).")], None)],
            forbid_unknown_fields=True)
        self.CheckBody.__doc__ = ("A conformance check. Rules the schema cannot state: "
                                  + "; ".join(CHECK_RULES) + ".")
        self._rasterize_decoder = msgspec.json.Decoder(self.RasterizeBody)
        self._check_decoder = msgspec.json.Decoder(self.CheckBody)

    def decode_rasterize(self, body):
        """The JSON body as a ``RasterizeBody``; :class:`ModelError` when it is not one."""
        return _decode(self._rasterize_decoder, self.RasterizeBody, body)

    def decode_check(self, body):
        return _decode(self._check_decoder, self.CheckBody, body)

    def query(self, kind: str, items) -> object:
        """The query parameters ``items`` ((name, value) pairs) as a ``RasterizeQuery``
        (``kind`` "rasterize") or ``CheckQuery``; :class:`ModelError` naming the parameter
        (unknown, given twice or invalid)."""
        model = self.RasterizeQuery if kind == "rasterize" else self.CheckQuery
        given = {}
        for key, value in items:
            if key in given:
                raise ModelError(key, f"query parameter {key[:40]!r} is given twice")
            given[key] = value
        try:
            # strict=False: query values are strings, deadline is converted to a number
            return msgspec.convert(given, model, strict=False)
        except msgspec.ValidationError as exc:
            raise _model_error(str(exc), "query", "query parameter") from None


class ModelError(Exception):
    """A request part that is not an instance of its model: the ``field`` (the top-level
    name, or ``"body"`` for the body as a whole), a message naming the exact place, and
    whether the body was not JSON at all (``malformed``: 400, else 422)."""

    def __init__(self, field: str, message: str, malformed: bool = False):
        super().__init__(message)
        self.field = field
        self.message = message
        self.malformed = malformed


_AT = re.compile(r"^(?P<what>.*?)(?: - at `\$(?P<path>[^`]*)`)?$", re.S)
_NAMED = re.compile(r"(?:unknown|required) field `(?P<name>[^`]*)`")


def _model_error(text: str, root: str, noun: str = "field") -> ModelError:
    """msgspec's message ("Expected `int` >= 0 - at `$.tri[0][1]`") as a ModelError whose
    field is the first name of the path (``tri``) and whose message starts with the path."""
    m = _AT.match(text)
    what, path = m.group("what"), m.group("path") or ""
    name = re.match(r"^\.([A-Za-z_][A-Za-z0-9_]*)", path)
    if name:
        field = name.group(1)
        where = path[1:]
    else:
        named = _NAMED.search(what)
        field = (named.group("name")[:40] if named else "") or root
        where = root if not named else field
    message = what[:1].lower() + what[1:]
    message = message.replace("object missing required field", f"missing {noun}") \
                     .replace("object contains unknown field", f"unknown {noun}")
    return ModelError(field, f"{where}: {message}"[:300])


def _integral_as_int(value):
    """``value`` (decoded JSON) with every integral float as an int: JSON Schema's
    ``integer`` is a mathematical integer however it is spelled (``1.0`` is one)."""
    if isinstance(value, float):
        return int(value) if value.is_integer() else value
    if isinstance(value, list):
        return [_integral_as_int(v) for v in value]
    if isinstance(value, dict):
        return {k: _integral_as_int(v) for k, v in value.items()}
    return value


def _decode(decoder, model, body):
    try:
        try:
            return decoder.decode(body)
        except msgspec.ValidationError as exc:
            if "expected `int`, got `float`" not in str(exc).lower():
                raise
        # the slow path, only for bodies spelling an integer as 1.0
        return msgspec.convert(_integral_as_int(msgspec.json.decode(body)), model)
    except msgspec.ValidationError as exc:
        err = _model_error(str(exc), "body")
        # the body as a whole has the wrong type (an array, a number): unreadable, 400
        err.malformed = err.field == "body"
        raise err from None
    except msgspec.DecodeError as exc:
        raise ModelError("body", f"body is not valid JSON: {exc}"[:300], True) from None


@functools.lru_cache(maxsize=8)
def models(limits, max_deadline: float | None = None,
           max_check_deadline: float | None = None) -> Models:
    """The request models of a server with these :class:`~glraster.service.config.Limits`
    and largest deadlines a request may ask for (seconds; default ``limits.max_deadline``)."""
    max_deadline = limits.max_deadline if max_deadline is None else max_deadline
    return Models(limits, max_deadline,
                  max_deadline if max_check_deadline is None else max_check_deadline)


def for_config(config) -> Models:
    """The models of a :class:`~glraster.service.config.ServiceConfig` (its deadlines: a
    request may ask for up to the larger of the default and the configured maximum)."""
    cap = max(config.deadline, config.limits.max_deadline)
    return models(config.limits, cap, max(config.check_deadline, cap))


def json_schema_components(m: Models) -> tuple[dict, dict]:
    """(the schemas of the JSON bodies by name, those of the query models by name), in
    OpenAPI form (references to ``#/components/schemas/...``)."""
    (_, bodies) = msgspec.json.schema_components(
        [m.RasterizeBody, m.CheckBody], ref_template="#/components/schemas/{name}")
    (_, queries) = msgspec.json.schema_components(
        [m.RasterizeQuery, m.CheckQuery], ref_template="#/components/schemas/{name}")
    return bodies, queries
