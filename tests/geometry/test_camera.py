"""Camera matrices: exact properties, OpenCV pixel convention, pyrender agreement."""

import math

import numpy as np
import pytest

from glraster.geometry import camera as cam


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _random_camera(rng):
    W = int(rng.integers(32, 4097))
    H = int(rng.integers(32, 4097))
    f = rng.uniform(0.3, 3.0) * max(W, H)
    K = np.array([[f * rng.uniform(0.8, 1.25), rng.uniform(-2, 2), rng.uniform(0.2, 0.8) * W],
                  [0.0, f * rng.uniform(0.8, 1.25), rng.uniform(0.2, 0.8) * H],
                  [0.0, 0.0, 1.0]])
    return K, W, H, _random_rotation(rng), rng.normal(scale=3.0, size=3)


def test_opencv_projection_lands_on_same_window_position():
    """OpenCV (u, v) of random points, mapped by eq. C1, equals glraster's window
    position through from_intrinsics + view_from_opencv, on 200 random cameras."""
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(200):
        K, W, H, R, t = _random_camera(rng)
        near, far = 0.05, 500.0
        # Points in front of the camera, spread over (and beyond) the image.
        Xc = np.stack([rng.uniform(-1.5, 1.5, 100), rng.uniform(-1.5, 1.5, 100),
                       np.ones(100)], 1) * rng.uniform(0.1, 400.0, (100, 1))
        Xw = (Xc - t) @ R  # inverse of X_cam = R X_world + t
        uv = cam.opencv_project(Xw, K, R, t)
        expected = cam.opencv_to_window(uv, H)
        pos = cam.project(Xw, None, cam.view_from_opencv(R, t),
                          cam.from_intrinsics(K, W, H, near, far), dtype=np.float64)
        got = cam.clip_to_window(pos, (H, W))[:, :2]
        worst = max(worst, np.abs(got - expected).max())
    # 1e-4 px is the requirement; float64 rounding of coordinates up to ~1e6 px (points
    # far outside a 4096 image) stays near 1e-9 px, so this is not a loose bound.
    assert worst <= 1e-4, worst


def test_opencv_pixel_center_is_glraster_pixel_center():
    """OpenCV pixel (col, row) center -> glraster pixel (col, H-1-row) center, exactly."""
    H = 48
    uv = np.array([[0.0, 0.0], [5.0, 7.0], [63.0, 47.0]])
    xy = cam.opencv_to_window(uv, H)
    np.testing.assert_array_equal(xy, [[0.5, 47.5], [5.5, 40.5], [63.5, 0.5]])
    np.testing.assert_array_equal(cam.window_to_opencv(xy, H), uv)


def test_project_float32_rounds_once():
    """The default float32 output is the float64 product rounded once (exact equality)."""
    rng = np.random.default_rng(1)
    v = rng.normal(size=(50, 3))
    P = cam.perspective(60, 1.3, 0.1, 100)
    V = cam.look_at([1, 2, 5], [0, 0, 0])
    p32 = cam.project(v, None, V, P)
    p64 = cam.project(v, None, V, P, dtype=np.float64)
    assert p32.dtype == np.float32 and p32.shape == (50, 4)
    np.testing.assert_array_equal(p32, p64.astype(np.float32))


def test_from_intrinsics_matches_pyrender_with_half_pixel_shift():
    """pyrender's IntrinsicsCamera(cx, cy) uses half-integer pixel centers: it equals
    from_intrinsics(cx - 0.5, cy - 0.5).  Same float64 formulas, so 1e-15 relative."""
    pyrender = pytest.importorskip("pyrender")
    K = np.array([[500.0, 0, 319.5], [0, 480.0, 241.25], [0, 0, 1]])
    ours = cam.from_intrinsics(K, 640, 480, 0.1, 50.0)
    theirs = pyrender.IntrinsicsCamera(500.0, 480.0, 320.0, 241.75, znear=0.1,
                                       zfar=50.0).get_projection_matrix(640, 480)
    np.testing.assert_allclose(ours, theirs, rtol=1e-15, atol=1e-15)


def test_perspective_matches_pyrender():
    """Same formula as pyrender's PerspectiveCamera (float64 rounding only)."""
    pyrender = pytest.importorskip("pyrender")
    ours = cam.perspective(50.0, 1.5, 0.2, 30.0)
    theirs = pyrender.PerspectiveCamera(math.radians(50.0), 0.2, 30.0, 1.5).get_projection_matrix()
    np.testing.assert_allclose(ours, theirs, rtol=1e-14, atol=1e-15)


def test_perspective_maps_frustum_to_ndc_cube():
    near, far, fovy, aspect = 0.5, 20.0, 90.0, 2.0
    P = cam.perspective(fovy, aspect, near, far)
    # At depth d the half height is d * tan(45 deg) = d, half width = 2 d.
    pts = np.array([[0, 0, -near, 1], [0, 0, -far, 1], [2 * 3, 3, -3, 1], [-2 * 7, -7, -7, 1]])
    clip = pts @ P.T
    ndc = clip[:, :3] / clip[:, 3:]
    # 1e-12: a handful of float64 operations on O(1) numbers.
    np.testing.assert_allclose(ndc, [[0, 0, -1], [0, 0, 1], [1, 1, ndc[2, 2]], [-1, -1, ndc[3, 2]]],
                               atol=1e-12)
    np.testing.assert_allclose(clip[:, 3], -pts[:, 2], atol=0)  # w_c is the view depth, exactly


def test_orthographic_maps_box_corners_to_ndc_corners():
    O = cam.orthographic(-2, 6, -1, 3, 0.5, 10)
    corners = np.array([[-2, -1, -0.5, 1], [6, 3, -10, 1]])
    # 1e-12: float64 rounding of the affine map.
    np.testing.assert_allclose(corners @ O.T, [[-1, -1, -1, 1], [1, 1, 1, 1]], atol=1e-12)


def test_look_at_frame():
    eye, target, up = np.array([3.0, 2.0, 5.0]), np.array([0.5, -1.0, 0.0]), np.array([0, 1.0, 0])
    V = cam.look_at(eye, target, up)
    R = V[:3, :3]
    # 1e-12: orthonormality and the mapped points are float64 products of O(10) numbers.
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1) < 1e-12
    np.testing.assert_allclose(V @ np.append(eye, 1), [0, 0, 0, 1], atol=1e-12)
    d = np.linalg.norm(target - eye)
    np.testing.assert_allclose(V @ np.append(target, 1), [0, 0, -d, 1], atol=1e-12)
    up_eye = R @ up
    assert abs(up_eye[0]) < 1e-12 and up_eye[1] > 0


@pytest.mark.parametrize("call, name", [
    (lambda: cam.perspective(0, 1, 0.1, 10), "fovy_deg"),
    (lambda: cam.perspective(60, -1, 0.1, 10), "aspect"),
    (lambda: cam.perspective(60, 1, 0.0, 10), "near"),
    (lambda: cam.perspective(60, 1, 1.0, 0.5), "far"),
    (lambda: cam.orthographic(1, 1, 0, 1, 0, 1), "right"),
    (lambda: cam.orthographic(0, 1, 2, 2, 0, 1), "top"),
    (lambda: cam.orthographic(0, 1, 0, 1, 3, 3), "far"),
    (lambda: cam.look_at([0, 0, 0], [0, 0, 0]), "target"),
    (lambda: cam.look_at([0, 0, 0], [0, 1, 0], [0, 2, 0]), "up"),
    (lambda: cam.look_at([0, 0], [0, 1, 0]), "eye"),
    (lambda: cam.from_intrinsics(np.eye(3)[:2], 4, 4, 0.1, 1), "K"),
    (lambda: cam.from_intrinsics([[1, 0, 0], [0, 1, 0], [0, 0, 2]], 4, 4, 0.1, 1), "K"),
    (lambda: cam.from_intrinsics([[-1, 0, 0], [0, 1, 0], [0, 0, 1]], 4, 4, 0.1, 1), "K"),
    (lambda: cam.from_intrinsics(np.eye(3), 0, 4, 0.1, 1), "width"),
    (lambda: cam.from_intrinsics(np.eye(3), 4, 2.5, 0.1, 1), "height"),
    (lambda: cam.from_intrinsics(np.eye(3), 4, 4, 0.1, float("nan")), "far"),
    (lambda: cam.project(np.zeros((3, 2))), "vertices"),
    (lambda: cam.project(np.zeros((3, 3)), model=np.eye(3)), "model"),
    (lambda: cam.project(np.zeros((3, 3)), view=np.eye(3)), "view"),
    (lambda: cam.project(np.zeros((3, 3)), proj=np.eye(3)), "proj"),
    (lambda: cam.project(np.zeros((3, 3)), dtype=np.int32), "dtype"),
    (lambda: cam.view_from_opencv(np.eye(3), [0, 0]), "t"),
    (lambda: cam.opencv_to_window(np.zeros((2, 3)), 4), "uv"),
])
def test_invalid_arguments_raise_valueerror_naming_them(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_shift_window_moves_every_point_by_the_shift():
    rng = np.random.default_rng(3)
    P = cam.from_intrinsics([[300, 0, 100], [0, 310, 80], [0, 0, 1]], 200, 160, 0.1, 50)
    pts = rng.uniform(-1, 1, (30, 3)) + [0, 0, -5]
    a = cam.clip_to_window(cam.project(pts, proj=P, dtype=np.float64), (160, 200))
    b = cam.clip_to_window(cam.project(pts, proj=cam.shift_window(P, 0.125, -0.375, (160, 200)),
                                       dtype=np.float64), (160, 200))
    # float64 rounding of window coordinates of size ~200 px
    np.testing.assert_allclose(b - a, np.tile([0.125, -0.375, 0.0], (30, 1)), atol=1e-10)


def test_gpu_covers_the_opencv_pixel(ctx):
    """A small triangle around the 3D point whose OpenCV projection is the center of pixel
    (col, row) covers exactly glraster pixel (col, H - 1 - row) on the GPU."""
    import glraster as gr

    rng = np.random.default_rng(11)
    for _ in range(12):
        W, H = int(rng.integers(16, 200)), int(rng.integers(16, 200))
        f = rng.uniform(0.5, 2.0) * max(W, H)
        K = np.array([[f, 0.0, rng.uniform(0.3, 0.7) * W], [0.0, f * rng.uniform(0.9, 1.1),
                      rng.uniform(0.3, 0.7) * H], [0.0, 0.0, 1.0]])
        R, t = _random_rotation(rng), rng.normal(size=3)
        col, row = int(rng.integers(0, W)), int(rng.integers(0, H))
        Z = rng.uniform(0.5, 20.0)
        center = Z * np.linalg.solve(K, [col, row, 1.0])
        # corners 0.3 px from the center (at depth Z): the center's pixel is inside, every
        # neighbouring pixel center (1 px away) is outside, so coverage is unambiguous.
        s = 0.3 * Z / K[0, 0]
        corners = center + s * np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
        world = (corners - t) @ R
        pos = cam.project(world, None, cam.view_from_opencv(R, t),
                          cam.from_intrinsics(K, W, H, 0.1, 100.0))
        r = gr.rasterize(pos, [[0, 1, 2]], (H, W), ctx=ctx, outputs=("tri_id",))
        ys, xs = np.nonzero(r.mask)
        assert list(zip(xs, ys)) == [(col, H - 1 - row)], (W, H, col, row)
