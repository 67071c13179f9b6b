"""The conformance scene catalog.

Scenes ship with the package as recipes in ``glraster/scenes/data/catalog.json``: each entry
names a builder (see :mod:`glraster.conformance.scenes.builders`) and its parameters, so geometry is
generated deterministically (seeded) instead of being stored. A :class:`Scene` holds the
resulting clip-space geometry:

- ``pos``: (V, 4) float32 clip-space positions (the float64 recipe result rounded once);
- ``tri``: (T, 3) int32 vertex indices;
- ``resolution``: (height, width) in pixels;
- ``samples``, ``interpolation``: multisampling (catalog scenes tagged "multisample":
  S = 4 in the catalog, run by ``glraster check`` at every S the driver offers).

Users can also load their own scenes with :func:`load_scene_file` (``.npz`` or ``.json``),
which validates every field and raises ``ValueError`` naming the file and the field.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import zipfile
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError

from glraster.conformance.scenes.builders import BUILDERS

from glraster.types import OUTPUTS as ALL_OUTPUTS
MAX_RESOLUTION = 16384

# The fields a scene file may hold; any other is refused (a misspelt "samples" must not
# silently render one sample a pixel). Raw geometry (.json fields, .npz arrays) and recipes:
_OPTIONAL = ("name", "description", "outputs", "tags", "samples", "interpolation")
GEOMETRY_FIELDS = ("pos", "tri", "resolution") + _OPTIONAL
RECIPE_FIELDS = ("builder", "params", "resolution") + _OPTIONAL
NPZ_ARRAYS = ("pos", "tri", "resolution", "name", "samples", "interpolation")


@dataclass(frozen=True)
class Scene:
    """One scene: clip-space geometry and the viewport it is rendered at."""

    name: str
    pos: np.ndarray            # (V, 4) float32 clip space
    tri: np.ndarray            # (T, 3) int32 vertex indices
    resolution: tuple[int, int]  # (height, width)
    description: str = ""
    outputs: tuple[str, ...] = ALL_OUTPUTS
    tags: tuple[str, ...] = field(default_factory=tuple)
    samples: int = 1             # samples per pixel (rasterize(samples=))
    interpolation: str = "center"  # rasterize(interpolation=)

    @property
    def hash(self) -> str:
        """sha256 (hex, 16 chars) of resolution, pos and tri bytes: identifies the geometry."""
        return scene_hash(self.pos, self.tri, self.resolution)


def scene_hash(pos: np.ndarray, tri: np.ndarray, resolution) -> str:
    """Stable content hash of a scene: resolution as int64, pos as little-endian float32,
    tri as little-endian int32, all C-ordered. Returns 16 hex characters."""
    h = hashlib.sha256()
    h.update(np.asarray(resolution, dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(pos, dtype="<f4").tobytes())
    h.update(np.ascontiguousarray(tri, dtype="<i4").tobytes())
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def _catalog() -> dict[str, dict]:
    text = resources.files(__name__).joinpath("data/catalog.json").read_text()
    data = json.loads(text)
    out = {}
    for entry in data["scenes"]:
        if entry["name"] in out:
            raise RuntimeError(f"duplicate scene name in catalog: {entry['name']}")
        out[entry["name"]] = entry
    return out


def list_scenes(pattern: str | None = None) -> list[str]:
    """Names of the catalog scenes, in catalog order.

    pattern: optional shell-style pattern (``fnmatch``) or comma-separated list of
    patterns, e.g. ``"grid_*,torus"``."""
    names = list(_catalog())
    if not pattern:
        return names
    pats = [p.strip() for p in pattern.split(",") if p.strip()]
    return [n for n in names if any(fnmatch.fnmatchcase(n, p) for p in pats)]


def describe(name: str) -> str:
    """The catalog description of scene ``name``."""
    return _entry(name).get("description", "")


def _entry(name: str) -> dict:
    cat = _catalog()
    if name not in cat:
        raise ArgumentError("name", f"unknown scene {name!r}; known scenes: {', '.join(cat)}")
    return cat[name]


@lru_cache(maxsize=64)
def load_scene(name: str) -> Scene:
    """Build catalog scene ``name`` (cached; the arrays are read-only). A multisample
    scene at another sample count is ``<name>@<S>x`` (:func:`with_samples`)."""
    base, at, count = name.partition("@")
    if at:
        if not (count.endswith("x") and count[:-1].isdigit() and int(count[:-1]) >= 1):
            raise ArgumentError(
                "name", f"scene name {name!r}: a sample count is written <name>@<S>x, "
                         f"e.g. {base}@4x")
        scene = load_scene(base)
        if scene.samples == 1:
            raise ArgumentError("name",
                                f"scene name {name!r}: {base!r} is a single-sample scene")
        return with_samples(scene, int(count[:-1]))
    return build_scene(_entry(name), source=f"catalog scene {name!r}")


def build_scene(entry: dict, source: str = "scene") -> Scene:
    """Build a Scene from a recipe dict (the catalog format) and validate it."""
    for key in ("name", "resolution", "builder"):
        if key not in entry:
            raise ArgumentError("entry", f"{source}: missing field {key!r}")
    refuse_unknown(entry, RECIPE_FIELDS, "field", "recipe", source)
    fn = BUILDERS.get(entry["builder"])
    if fn is None:
        raise ArgumentError("entry", f"{source}: unknown builder {entry['builder']!r}; "
                                     f"known: {', '.join(sorted(BUILDERS))}")
    try:
        resolution = validate.resolution(entry["resolution"], MAX_RESOLUTION)
    except ArgumentError as exc:
        raise ArgumentError(exc.argument, f"{source}: {exc}") from None
    params = entry.get("params", {})
    if not isinstance(params, dict):
        raise ArgumentError("entry", f"{source}: params must be an object of the builder's "
                                     f"parameters, got {type(params).__name__}")
    try:
        pos, tri = fn(resolution, **params)
    except (TypeError, ValueError, IndexError) as exc:   # a parameter the builder cannot take
        raise ArgumentError("entry", f"{source}: bad parameters for builder "
                                     f"{entry['builder']!r}: {exc}") from exc
    outputs = tuple(entry.get("outputs", ALL_OUTPUTS))
    return make_scene(entry["name"], pos, tri, resolution, entry.get("description", ""),
                      outputs=outputs, tags=tuple(entry.get("tags", ())), source=source,
                      samples=entry.get("samples", 1),
                      interpolation=entry.get("interpolation", "center"))


def make_scene(name, pos, tri, resolution, description="", outputs=ALL_OUTPUTS, tags=(),
               source="scene", samples=1, interpolation="center") -> Scene:
    """Validate arrays and wrap them in a read-only Scene (pos -> float32, tri -> int32).
    Errors are glraster.validate's (the same ``.argument``), prefixed with ``source`` (the
    file or catalog entry)."""
    try:
        resolution = validate.resolution(resolution, MAX_RESOLUTION)
        pos32 = validate.positions(pos)
        tri32 = validate.triangles(tri, len(pos32))
        outputs = validate.outputs(outputs)
        samples = validate.samples(samples)
        interpolation = validate.interpolation(interpolation)
    except ArgumentError as exc:        # the argument at fault, its message after the source
        raise ArgumentError(exc.argument, f"{source}: {exc}") from None
    pos32.setflags(write=False)
    tri32.setflags(write=False)
    return Scene(str(name), pos32, tri32, resolution, description, tuple(outputs), tuple(tags),
                 samples, interpolation)


def with_samples(scene: Scene, samples: int) -> Scene:
    """A multisample scene at another sample count, named ``<name>@<S>x`` (the scene's
    own count keeps the name)."""
    from dataclasses import replace

    if samples == scene.samples:
        return scene
    return replace(scene, samples=samples, name=f"{scene.name}@{samples}x")


def load_scene_file(path) -> Scene:
    """Load a user scene file.

    ``.npz``: arrays ``pos`` (V, 4) clip space, ``tri`` (T, 3) integer, ``resolution``
    (2,) = (height, width); optional ``name`` (string), ``samples`` (int, samples per
    pixel) and ``interpolation`` (string), 0-d arrays.
    ``.json``: either ``{"pos": [[x, y, z, w], ...], "tri": [[i, j, k], ...],
    "resolution": [H, W]}`` or a catalog-style recipe ``{"name", "resolution",
    "builder", "params"}``; both may add ``name``, ``description``, ``outputs``, ``tags``,
    ``samples`` and ``interpolation`` (:data:`GEOMETRY_FIELDS`, :data:`RECIPE_FIELDS`).
    Raises ValueError naming the file and the faulty field; a field or array the format
    does not have is refused, not ignored.
    """
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ArgumentError("path", f"{src}: no such scene file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        if not zipfile.is_zipfile(path):     # (np.load would say "pickled data")
            raise ArgumentError("path", f"{src}: not a .npz file (not a zip archive)")
        try:
            data = np.load(path, allow_pickle=False)
        except Exception as exc:  # zipfile/pickle errors from a corrupt file
            raise ArgumentError("path", f"{src}: not a readable .npz file ({exc})") from None
        with data:
            missing = [k for k in ("pos", "tri", "resolution") if k not in data.files]
            if missing:
                raise ArgumentError("path", f"{src}: missing array(s) {', '.join(missing)} "
                                            f"(found: {', '.join(data.files) or 'none'})")
            refuse_unknown(data.files, NPZ_ARRAYS, "array", "scene file", src)
            arrays = {}
            for key in NPZ_ARRAYS:
                if key in data.files:
                    try:
                        arrays[key] = data[key]
                    except ValueError as exc:   # an object array needs pickle: refused
                        raise ArgumentError("path", f"{src}: array {key!r} cannot be read "
                                                    f"({exc})") from None
            name = str(arrays["name"]) if "name" in arrays else path.stem
            return make_scene(name, arrays["pos"], arrays["tri"], arrays["resolution"],
                              source=src, samples=_scalar(arrays.get("samples", 1)),
                              interpolation=str(arrays.get("interpolation", "center")))
    if suffix == ".json":
        try:
            entry = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ArgumentError("path", f"{src}: invalid JSON ({exc})") from None
        if not isinstance(entry, dict):
            raise ArgumentError("path", f"{src}: top level must be a JSON object")
        if "builder" in entry:
            entry = dict(entry)
            entry.setdefault("name", path.stem)
            return build_scene(entry, source=src)
        missing = [k for k in ("pos", "tri", "resolution") if k not in entry]
        if missing:
            raise ArgumentError("path", f"{src}: missing field(s) {', '.join(missing)}")
        refuse_unknown(entry, GEOMETRY_FIELDS, "field", "scene file", src)
        try:
            pos = np.array(entry["pos"], dtype=np.float64)
            tri = np.array(entry["tri"])             # integers stay integers
        except (TypeError, ValueError) as exc:
            raise ArgumentError(
                "path", f"{src}: pos and tri must be rectangular numeric lists ({exc})") from None
        return make_scene(entry.get("name", path.stem), pos, tri, entry["resolution"],
                          entry.get("description", ""),
                          outputs=tuple(entry.get("outputs", ALL_OUTPUTS)),
                          tags=tuple(entry.get("tags", ())), source=src,
                          samples=entry.get("samples", 1),
                          interpolation=entry.get("interpolation", "center"))
    raise ArgumentError(
        "path", f"{src}: unsupported scene file type {suffix!r} (use .npz or .json)")


def refuse_unknown(keys, known, kind: str, holder: str, source: str) -> None:
    """ArgumentError naming the ``kind``s ("field", "array") of ``keys`` not in ``known``,
    the ones a ``holder`` ("scene file", "recipe", "views file") may hold."""
    unknown = [k for k in keys if k not in known]
    if unknown:
        article = "an" if holder[0] in "aeiou" else "a"
        raise ArgumentError(
            "path", f"{source}: unknown {kind}{'s' if len(unknown) > 1 else ''} "
                    f"{', '.join(map(repr, unknown))}; {article} {holder}'s {kind}s are "
                    f"{', '.join(known)}")


def _scalar(value):
    """A 0-d (or 1-element) .npz array as its Python value; anything else unchanged (for
    validate to name)."""
    value = np.asarray(value)
    return value.item() if value.size == 1 else value


def resolve(name_or_path) -> Scene:
    """A catalog scene by name (``<name>@<S>x`` for a multisample scene at S samples), or a
    user scene file by path."""
    s = str(name_or_path)
    if s.partition("@")[0] in _catalog():
        return load_scene(s)
    if Path(s).suffix.lower() in (".npz", ".json") or Path(s).exists():
        return load_scene_file(s)
    raise ArgumentError("name_or_path", f"{s!r} is neither a catalog scene nor a scene file; "
                                        f"known scenes: {', '.join(_catalog())}")


__all__ = ["Scene", "list_scenes", "load_scene", "load_scene_file", "make_scene",
           "build_scene", "scene_hash", "describe", "resolve", "ALL_OUTPUTS"]
