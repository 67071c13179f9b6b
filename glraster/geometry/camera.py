"""Camera matrices: OpenGL-style view/projection and OpenCV pinhole intrinsics.

Every matrix here is a (4, 4) float64 NumPy array acting on column vectors
(``clip = proj @ view @ model @ [x, y, z, 1]``), the layout OpenGL, trimesh and
pyrender use.

Eye space is OpenGL's: x right, y up, the camera looks down -z.  OpenCV's camera
space is x right, y *down*, looking down +z; the two differ by a rotation of 180
degrees about x, ``OPENCV_TO_OPENGL = diag(1, -1, -1, 1)``.

Pixel-center convention
-----------------------
glraster follows GL window coordinates (see DESIGN.md)::

    x_w = (x_c / w_c + 1) * W / 2,   y_w = (y_c / w_c + 1) * H / 2

pixel ``(x, y)`` covers ``[x, x+1) x [y, y+1)`` and has its center at
``(x + 0.5, y + 0.5)``; row 0 is at the *bottom*.

OpenCV puts pixel centers at *integer* image coordinates: pixel ``(col, row)``
has its center at ``(u, v) = (col, row)``, the image spans ``[-0.5, W - 0.5]``,
and row 0 is at the *top*.  Pixel ``(col, row)`` of an OpenCV image is glraster
pixel ``(col, H - 1 - row)``, so a continuous OpenCV position maps to window
coordinates by::

    x_w = u + 0.5,   y_w = H - 0.5 - v                          (eq. C1)

:func:`from_intrinsics` builds the projection for which eq. C1 holds exactly
(up to rounding) for every point in front of the camera.
"""

from __future__ import annotations

import math

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError
from glraster.geometry.window import clip_to_window  # noqa: F401 (part of this API)

__all__ = [
    "OPENCV_TO_OPENGL",
    "perspective",
    "orthographic",
    "look_at",
    "from_intrinsics",
    "view_from_opencv",
    "project",
    "clip_to_window",
    "shift_window",
    "opencv_project",
    "opencv_to_window",
    "window_to_opencv",
]

#: Rotation (as a 4x4 homogeneous matrix) taking OpenCV camera coordinates
#: (x right, y down, z forward) to OpenGL eye coordinates (x right, y up, z back).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
OPENCV_TO_OPENGL.setflags(write=False)


# --------------------------------------------------------------------------- OpenGL matrices


def perspective(fovy_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """Symmetric perspective projection (as ``gluPerspective``).

    Args:
        fovy_deg: full vertical field of view in degrees, in (0, 180).
        aspect: width / height of the viewport, > 0.
        near, far: distances to the clip planes along -z (eye units), 0 < near < far.

    Returns:
        (4, 4) float64.  Maps eye-space z = -near to NDC z = -1 and -far to +1;
        clip w = -z_eye (the view depth).
    """
    fovy = validate.real("fovy_deg", fovy_deg)
    if not 0.0 < fovy < 180.0:
        raise ArgumentError("fovy_deg", f"fovy_deg must be in (0, 180), got {fovy}")
    aspect = validate.real("aspect", aspect, positive=True)
    near = validate.real("near", near, positive=True)
    far = validate.real("far", far, positive=True)
    if far <= near:
        raise ArgumentError("far", f"far must be > near, got near={near}, far={far}")
    f = 1.0 / math.tan(math.radians(fovy) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(left: float, right: float, bottom: float, top: float,
                 near: float, far: float) -> np.ndarray:
    """Orthographic projection (as ``glOrtho``); clip w is 1 everywhere.

    Args:
        left, right, bottom, top: eye-space bounds of the view volume, left != right,
            bottom != top.
        near, far: signed distances to the clip planes along -z, near != far.

    Returns:
        (4, 4) float64.
    """
    l, r = validate.real("left", left), validate.real("right", right)
    b, t = validate.real("bottom", bottom), validate.real("top", top)
    n, f = validate.real("near", near), validate.real("far", far)
    if r == l:
        raise ArgumentError("right", f"right must differ from left, both are {l}")
    if t == b:
        raise ArgumentError("top", f"top must differ from bottom, both are {b}")
    if f == n:
        raise ArgumentError("far", f"far must differ from near, both are {n}")
    m = np.eye(4)
    m[0, 0] = 2.0 / (r - l)
    m[1, 1] = 2.0 / (t - b)
    m[2, 2] = -2.0 / (f - n)
    m[0, 3] = -(r + l) / (r - l)
    m[1, 3] = -(t + b) / (t - b)
    m[2, 3] = -(f + n) / (f - n)
    return m


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-eye (view) matrix of a camera at ``eye`` looking at ``target``.

    Args:
        eye, target: (3,) world positions, distinct.
        up: (3,) approximate up direction, not parallel to ``target - eye``.

    Returns:
        (4, 4) float64 rigid transform; the camera looks down its -z axis and
        ``up`` projects onto +y.
    """
    eye = validate.float_array("eye", eye, (3,))
    target = validate.float_array("target", target, (3,))
    up = validate.float_array("up", up, (3,))
    fwd = target - eye
    n = np.linalg.norm(fwd)
    if n == 0.0:
        raise ArgumentError("target", "target must differ from eye")
    fwd /= n
    side = np.cross(fwd, up)
    ns = np.linalg.norm(side)
    if ns <= 1e-12 * max(np.linalg.norm(up), 1e-300):
        raise ArgumentError("up", "up must not be parallel to target - eye (or zero)")
    side /= ns
    upv = np.cross(side, fwd)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = side, upv, -fwd
    m[:3, 3] = -m[:3, :3] @ eye
    return m


# --------------------------------------------------------------------------- OpenCV cameras


def from_intrinsics(K, width: int, height: int, near: float, far: float) -> np.ndarray:
    """OpenGL projection matrix for an OpenCV pinhole camera.

    OpenCV projects a camera-space point (X, Y, Z), Z > 0, to
    ``u = (fx X + s Y) / Z + cx``, ``v = fy Y / Z + cy`` with pixel centers at integer
    (u, v) and row 0 at the top.  The returned matrix, applied to OpenGL eye coordinates
    ``(X, -Y, -Z)`` (see :data:`OPENCV_TO_OPENGL`, :func:`view_from_opencv`), puts that
    point at window position ``x_w = u + 0.5``, ``y_w = H - 0.5 - v`` (module docstring,
    eq. C1), i.e. on the same pixel and sub-pixel position.

    Derivation (docs/cameras.md, with the half-pixel terms kept): with
    ``w_c = Z = -z_e`` and ``x_ndc = 2 x_w / W - 1``::

        x_c = 2 fx/W x_e - 2 s/W y_e + (1 - 2 (cx + 0.5)/W) z_e
        y_c = 2 fy/H y_e + (2 (cy + 0.5)/H - 1) z_e

    Depth rows are those of :func:`perspective` (NDC z -1 at ``near``, +1 at ``far``).

    Note: pyrender's ``IntrinsicsCamera(fx, fy, cx, cy)`` puts pixel centers at
    half-integers; it equals ``from_intrinsics`` with ``cx - 0.5, cy - 0.5``.

    Args:
        K: (3, 3) intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, fx, fy > 0.
        width, height: image size in pixels (the glraster resolution is (height, width)).
        near, far: clip distances along the optical axis, 0 < near < far.

    Returns:
        (4, 4) float64.
    """
    K = validate.intrinsics(K)
    W = validate.positive_int("width", width)
    H = validate.positive_int("height", height)
    near = validate.real("near", near, positive=True)
    far = validate.real("far", far, positive=True)
    if far <= near:
        raise ArgumentError("far", f"far must be > near, got near={near}, far={far}")
    fx, s, cx = K[0]
    fy, cy = K[1, 1], K[1, 2]
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 * fx / W
    m[0, 1] = -2.0 * s / W
    m[0, 2] = 1.0 - 2.0 * (cx + 0.5) / W
    m[1, 1] = 2.0 * fy / H
    m[1, 2] = 2.0 * (cy + 0.5) / H - 1.0
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def view_from_opencv(R, t) -> np.ndarray:
    """OpenGL view matrix from OpenCV extrinsics.

    Args:
        R: (3, 3) rotation, world to OpenCV camera.
        t: (3,) translation, so that ``X_cam = R @ X_world + t``.

    Returns:
        (4, 4) float64 ``OPENCV_TO_OPENGL @ [[R, t], [0, 1]]``.
    """
    R = validate.float_array("R", R, (3, 3))
    t = validate.float_array("t", t, (3,)) if np.ndim(t) == 1 else validate.float_array("t", t, (3, 1)).ravel()
    m = np.eye(4)
    m[:3, :3] = R
    m[:3, 3] = t
    return OPENCV_TO_OPENGL @ m


def opencv_project(points, K, R=None, t=None) -> np.ndarray:
    """OpenCV's pinhole projection without distortion (as ``cv2.projectPoints``).

    Args:
        points: (N, 3) world points.
        K: (3, 3) intrinsics.
        R, t: (3, 3) rotation and (3,) translation, world to camera (identity / zero
            if None).

    Returns:
        (N, 2) float64 ``(u, v)`` in OpenCV pixel coordinates (integer = pixel center,
        row 0 at the top).  Points with Z <= 0 give meaningless values.
    """
    P = validate.float_array("points", points, (-1, 3))
    K = validate.intrinsics(K)
    R = np.eye(3) if R is None else validate.float_array("R", R, (3, 3))
    t = np.zeros(3) if t is None else validate.float_array("t", np.ravel(t), (3,))
    Xc = P @ R.T + t
    uvw = Xc @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def opencv_to_window(uv, height: int) -> np.ndarray:
    """OpenCV image coordinates to glraster window coordinates (eq. C1).

    Args:
        uv: (N, 2) OpenCV (u, v), integer at pixel centers, row 0 at the top.
        height: image height H in pixels.

    Returns:
        (N, 2) float64 ``(x_w, y_w) = (u + 0.5, H - 0.5 - v)``.
    """
    uv = validate.float_array("uv", uv, (-1, 2))
    H = validate.positive_int("height", height)
    return np.stack([uv[:, 0] + 0.5, H - 0.5 - uv[:, 1]], axis=1)


def window_to_opencv(xy, height: int) -> np.ndarray:
    """Inverse of :func:`opencv_to_window`: (N, 2) window (x_w, y_w) to OpenCV (u, v)."""
    xy = validate.float_array("xy", xy, (-1, 2))
    H = validate.positive_int("height", height)
    return np.stack([xy[:, 0] - 0.5, H - 0.5 - xy[:, 1]], axis=1)


# --------------------------------------------------------------------------- projection


def project(vertices, model=None, view=None, proj=None, *, dtype=np.float32) -> np.ndarray:
    """Clip-space positions ``proj @ view @ model @ v`` ready for :func:`glraster.rasterize`.

    Args:
        vertices: (V, 3) positions (w = 1 appended) or (V, 4) homogeneous positions,
            object space.
        model, view, proj: (4, 4) matrices or None for identity.
        dtype: float32 (default, what the GPU consumes) or float64 (for the reference and
            for checking camera math without float32 rounding).

    Returns:
        (V, 4) clip-space ``pos`` of ``dtype``.  The product is formed in float64 and
        rounded once.
    """
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ArgumentError("dtype", f"dtype must be float32 or float64, got {dtype}")
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise ArgumentError(
            "vertices", "vertices must be a numeric array of shape (V, 3) or (V, 4)") from None
    if v.ndim != 2 or v.shape[1] not in (3, 4):
        raise ArgumentError("vertices", f"vertices must have shape (V, 3) or (V, 4), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ArgumentError("vertices", "vertices must be finite")
    if v.shape[1] == 3:
        v = np.concatenate([v, np.ones((v.shape[0], 1))], axis=1)
    m = validate.matrix4("proj", proj) @ validate.matrix4("view", view) @ validate.matrix4("model", model)
    return (v @ m.T).astype(dtype)


def shift_window(proj, dx: float, dy: float, resolution) -> np.ndarray:
    """Projection whose window positions are those of ``proj`` moved by (dx, dy) pixels.

    ``x_w' = x_w + dx`` means ``x_ndc' = x_ndc + 2 dx / W``, i.e. adding ``2 dx / W`` times
    the w row to the x row (same for y).  Rendering with the result samples the scene at
    window position ``(x + 0.5 - dx, y + 0.5 - dy)`` of the original projection in pixel
    (x, y); with ``dx = 0.5 - sx`` that is a sample at ``(x + sx, y + sy)``.

    Args:
        proj: (4, 4) projection.
        dx, dy: shift in pixels.
        resolution: (H, W).

    Returns:
        (4, 4) float64.
    """
    m = validate.float_array("proj", proj, (4, 4))
    dx, dy = validate.real("dx", dx), validate.real("dy", dy)
    if len(resolution) != 2:
        raise ArgumentError("resolution", f"resolution must be (H, W), got {resolution!r}")
    H, W = validate.positive_int("resolution[0]", resolution[0]), validate.positive_int("resolution[1]", resolution[1])
    m[0] += 2.0 * dx / W * m[3]
    m[1] += 2.0 * dy / H * m[3]
    return m
