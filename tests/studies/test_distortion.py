"""Worked example (docs/distortion.md), the GPU reproducing it, and the distortion figure's content."""

import random
from fractions import Fraction

import numpy as np
import pytest

from glraster.geometry import camera as cam
from glraster.studies.distortion import (builtin_scenes, render_scene_comparison, segment_example,
                                 segment_example_gpu)


def test_seed001_numbers_exactly():
    ex = segment_example()
    # exact rational arithmetic: equality, no tolerance
    assert (ex.s0, ex.s1) == (-2, Fraction(2, 5))
    assert ex.t == Fraction(5, 6)
    assert ex.affine_depth == Fraction(9, 2)
    assert ex.correct_depth == 4
    assert ex.true_point == (0, 4)
    assert ex.true_fraction == Fraction(2, 3) and ex.affine_fraction == Fraction(5, 6)


def test_correct_depth_is_the_ray_hit_for_any_segment():
    """1/depth interpolation recovers the true depth on random rational segments; affine
    interpolation does not unless both ends have the same depth."""
    rng = random.Random(1)
    for _ in range(200):
        v0 = (Fraction(rng.randint(-20, 20), rng.randint(1, 5)), Fraction(rng.randint(1, 40), 4))
        v1 = (Fraction(rng.randint(-20, 20), rng.randint(1, 5)), Fraction(rng.randint(1, 40), 4))
        s0, s1 = v0[0] / v0[1], v1[0] / v1[1]
        if s0 == s1:
            continue
        sx = s0 + (s1 - s0) * Fraction(rng.randint(0, 12), 12)
        ex = segment_example(v0, v1, sx)
        assert ex.correct_depth == ex.true_point[1]
        assert ex.true_point[0] == sx * ex.true_point[1]          # the point is on the ray
        assert (ex.affine_depth == ex.correct_depth) == (v0[1] == v1[1] or ex.t in (0, 1))


@pytest.mark.parametrize("kwargs, name", [
    (dict(v0=(0, -1)), "depth"),
    (dict(screen_x=5), "screen_x"),
    (dict(v0=(2, 5)), "same screen point"),
    (dict(v1="ab"), "v0 and v1"),
])
def test_segment_example_errors(kwargs, name):
    with pytest.raises(ValueError, match=name):
        segment_example(**kwargs)


def test_gpu_reproduces_4_5_against_4(ctx):
    g = segment_example_gpu(ctx)
    # llvmpipe's noperspective and smooth barycentrics are within ~6e-5 / 1e-5 on a
    # triangle this size (DESIGN.md, measured here ~1e-7); depths span 2..5, so 3e-4
    # bounds the interpolated depths with margin and still separates 4 from 4.5 by 1000x.
    assert abs(g["screen_weight_B"] - 5 / 6) < 1e-4
    assert abs(g["affine_depth"] - 4.5) < 3e-4
    assert abs(g["correct_depth"] - 4.0) < 3e-4


def _ray_plane_uv(scene, H, W):
    """Analytic uv where each pixel-center ray meets the plane y = 0 (float64)."""
    inv = np.linalg.inv(scene.proj @ scene.view)
    ys, xs = np.mgrid[0:H, 0:W]
    ndc = np.stack([(xs + 0.5) / W * 2 - 1, (ys + 0.5) / H * 2 - 1], -1)
    def unproject(z):
        p = np.concatenate([ndc, np.full((H, W, 1), z), np.ones((H, W, 1))], -1) @ inv.T
        return p[..., :3] / p[..., 3:]
    a, b = unproject(-1.0), unproject(1.0)
    s = a[..., 1] / (a[..., 1] - b[..., 1])
    hit = a + s[..., None] * (b - a)
    return np.stack([(hit[..., 0] + 1) / 2, (1 - hit[..., 2]) / 2], -1)


def test_plane_correct_uv_is_the_ray_hit_and_affine_is_not(ctx):
    H, W = 72, 96
    plane = builtin_scenes((H, W))[0]
    res = render_scene_comparison(plane, (H, W), supersample=1, ctx=ctx)
    inside = res.coverage == 1.0
    uv = _ray_plane_uv(plane, H, W)
    err_c = np.abs(res.uv_correct - uv)[inside].max()
    err_a = np.abs(res.uv_affine - uv)[inside].max()
    # persp barycentric error (~1e-5 on llvmpipe, DESIGN.md) times uv extent 1, plus
    # float32 storage: 1e-4 uv = 1/1250 of a checker square.
    assert err_c < 1e-4, err_c
    # the affine image is off by several checker squares (measured 4.3 at 480x360)
    assert err_a * plane.checks > 2.0, err_a
    np.testing.assert_allclose(res.uv_error[inside] / plane.checks,
                               np.linalg.norm(res.uv_affine - res.uv_correct, axis=-1)[inside],
                               atol=1e-6)  # float32 storage of both


def test_affine_error_vanishes_at_vertices_and_peaks_inside(ctx):
    """The error map is where it should be: ~0 at the projected vertices, largest inside
    (on the seam that joins the nearest and farthest corners)."""
    H, W = 288, 384
    plane = builtin_scenes((H, W))[0]
    res = render_scene_comparison(plane, (H, W), supersample=1, ctx=ctx)
    win = cam.clip_to_window(cam.project(plane.vertices, None, plane.view, plane.proj,
                                         dtype=np.float64), (H, W))
    checked = 0
    for x, y, _ in win:
        if not (1 <= x < W - 1 and 1 <= y < H - 1):
            continue              # the near corners are below the image
        xi, yi = int(x), int(y)
        box = (slice(yi - 1, yi + 2), slice(xi - 1, xi + 2))
        patch = res.uv_error[box][res.coverage[box] == 1]
        # Covered pixels within 1.5 px of the vertex: the error there is at most 1.5 px
        # times its gradient, which at the far edge is ~0.1 squares/px at this resolution
        # (texture is compressed there); the interior reaches > 3 squares.
        assert patch.size and patch.min() < 0.15, patch
        checked += 1
    assert checked == 2
    assert res.stats["max_uv_error"] > 3.0
    # The maximum lies on the seam from the nearest corner (0) to the farthest (2): the
    # edge along which w varies most.  Within 1 px (pixel-center sampling of a ridge).
    y, x = np.unravel_index(np.argmax(res.uv_error), res.uv_error.shape)
    (ax, ay), (bx, by) = win[0, :2], win[2, :2]
    dist = abs((bx - ax) * (y + 0.5 - ay) - (by - ay) * (x + 0.5 - ax)) / np.hypot(bx - ax, by - ay)
    assert dist < 1.0, dist


def test_cli_writes_upright_complete_files(tmp_path, capsys, gl_backend):
    """`glraster distortion` (no required arguments) writes every file, upright."""
    import argparse
    import json

    import matplotlib.image as mpimg
    import OpenImageIO as oiio

    from glraster.cli.commands import distortion as cmd

    parser = argparse.ArgumentParser(prog="glraster")
    cmd.register(parser.add_subparsers(dest="command", required=True))
    assert parser.parse_args(["distortion"]).out == "out/distortion"
    H, W = 60, 80
    args = parser.parse_args(["distortion", "--backend", gl_backend, "--out", str(tmp_path),
                              "--width", str(W),
                              "--height", str(H), "--supersample", "1"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "9/2 = 4.5" in out and "= 4\n" in out
    s = json.loads((tmp_path / "summary.json").read_text())
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(["plane_affine.png", "plane_correct.png", "plane_diff.png",
                            "cube_affine.png", "cube_correct.png", "cube_diff.png",
                            "distortion_figure.png", "distortion.exr",
                            "segment_example.txt", "summary.json"])
    png = mpimg.imread(tmp_path / "plane_correct.png")
    assert png.shape[:2] == (H, W)
    # the plane lies below the horizon: upright files have background on top, plane at
    # the bottom (8-bit PNG: 1/255 tolerance)
    from glraster.studies.distortion import BACKGROUND
    np.testing.assert_allclose(png[0, :, :3], np.tile(BACKGROUND, (W, 1)), atol=1 / 255 + 1e-6)
    assert np.abs(png[-1, :, :3] - BACKGROUND).max() > 0.1

    inp = oiio.ImageInput.open(str(tmp_path / "distortion.exr"))
    spec = inp.spec()
    data = inp.read_image(oiio.FLOAT)
    inp.close()
    assert (spec.width, spec.height) == (W, H)
    assert "plane.correct.R" in spec.channelnames and "cube.uv_error.Y" in spec.channelnames
    assert spec.getattribute("glraster:orientation").startswith("upright")
    k = list(spec.channelnames).index("plane.correct.R")
    np.testing.assert_array_equal(data[0, :, k], np.float32(BACKGROUND[0]))   # top row
    assert "9/2" in (tmp_path / "segment_example.txt").read_text()
    assert s["segment_example"]["correct_depth"] == "4"
