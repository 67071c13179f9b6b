"""Triangle meshes from files, trimesh and pyrender scenes.

:func:`load_mesh` reads OBJ / PLY / GLB / GLTF / STL (anything trimesh reads) into a small
:class:`Mesh`.  :func:`scene_geometry` flattens a mesh or a whole scene (trimesh or
pyrender: meshes with their poses and, for pyrender, its camera) into world-space
triangles plus view and projection matrices (:func:`glraster.render_scene`, in gpu.render,
rasterizes that).

trimesh and pyrender are optional dependencies (the ``mesh`` extra); they are imported
only when used.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError
from glraster.geometry import camera as cam

__all__ = ["Mesh", "SceneGeometry", "load_mesh", "scene_geometry",
           "framing_camera"]

GL_TRIANGLES = 4  # pyrender Primitive.mode for triangle lists


@dataclass(frozen=True)
class Mesh:
    """An indexed triangle mesh.

    vertices : (V, 3) float64  positions (object or world units)
    faces    : (T, 3) int64    vertex indices, counter-clockwise front faces
    uv       : (V, 2) float64 or None  texture coordinates, when the source has them
    normals  : (V, 3) float64 or None  vertex normals, when the source has them
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ArgumentError("vertices", f"vertices must have shape (V, 3), got {v.shape}")
        f = np.asarray(self.faces)
        if f.ndim != 2 or f.shape[1] != 3:
            raise ArgumentError("faces", f"faces must have shape (T, 3), got {f.shape}")
        if f.size and f.dtype.kind not in "iu":
            raise ArgumentError("faces", f"faces must hold integers, got dtype {f.dtype}")
        f = np.ascontiguousarray(f, dtype=np.int64)
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ArgumentError("faces", f"faces index vertices 0..{len(v) - 1}, got indices in "
                                         f"[{f.min()}, {f.max()}]")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        for name, width in (("uv", 2), ("normals", 3)):
            a = getattr(self, name)
            if a is not None:
                a = np.ascontiguousarray(a, dtype=np.float64)
                if a.shape != (len(v), width):
                    raise ArgumentError(name, f"{name} must have shape ({len(v)}, {width}), "
                                              f"got {a.shape}")
                object.__setattr__(self, name, a)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """(center (3,), radius): the bounding box center and the farthest vertex from it."""
        if len(self.vertices) == 0:
            return np.zeros(3), 0.0
        c = (self.vertices.min(0) + self.vertices.max(0)) / 2
        return c, float(np.linalg.norm(self.vertices - c, axis=1).max())

    def transformed(self, matrix) -> "Mesh":
        """Copy with positions mapped by a (4, 4) affine ``matrix`` (normals by its inverse
        transpose, renormalized)."""
        m = validate.float_array("matrix", matrix, (4, 4))
        v = self.vertices @ m[:3, :3].T + m[:3, 3]
        n = None
        if self.normals is not None:
            n = self.normals @ np.linalg.inv(m[:3, :3])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return Mesh(v, self.faces, self.uv, n)

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def _from_trimesh(tm) -> Mesh:
    uv = None
    visual = getattr(tm, "visual", None)
    if getattr(visual, "kind", None) == "texture" and getattr(visual, "uv", None) is not None:
        if len(visual.uv) == len(tm.vertices):
            uv = np.asarray(visual.uv, dtype=np.float64)
    # trimesh keeps normals read from the file in its cache; anything else it would compute.
    normals = None
    if "vertex_normals" in tm._cache.cache:
        normals = np.asarray(tm.vertex_normals, dtype=np.float64)
    return Mesh(np.asarray(tm.vertices), np.asarray(tm.faces), uv, normals)


def _merge(meshes: list[Mesh]) -> Mesh:
    if not meshes:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    v = np.concatenate([m.vertices for m in meshes])
    f = np.concatenate([m.faces + o for m, o in zip(meshes, offsets)])
    uv = (np.concatenate([m.uv for m in meshes])
          if all(m.uv is not None for m in meshes) else None)
    n = (np.concatenate([m.normals for m in meshes])
         if all(m.normals is not None for m in meshes) else None)
    return Mesh(v, f, uv, n)


def _trimesh_scene_to_mesh(scene) -> Mesh:
    import trimesh

    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh):
            continue  # paths and point clouds have no triangles
        parts.append(_from_trimesh(geom).transformed(transform))
    return _merge(parts)


def load_mesh(source) -> Mesh:
    """Load a triangle mesh.

    Args:
        source: a path to an OBJ, PLY, GLB/GLTF, STL (or other trimesh-readable) file, a
            ``trimesh.Trimesh``, a ``trimesh.Scene`` (geometry merged with node
            transforms), or a :class:`Mesh` (returned unchanged).

    Returns:
        :class:`Mesh`.  Vertex order is the file's (loaded with ``process=False``: no
        merging or reordering), so per-vertex data stays aligned; polygons are
        triangulated by trimesh.

    Raises:
        ValueError: missing file, unreadable format, or no triangles in the source.
    """
    if isinstance(source, Mesh):
        return source
    import trimesh

    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if not os.path.isfile(path):
            raise ArgumentError("source", f"source file does not exist: {path}")
        try:
            loaded = trimesh.load(path, process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ArgumentError(
                "source", f"source {path!r} could not be read as a mesh: {exc}") from exc
    else:
        loaded = source
    if isinstance(loaded, trimesh.Scene):
        mesh = _trimesh_scene_to_mesh(loaded)
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = _from_trimesh(loaded)
    elif loaded is not source:   # a file of points or lines only (OBJ "v" with no "f")
        raise ArgumentError("source", f"source {path!r} contains no triangles (trimesh read "
                                      f"it as a {type(loaded).__name__})")
    else:
        raise ArgumentError(
            "source", f"source must be a mesh file path, trimesh.Trimesh, trimesh.Scene or "
                      f"glraster Mesh, got {type(loaded).__name__}")
    if len(mesh.faces) == 0:
        raise ArgumentError("source", "source contains no triangles")
    return mesh


# --------------------------------------------------------------------------- scenes


@dataclass(frozen=True)
class SceneGeometry:
    """World-space triangles and a camera, ready to rasterize.

    mesh       : Mesh in world coordinates (all scene meshes merged, poses applied)
    view, proj : (4, 4) float64 OpenGL view and projection matrices
    resolution : (H, W)
    """

    mesh: Mesh
    view: np.ndarray
    proj: np.ndarray
    resolution: tuple[int, int]

    @property
    def pos(self) -> np.ndarray:
        """(V, 4) float32 clip-space positions."""
        return cam.project(self.mesh.vertices, None, self.view, self.proj)

    @property
    def tri(self) -> np.ndarray:
        """(T, 3) int64 vertex indices (same as ``mesh.faces``)."""
        return self.mesh.faces

    @property
    def view_depth(self) -> np.ndarray:
        """(V,) float64 per-vertex view depth ``-z_eye`` (the clip w of a perspective camera)."""
        v = self.mesh.vertices @ self.view[:3, :3].T + self.view[:3, 3]
        return -v[:, 2]


def framing_camera(mesh: Mesh, resolution, fovy_deg: float = 40.0,
                   direction=(0.45, 0.35, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """(view, proj) of a perspective camera that sees the whole mesh.

    The camera looks at the bounding-sphere center from ``direction``; near/far hug the
    sphere so 32-bit depth keeps its precision.
    """
    H, W = resolution
    c, r = mesh.bounding_sphere()
    r = max(r, 1e-6)
    half = math.radians(fovy_deg) / 2
    half = min(half, math.atan(math.tan(half) * W / H))   # fit the narrower side
    dist = 1.15 * r / math.sin(half)
    d = np.asarray(direction, dtype=np.float64)
    eye = c + dist * d / np.linalg.norm(d)
    view = cam.look_at(eye, c, (0.0, 1.0, 0.0))
    proj = cam.perspective(fovy_deg, W / H, max(dist - 1.5 * r, 1e-3 * dist), dist + 1.5 * r)
    return view, proj


def _resolution(resolution) -> tuple[int, int]:
    try:
        H, W = resolution
    except (TypeError, ValueError):
        raise ArgumentError(
            "resolution", f"resolution must be (H, W), got {resolution!r}") from None
    return validate.positive_int("resolution[0]", H), validate.positive_int("resolution[1]", W)


def _pyrender_scene(scene, resolution, view, proj) -> SceneGeometry:
    parts = []
    for node in scene.mesh_nodes:
        pose = scene.get_pose(node)
        for prim in node.mesh.primitives:
            if prim.mode != GL_TRIANGLES:
                raise ArgumentError(
                    "scene", f"scene mesh {node.name or node.mesh.name!r} has a primitive "
                             f"with mode {prim.mode}; only triangle lists (4) rasterize")
            v = np.asarray(prim.positions, dtype=np.float64)
            f = (np.asarray(prim.indices, dtype=np.int64).reshape(-1, 3)
                 if prim.indices is not None else np.arange(len(v)).reshape(-1, 3))
            uv = (np.asarray(prim.texcoord_0, dtype=np.float64)
                  if prim.texcoord_0 is not None else None)
            base = Mesh(v, f, uv, None)
            instances = prim.poses if prim.poses is not None else [np.eye(4)]
            parts += [base.transformed(pose @ inst) for inst in instances]
    mesh = _merge(parts)
    if view is None or proj is None:
        node = scene.main_camera_node
        if node is None:
            raise ArgumentError("scene", "scene has no camera; add one or pass view and proj")
        H, W = resolution
        view = np.linalg.inv(scene.get_pose(node)) if view is None else view
        proj = node.camera.get_projection_matrix(W, H) if proj is None else proj
    return SceneGeometry(mesh, np.asarray(view, np.float64), np.asarray(proj, np.float64),
                         resolution)


def scene_geometry(scene, resolution=(256, 256), *, view=None, proj=None) -> SceneGeometry:
    """Flatten a mesh or scene into world-space triangles and a camera.

    Args:
        scene: a ``pyrender.Scene`` (mesh nodes with poses and instance poses; its main
            camera unless ``view``/``proj`` are given), a ``trimesh.Scene``, a
            ``trimesh.Trimesh``, a :class:`Mesh` or a mesh file path.
        resolution: (H, W) of the image; pyrender cameras build their projection for it.
        view, proj: (4, 4) OpenGL view / projection overriding the scene's camera.  For
            sources without a camera, a :func:`framing_camera` is used when omitted.

    Returns:
        :class:`SceneGeometry`.
    """
    resolution = _resolution(resolution)
    if view is not None:
        view = validate.float_array("view", view, (4, 4))
    if proj is not None:
        proj = validate.float_array("proj", proj, (4, 4))
    if type(scene).__module__.startswith("pyrender"):
        return _pyrender_scene(scene, resolution, view, proj)
    mesh = load_mesh(scene)
    if view is None or proj is None:
        v, p = framing_camera(mesh, resolution)
        view = v if view is None else view
        proj = p if proj is None else proj
    return SceneGeometry(mesh, view, proj, resolution)
