"""Cross-check glraster's depth against pyrender's.

pyrender renders the mesh (depth only) with an ``IntrinsicsCamera`` in a **subprocess**:
PyOpenGL chooses its platform (``PYOPENGL_PLATFORM=egl`` here) once at import time and
pyrender makes its own EGL context current, which must not disturb the moderngl context
of this process.  pyrender returns linear depth (distance along the optical axis, 0 where
empty) with row 0 at the top; it is flipped here to glraster's row 0 at the bottom.

glraster renders the same triangles with :func:`glraster.geometry.camera.from_intrinsics` (pyrender's
``IntrinsicsCamera(cx, cy)`` is ours with ``cx - 0.5, cy - 0.5``) and interpolates the
per-vertex view depth (clip w) perspective-correctly with :func:`glraster.interpolate`.

Where the two depths differ, and why
------------------------------------
* **Sample position.** pyrender draws into a 4x multisampled framebuffer and blits it to a
  single-sample one.  Mesa resolves a depth blit by copying one sample (sample 0, at
  (0.375, 0.125) inside the pixel on llvmpipe), not by evaluating the pixel center.  On a
  sloped surface that offset alone gives relative differences of ~1e-3.  The check
  therefore also renders glraster with the window shifted by ``(0.5 - sx, 0.5 - sy)``
  (:func:`glraster.geometry.camera.shift_window`) so its pixel centers land on each MSAA sample
  position, and uses the best-matching one (reported, with the pixel-center figure).
* **24-bit depth.** pyrender's depth buffer is ``GL_DEPTH_COMPONENT24``: window z is
  quantized to steps of 2^-24; pyrender then linearizes in float32.  One step of window z
  is a relative linear-depth step of ``2^-24 * z (f - n) / (n f)`` (differentiate
  ``z = 2 n f / (f + n - (2 z_w - 1)(f - n))``).  :attr:`CrosscheckReport.quantum_rel`
  gives it per pixel.
* **Silhouettes.** At the outline and at occlusion edges one renderer may see a
  different surface than the other (fill-rule ties, a different sample position, depth-test
  ties at 24 against 32 bits).  Pixels within ``margin`` pixels of a coverage boundary or of
  a depth jump larger than ``jump`` (relative, between 4-neighbours) are excluded.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass, field

import numpy as np

from glraster import validate
from glraster.geometry import camera as cam
from glraster.interpolate import interpolate
from glraster.geometry.mesh import Mesh, load_mesh

__all__ = ["CrosscheckReport", "pyrender_depth", "crosscheck_pyrender", "default_mesh",
           "default_camera"]


# --------------------------------------------------------------------------- pyrender side

_WORKER = "from glraster.studies.crosscheck import _worker_main; _worker_main()"


def _worker_main() -> None:
    """Runs in the subprocess: argv = [in.npz, out.npz]."""
    in_path, out_path = sys.argv[1], sys.argv[2]
    import pyrender
    import trimesh
    from OpenGL import GL

    d = np.load(in_path)
    scene = pyrender.Scene()
    tm = trimesh.Trimesh(d["vertices"], d["faces"], process=False)
    scene.add(pyrender.Mesh.from_trimesh(tm, smooth=False))
    fx, fy, cx, cy = (float(x) for x in d["intrinsics"])
    near, far = float(d["near"]), float(d["far"])
    scene.add(pyrender.IntrinsicsCamera(fx, fy, cx, cy, znear=near, zfar=far),
              pose=d["camera_pose"])
    H, W = (int(x) for x in d["resolution"])
    renderer = pyrender.OffscreenRenderer(W, H)
    depth = renderer.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
    info = {"renderer": GL.glGetString(GL.GL_RENDERER).decode(),
            "gl_version": GL.glGetString(GL.GL_VERSION).decode(),
            "sample_positions": []}
    # MSAA sample positions of pyrender's multisampled framebuffer (private attribute:
    # diagnostics only, so a pyrender change degrades to "unknown" instead of failing).
    fb = getattr(getattr(renderer, "_renderer", None), "_main_fb_ms", None)
    if fb is not None:
        renderer._platform.make_current()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, fb)
        for i in range(int(GL.glGetIntegerv(GL.GL_SAMPLES))):
            buf = np.zeros(2, np.float32)
            GL.glGetMultisamplefv(GL.GL_SAMPLE_POSITION, i, buf)
            info["sample_positions"].append([float(buf[0]), float(buf[1])])
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
    renderer.delete()
    np.savez(out_path, depth=np.asarray(depth, np.float32), info=json.dumps(info))


def pyrender_depth(vertices, faces, K, resolution, view, near: float, far: float, *,
                   platform: str = "egl", timeout: float = 300.0) -> tuple[np.ndarray, dict]:
    """Render linear depth with pyrender in a subprocess.

    Args:
        vertices: (V, 3) world positions; faces: (T, 3) indices.
        K: (3, 3) OpenCV intrinsics (pixel centers at integers), zero skew.
        resolution: (H, W).
        view: (4, 4) OpenGL view matrix (world to eye); pyrender's camera pose is its inverse.
        near, far: clip distances.
        platform: PYOPENGL_PLATFORM for the subprocess ("egl" or "osmesa").
        timeout: seconds.

    Returns:
        depth: (H, W) float32 view depth (eye units), 0 where empty, **row 0 at the bottom**.
        info: {"renderer", "gl_version", "sample_positions": [[sx, sy], ...]} with sample
        positions in [0, 1) from the pixel's lower-left corner.
    """
    K = validate.intrinsics(K)
    if K[0, 1] != 0.0:
        raise ValueError(f"K must have zero skew for pyrender's IntrinsicsCamera, got {K[0, 1]}")
    H, W = validate.positive_int("resolution[0]", resolution[0]), validate.positive_int("resolution[1]", resolution[1])
    view = validate.float_array("view", view, (4, 4))
    if platform not in ("egl", "osmesa"):
        raise ValueError(f"platform must be 'egl' or 'osmesa', got {platform!r}")
    with tempfile.TemporaryDirectory(prefix="glraster-pyrender-") as tmp:
        src, dst = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(src, vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                 # pyrender's principal point is ours + 0.5 (see camera.from_intrinsics)
                 intrinsics=np.array([K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]),
                 near=near, far=far, camera_pose=np.linalg.inv(view), resolution=[H, W])
        env = dict(os.environ, PYOPENGL_PLATFORM=platform)
        proc = subprocess.run([sys.executable, "-c", _WORKER, src, dst], env=env,
                              capture_output=True, text=True, timeout=timeout)
        if proc.returncode != 0:
            tail = "\n".join(proc.stderr.strip().splitlines()[-8:])
            raise RuntimeError(
                f"pyrender subprocess failed (PYOPENGL_PLATFORM={platform}):\n{tail}")
        out = np.load(dst)
        depth = out["depth"][::-1].copy()   # pyrender row 0 is the top
        info = json.loads(str(out["info"]))
    return depth, info


# --------------------------------------------------------------------------- defaults


def default_mesh() -> Mesh:
    """Built-in test object: a torus (outer radius 1, tube 0.35) tilted 35 degrees about x
    and 20 about y, so it has sloped faces, an outline and inner occlusion edges."""
    import trimesh

    tm = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=48,
                                minor_sections=24)
    rx = trimesh.transformations.rotation_matrix(np.radians(35), [1, 0, 0])
    ry = trimesh.transformations.rotation_matrix(np.radians(20), [0, 1, 0])
    return Mesh(np.asarray(tm.vertices), np.asarray(tm.faces)).transformed(ry @ rx)


def default_camera(mesh: Mesh, resolution=(240, 320)):
    """(K, view, near, far): an OpenCV camera with focal length 1.2 W pixels and the
    principal point at the image center, looking at the mesh's bounding sphere from +z
    from a distance where the sphere fills most of the shorter image side."""
    H, W = resolution
    f = 1.2 * W
    K = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])
    c, r = mesh.bounding_sphere()
    dist = 1.1 * r * f / (min(H, W) / 2) + r
    view = cam.look_at(c + [0.0, 0.0, dist], c, (0.0, 1.0, 0.0))
    return K, view, max(dist - 2 * r, 1e-3), dist + 2 * r


# --------------------------------------------------------------------------- comparison


@dataclass
class CrosscheckReport:
    """Result of :func:`crosscheck_pyrender`.  Relative differences are
    ``|d_pyrender - d_glraster| / d_glraster`` of linear view depth."""

    resolution: tuple
    near: float
    far: float
    sample: str                      # "center" or "sample i (sx, sy)": where glraster sampled
    covered_both: int                # pixels covered in both images
    coverage_mismatch: int           # covered in exactly one
    compared: int                    # covered in both and away from silhouettes
    median_rel: float
    p99_rel: float
    max_rel: float
    max_rel_at: tuple                # (x, y) glraster pixel, row 0 at the bottom
    max_rel_quanta: float            # max_rel in units of the 24-bit depth step there
    max_rel_all: float               # including silhouette pixels
    median_rel_raw: float            # with interpolate(normalize=False): raw GPU weights
    max_rel_raw: float
    ref_median_rel: float            # pyrender against the float64 reference depth
    ref_max_rel: float
    ref_max_bound_ratio: float       # max of |pyrender - reference| / error-model bound
    median_rel_by_sample: dict = field(default_factory=dict)  # each candidate's median
    pyrender: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        lines = [
            f"pyrender ({self.pyrender.get('renderer', '?')}) vs glraster, "
            f"{self.resolution[0]}x{self.resolution[1]} (HxW), near {self.near:g}, "
            f"far {self.far:g}",
            f"  glraster sampled at: {self.sample}",
            f"  covered in both: {self.covered_both}, in one only: {self.coverage_mismatch}, "
            f"compared away from silhouettes: {self.compared}",
            f"  relative depth difference: median {self.median_rel:.3g}, p99 {self.p99_rel:.3g}, "
            f"max {self.max_rel:.3g} at {self.max_rel_at} "
            f"({self.max_rel_quanta:.2f} steps of 24-bit depth)",
            f"  max including silhouettes: {self.max_rel_all:.3g}",
            f"  with raw (unnormalized) GPU barycentrics: median {self.median_rel_raw:.3g}, "
            f"max {self.max_rel_raw:.3g}",
            f"  pyrender against the float64 reference: median {self.ref_median_rel:.3g}, "
            f"max {self.ref_max_rel:.3g} = {self.ref_max_bound_ratio:.2f} of the error-model "
            "bound (float32 depth plane + one 24-bit step + float32 linearization)",
            "  median by glraster sample position: " + ", ".join(
                f"{k}: {v:.3g}" for k, v in self.median_rel_by_sample.items()),
        ]
        return "\n".join(lines)


def _dilate(m: np.ndarray, r: int) -> np.ndarray:
    out = m.copy()
    for _ in range(r):
        p = np.pad(out, 1)
        out = (p[1:-1, 1:-1] | p[:-2, 1:-1] | p[2:, 1:-1] | p[1:-1, :-2] | p[1:-1, 2:]
               | p[:-2, :-2] | p[:-2, 2:] | p[2:, :-2] | p[2:, 2:])
    return out


def silhouette_band(mask_a, mask_b, depth, margin: int = 1, jump: float = 0.02) -> np.ndarray:
    """(H, W) bool: pixels within ``margin`` px of a coverage boundary of ``mask_a`` or
    ``mask_b``, or of a relative depth jump above ``jump`` between 4-neighbours of
    ``depth`` (occlusion edges)."""
    edge = np.zeros_like(mask_a)
    for m in (mask_a, mask_b):
        h = m[:, 1:] != m[:, :-1]
        v = m[1:, :] != m[:-1, :]
        edge[:, 1:] |= h
        edge[:, :-1] |= h
        edge[1:, :] |= v
        edge[:-1, :] |= v
    d = np.where(mask_a, depth, np.nan).astype(np.float64)
    with np.errstate(invalid="ignore"):
        h = np.abs(d[:, 1:] - d[:, :-1]) > jump * np.fmin(d[:, 1:], d[:, :-1])
        v = np.abs(d[1:, :] - d[:-1, :]) > jump * np.fmin(d[1:, :], d[:-1, :])
    edge[:, 1:] |= h
    edge[:, :-1] |= h
    edge[1:, :] |= v
    edge[:-1, :] |= v
    return _dilate(edge, margin)


def _glraster_depth(mesh, view, proj, resolution, ctx):
    """(normalized, raw) perspective-correct view depth (H, W) float32 and the mask."""
    from glraster.gpu.rasterize import rasterize

    pos = cam.project(mesh.vertices, None, view, proj)
    r = rasterize(pos, mesh.faces, resolution, ctx=ctx, outputs=("persp", "tri_id"))
    # clip w is the view depth -z_eye for a perspective camera (w row = (0, 0, -1, 0))
    w = -(mesh.vertices @ view[2, :3] + view[2, 3])
    return (interpolate(w, r, mesh.faces, space="persp"),
            interpolate(w, r, mesh.faces, space="persp", normalize=False), r.mask)


def _against_reference(mesh, view, proj, resolution, near, far, d_py, keep):
    """pyrender's depth against the float64 reference at the same sample positions.

    The bound per pixel, in relative linear depth, is
    ``(tol_zw + 2^-24) * z (f - n) / (n f) + 4 eps32``: the project's float32 plane-equation
    bound on window z (:func:`glraster.verify.tolerance.value_tolerance`), one step of the 24-bit
    buffer, both scaled by dz/dz_w / z, plus pyrender's float32 linearization.
    Returns (median, max, max ratio to the bound) over ``keep`` pixels the reference covers.
    """
    from glraster.reference import rasterize as ref_rasterize
    from glraster.verify.tolerance import value_tolerance

    pos = cam.project(mesh.vertices, None, view, proj)
    ref = ref_rasterize(pos, mesh.faces, resolution, outputs=("depth", "tri_id"))
    zw = ref.depth
    z = 2.0 * near * far / (far + near - (2.0 * zw - 1.0) * (far - near))
    sel = keep & ref.mask & ~ref.edge_band
    if not sel.any():
        return float("nan"), float("nan"), float("nan")
    rel = np.abs(d_py - z)[sel] / z[sel]
    tol = value_tolerance(ref.triangles, ref.tri_id, ("depth",)).depth[sel]
    bound = (tol + 2.0 ** -24) * z[sel] * (far - near) / (near * far) \
        + 4 * float(np.finfo(np.float32).eps)
    return float(np.median(rel)), float(rel.max()), float((rel / bound).max())


def crosscheck_pyrender(mesh=None, *, resolution=(240, 320), K=None, view=None,
                        near: float | None = None, far: float | None = None, ctx=None,
                        platform: str = "egl", sample: str = "auto", margin: int = 1,
                        jump: float = 0.02) -> CrosscheckReport:
    """Compare pyrender's linear depth with glraster's perspective-correct view depth.

    Args:
        mesh: a path, trimesh object or :class:`Mesh` in world coordinates; None for
            :func:`default_mesh`.
        resolution: (H, W).
        K, view, near, far: OpenCV intrinsics (zero skew), OpenGL view matrix and clip
            distances; any left None comes from :func:`default_camera`.
        ctx: glraster context (None: the default one).
        platform: PYOPENGL_PLATFORM of the pyrender subprocess.
        sample: where glraster samples each pixel: "center", "sample0".."sampleN" (pyrender's
            MSAA sample positions) or "auto" (whichever of these gives the smallest median).
        margin, jump: silhouette exclusion, see :func:`silhouette_band`.

    Returns:
        :class:`CrosscheckReport`.
    """
    mesh = default_mesh() if mesh is None else load_mesh(mesh)
    H, W = validate.positive_int("resolution[0]", resolution[0]), validate.positive_int("resolution[1]", resolution[1])
    dK, dview, dnear, dfar = default_camera(mesh, (H, W))
    K = dK if K is None else validate.intrinsics(K)
    view = dview if view is None else validate.float_array("view", view, (4, 4))
    near = dnear if near is None else validate.real("near", near, positive=True)
    far = dfar if far is None else validate.real("far", far, positive=True)
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")

    d_py, info = pyrender_depth(mesh.vertices, mesh.faces, K, (H, W), view, near, far,
                                platform=platform)
    covered_py = d_py > 0
    proj = cam.from_intrinsics(K, W, H, near, far)

    candidates = {"center": (0.5, 0.5)}
    for i, (sx, sy) in enumerate(info.get("sample_positions", [])):
        candidates[f"sample{i}"] = (sx, sy)
    if sample != "auto" and sample not in candidates:
        raise ValueError(f"sample must be 'auto' or one of {sorted(candidates)}, got {sample!r}")

    results = {}
    for name, (sx, sy) in candidates.items():
        if sample != "auto" and name not in (sample, "center"):
            continue
        d_gl, d_raw, covered_gl = _glraster_depth(
            mesh, view, cam.shift_window(proj, 0.5 - sx, 0.5 - sy, (H, W)), (H, W), ctx)
        both = covered_gl & covered_py
        keep = both & ~silhouette_band(covered_gl, covered_py, d_gl, margin, jump)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.abs(d_py.astype(np.float64) - d_gl) / d_gl
            rel_raw = np.abs(d_py.astype(np.float64) - d_raw) / d_raw
        results[name] = (rel, both, keep, covered_gl, d_gl, rel_raw)
    medians = {k: float(np.median(v[0][v[2]])) if v[2].any() else float("nan")
               for k, v in results.items()}
    chosen = min(medians, key=lambda k: medians[k]) if sample == "auto" else sample
    rel, both, keep, covered_gl, d_gl, rel_raw = results[chosen]
    sx, sy = candidates[chosen]
    ref_med, ref_max, ratio = _against_reference(
        mesh, view, cam.shift_window(proj, 0.5 - sx, 0.5 - sy, (H, W)), (H, W), near, far,
        d_py, keep)
    if not keep.any():
        raise ValueError("no pixel is covered by both renderers away from silhouettes; "
                         "check the camera (view, K, near, far)")
    vals = rel[keep]
    iy, ix = np.unravel_index(np.argmax(np.where(keep, rel, -1.0)), rel.shape)
    z = d_gl[iy, ix]
    quantum = 2.0 ** -24 * z * (far - near) / (near * far)
    return CrosscheckReport(
        resolution=(H, W), near=near, far=far,
        sample=chosen if chosen == "center" else f"{chosen} ({sx:g}, {sy:g})",
        covered_both=int(both.sum()), coverage_mismatch=int((covered_gl ^ covered_py).sum()),
        compared=int(keep.sum()), median_rel=float(np.median(vals)),
        p99_rel=float(np.percentile(vals, 99)), max_rel=float(vals.max()),
        max_rel_at=(int(ix), int(iy)), max_rel_quanta=float(rel[iy, ix] / quantum),
        max_rel_all=float(rel[both].max()), median_rel_raw=float(np.median(rel_raw[keep])),
        max_rel_raw=float(rel_raw[keep].max()), ref_median_rel=ref_med, ref_max_rel=ref_max,
        ref_max_bound_ratio=ratio, median_rel_by_sample=medians, pyrender=info)
