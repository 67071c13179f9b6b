"""What a dataset is: the scenes ``glraster batch`` renders, in a fixed order.

A dataset source is one of

- a folder: every ``.npz`` and ``.json`` scene file below it (as ``glraster render`` reads
  them, :func:`glraster.conformance.scenes.load_scene_file`), in sorted path order;
- a ``.txt`` list: one scene file per line (relative to the list's folder; ``#`` comments);
- a list of scene file paths (Python);
- a views file, ``.json`` with a mesh and a camera list::

      {"mesh": "bunny.obj",              # .npz with vertices (V, 3), faces (T, 3); or any
                                         # trimesh format (the mesh extra)
       "resolution": [H, W],
       "outputs": ["persp", "tri_id"],   # optional, default all four
       "samples": 4,                     # optional: samples per pixel (default 1)
       "interpolation": "sample",        # optional: center, centroid or sample
       "cameras": [
         {"view": 4x4, "proj": 4x4},                                # OpenGL matrices
         {"K": 3x3, "R": 3x3, "t": [3], "near": 0.1, "far": 100},   # OpenCV camera
         {"eye": [3], "target": [3], "up": [3], "fovy": 40, "near": 0.1, "far": 100}]}

  One scene per camera, named ``<views file>#<index>``. A field the file or a camera form
  does not have (a misspelt ``"sample"``, a camera mixing two forms) is an error naming it.

Items are plain strings (a path, or ``path#index``), cheap to ship to workers; a worker
loads each with :func:`load_item` (a views file's mesh once per worker).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from glraster.errors import ArgumentError

SCENE_SUFFIXES = (".npz", ".json")

# A views file's fields, and each camera form's: any other is refused, as in scene files.
VIEWS_FIELDS = ("mesh", "resolution", "cameras", "outputs", "samples", "interpolation")
CAMERA_FORMS = {"view": ("view", "proj"),
                "K": ("K", "R", "t", "near", "far"),
                "eye": ("eye", "target", "up", "fovy", "near", "far")}


def _is_views_file(path: Path) -> bool:
    if path.suffix.lower() != ".json" or not path.is_file():
        return False
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and "cameras" in data and "mesh" in data


def list_items(source) -> list:
    """The dataset's items (str) in render order; ValueError naming ``source`` when it is
    none of the forms above or holds no scene."""
    if isinstance(source, (list, tuple)):
        items = [str(p) for p in source]
    else:
        path = Path(source)
        if path.is_dir():
            items = sorted(str(p) for p in path.rglob("*")
                           if p.suffix.lower() in SCENE_SUFFIXES and p.is_file()
                           and not p.name.startswith("."))
        elif path.suffix.lower() == ".txt" and path.is_file():
            items = []
            for line in path.read_text().splitlines():
                line = line.strip()
                if line and not line.startswith("#"):
                    p = Path(line)
                    items.append(str(p if p.is_absolute() else path.parent / p))
        elif _is_views_file(path):
            views = _views(str(path))
            items = [f"{path}#{i}" for i in range(len(views["cameras"]))]
        elif path.exists():
            raise ArgumentError(
                "source", f"source {str(source)!r} must be a folder of scene files, a .txt "
                          "list of them, or a .json views file (mesh and cameras)")
        else:
            raise ArgumentError("source", f"source {str(source)!r} does not exist")
    if not items:
        raise ArgumentError("source", f"source {str(source)!r} holds no scene (.npz or .json) file")
    return items


@lru_cache(maxsize=4)
def _views(path: str) -> dict:
    """A views file, checked: {"mesh": Mesh, "resolution", "outputs", "samples",
    "interpolation", "cameras": [(view, proj)]} (the mesh loaded once per process)."""
    from glraster import validate
    from glraster.conformance.scenes import refuse_unknown
    from glraster.geometry import camera
    from glraster.geometry.mesh import Mesh, load_mesh

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ArgumentError("path", f"{path}: not a readable JSON views file ({exc})") from None
    for key in ("mesh", "resolution", "cameras"):
        if key not in data:
            raise ArgumentError("path", f"{path}: views file lacks {key!r}")
    refuse_unknown(data, VIEWS_FIELDS, "field", "views file", path)
    if not isinstance(data["cameras"], list) or not data["cameras"]:
        raise ArgumentError("path", f"{path}: cameras must be a non-empty list")
    try:
        resolution = validate.resolution(data["resolution"])
        outputs = validate.outputs(tuple(data.get("outputs", ("persp", "screen", "depth",
                                                             "tri_id"))))
        samples = validate.samples(data.get("samples", 1))
        interpolation = validate.interpolation(data.get("interpolation", "center"))
    except ArgumentError as exc:
        raise ArgumentError(exc.argument, f"{path}: {exc}") from None
    mesh_path = Path(data["mesh"])
    if not mesh_path.is_absolute():
        mesh_path = Path(path).parent / mesh_path
    if mesh_path.suffix.lower() == ".npz":
        try:
            with np.load(mesh_path, allow_pickle=False) as z:
                mesh = Mesh(z["vertices"], z["faces"])
        except (OSError, KeyError, ValueError) as exc:
            raise ArgumentError(
                "path", f"{path}: mesh {str(mesh_path)!r}: {exc} (a mesh .npz holds "
                        "vertices (V, 3) and faces (T, 3))") from None
    else:
        mesh = load_mesh(str(mesh_path))
    height, width = resolution
    cameras = []
    for i, cam in enumerate(data["cameras"]):
        if not isinstance(cam, dict):
            raise ArgumentError("path", f"{path}: camera {i} must be an object, got "
                                        f"{type(cam).__name__}")
        form = next((CAMERA_FORMS[key] for key in ("view", "K", "eye") if key in cam),
                    CAMERA_FORMS["view"] if "proj" in cam else None)
        if form is not None:   # "a K/R/t camera's fields are K, R, t, near, far"
            refuse_unknown(cam, form, "field", f"{'/'.join(form[:3])} camera",
                           f"{path}: camera {i}")
        try:
            if "view" in cam or "proj" in cam:
                view, proj = cam.get("view"), cam.get("proj")
            elif "K" in cam:
                view = camera.view_from_opencv(cam["R"], cam["t"])
                proj = camera.from_intrinsics(cam["K"], width, height, cam["near"], cam["far"])
            elif "eye" in cam:
                view = camera.look_at(cam["eye"], cam["target"], cam.get("up", (0, 1, 0)))
                proj = camera.perspective(cam["fovy"], width / height, cam["near"], cam["far"])
            else:
                raise ValueError("needs view/proj, K/R/t/near/far or eye/target/fovy/near/far")
            cameras.append((validate.matrix4("view", view), validate.matrix4("proj", proj)))
        except KeyError as exc:
            raise ArgumentError("path", f"{path}: camera {i} lacks {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ArgumentError("path", f"{path}: camera {i}: {exc}") from None
    return {"mesh": mesh, "resolution": resolution, "outputs": outputs, "samples": samples,
            "interpolation": interpolation, "cameras": cameras}


def load_item(item: str):
    """The :class:`glraster.conformance.scenes.Scene` of one item (ValueError when it
    cannot be read)."""
    from glraster.conformance.scenes import load_scene_file, make_scene

    path, sep, index = item.rpartition("#")
    if sep and index.isdigit() and path.lower().endswith(".json") and _is_views_file(Path(path)):
        views = _views(path)
        k = int(index)
        if k >= len(views["cameras"]):
            raise ArgumentError(
                "item", f"{item}: the views file has {len(views['cameras'])} cameras")
        from glraster.geometry.camera import project

        view, proj = views["cameras"][k]
        mesh = views["mesh"]
        return make_scene(Path(item).name, project(mesh.vertices, view=view, proj=proj),
                          mesh.faces, views["resolution"], outputs=views["outputs"],
                          source=item, samples=views["samples"],
                          interpolation=views["interpolation"])
    return load_scene_file(item)
