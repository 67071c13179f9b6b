"""Inverse rendering (glraster.torch.fitting, `glraster fit`): short versions of the three
fits, which must make clear progress, the figures they write, and the helpers.

The full runs (5 seeds x 1000 iterations per resolution, ...) are `glraster fit ...`
commands run once for docs/fitting.md; here one seed each, a few hundred iterations at
most, so that the file stays within a minute per backend on llvmpipe.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import glraster.torch as dr
from glraster.cli import main
from glraster.torch.fitting import common, cube, figures, pose, texture


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


# --------------------------------------------------------------------------- the fits


def test_cube_fit_at_8x8_cuts_the_vertex_error_tenfold(glctx):
    # 300 iterations instead of 1000 (the learning rate decays over the shorter run).
    # Measured: 0.46 -> 0.031 (15x), colour 0.40 -> 0.055; the full run's 1000 iterations
    # reach 0.00044 (docs/fitting.md).
    f = cube.fit_cube(glctx, 8, seed=1, iterations=300, views=4)
    assert f.antialias is True
    assert f.error.shape == (301,) and f.loss.shape == (300,)
    assert 0.3 < f.error[0] < 0.7
    assert f.error[-1] < f.error[0] / 10, f.error[::50]
    assert f.color_error[-1] < f.color_error[0] / 4
    assert {"target", "forward", "backward", "step"} <= set(f.timing)
    assert f.timing["forward"]["n"] == 300


def test_the_cube_fits_progress_labels_give_the_error_of_the_state_just_rendered(glctx):
    labels = []
    f = cube.fit_cube(glctx, 4, seed=0, iterations=6, views=2,
                      progress=lambda i, n, label: labels.append((i, n, label)))
    assert [(i, n) for i, n, _ in labels] == [(i, 6) for i in range(1, 7)]
    # iteration i renders state i - 1 (the start first): its error, as the fit records it
    assert [label for *_, label in labels] == [f"4x4 seed 0 error {e:.4f}" for e in f.error[:6]]


def test_pose_fit_recovers_the_rotation_with_symmetry_jumps(glctx):
    # Measured: 0.020 degrees (the full run's 8 restarts x 300 iterations: 3.4e-6).
    f = pose.fit_pose(glctx, 0, resolution=32, restarts=4, iterations=120)
    assert f.angle.shape == (121, 4) and len(f.jumps) == 2
    assert f.best_angle < 5.0, f.angle[-1]
    assert f.best == int(np.argmin(f.final_loss))


def test_texture_fit_mipmapped_beats_linear(glctx):
    # A small version of the full run: 32² px images, a 128 x 64 texture, 8 training views,
    # 120 iterations at a higher learning rate. Measured (held-out PSNR, from the grey
    # start's 11.5 dB): linear 14.8 dB, mipmapped 19.1 dB.
    data = texture.make_data(glctx, 0, resolution=32, texture_size=64, pool=8, eval_views=4)
    fits = {mip: texture.fit_texture(glctx, 0, mip=mip, resolution=32, texture_size=64,
                                     iterations=120, eval_every=60, data=data, lr=0.1)
            for mip in (False, True)}
    for f in fits.values():
        assert list(f.eval_iterations) == [0, 60, 120]
        assert f.eval_psnr[-1] > f.eval_psnr[0] + 2.0
        assert f.final.shape == (64, 128, 3)
    assert fits[True].eval_psnr[-1] > fits[False].eval_psnr[-1] + 2.0, \
        (fits[True].eval_psnr, fits[False].eval_psnr)


def test_fit_command_writes_curves_images_and_json(tmp_path, gl_backend, capsys):
    out = tmp_path / "figs"
    rc = main(["fit", "cube", "--resolutions", "4", "--seeds", "1", "--iterations", "20",
               "--out", str(out), "--json", str(tmp_path / "r.json"),
               "--backend", gl_backend])
    assert rc == 1  # 20 iterations do not reach the goal, which the exit code says
    captured = capsys.readouterr()
    text = captured.out
    assert "cube 4x4 seed 0: error" in text and "goal" in text and "MISSED" in text
    assert "20/20" in captured.err and "4x4 seed 0 error" in captured.err  # the progress bar
    for name in ("fit-cube-error.png", "fit-cube-before-after.png"):
        assert (out / name).stat().st_size > 1000
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["problem"] == "cube" and len(result["runs"]) == 1
    run = result["runs"][0]
    assert run["iterations"] == 20 and set(run["timing"]) >= {"forward", "backward"}


def test_fit_pose_and_texture_commands_write_their_files(tmp_path, gl_backend):
    # with their progress bars (stderr), which the cube fit's once broke
    rc = main(["fit", "pose", "--seeds", "1", "--iterations", "8", "--restarts", "2",
               "--out", str(tmp_path), "--backend", gl_backend])
    assert rc in (0, 1)
    rc = main(["fit", "texture", "--iterations", "4", "--resolution", "16",
               "--texture-size", "16", "--pool", "4", "--eval-every", "2",
               "--out", str(tmp_path), "--backend", gl_backend])
    assert rc in (0, 1)
    names = {p.name for p in tmp_path.iterdir()}
    assert {"fit-pose-error.png", "fit-pose-before-after.png", "fit-texture-psnr.png",
            "fit-texture-before-after.png", "fit-texture-views.png"} <= names


@pytest.mark.parametrize("argv, message", [
    (["cube", "--resolutions", "0"], "--resolutions must be positive"),
    (["cube", "--resolutions", "4,x"], "--resolutions must be comma-separated"),
    (["cube", "--views", "0"], "--views must be >= 1"),
    (["cube", "--first-seed", "-1"], "--first-seed must be >= 0, got -1"),
    (["cube", "--lr", "-1"], "argument --lr: must be a finite number > 0, got '-1'"),
    (["cube", "--lr", "nan"], "argument --lr: must be a finite number > 0, got 'nan'"),
    (["pose", "--restarts", "0"], "--restarts must be >= 1"),
    (["texture", "--views", "9", "--pool", "8"], "must not exceed --pool"),
])
def test_fit_command_rejects_bad_arguments_before_opening_gl(argv, message, capsys):
    try:
        code = main(["fit", *argv])
    except SystemExit as exit_:     # an option's argparse type refused its value
        code = exit_.code
    assert code == 2
    assert message in capsys.readouterr().err


# --------------------------------------------------------------------------- helpers (no GL)


def test_quaternion_matrices_are_rotations_and_angles_add_up():
    q = common.random_quaternions(np.random.default_rng(0), 50)
    r = common.quaternion_matrices(q)
    assert np.allclose(r @ np.swapaxes(r, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    rt = common.quaternion_matrices(torch.tensor(q))
    assert np.allclose(rt.numpy(), r)
    # a turn by theta about z
    theta = np.radians(37.0)
    qz = np.array([np.cos(theta / 2), 0, 0, np.sin(theta / 2)])
    assert np.allclose(common.quaternion_matrices(qz)[:2, :2],
                       [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    assert np.isclose(common.angle_degrees(qz, [1, 0, 0, 0]), 37.0)
    assert np.isclose(common.angle_degrees(-qz, qz), 0.0)
    # the Hamilton product composes the rotations
    a, b = q[:25], q[25:]
    assert np.allclose(common.quaternion_matrices(pose.multiply(a, b)),
                       common.quaternion_matrices(a) @ common.quaternion_matrices(b))


def test_the_24_symmetries_map_the_cube_onto_itself():
    s = pose.cube_symmetries()
    assert s.shape == (24, 4) and np.allclose(np.linalg.norm(s, axis=1), 1.0)
    verts = cube.cube()[0]
    key = {tuple(v) for v in np.round(verts, 9)}
    mats = common.quaternion_matrices(s)
    for m in mats:
        assert {tuple(v) for v in np.round(verts @ m.T, 9) + 0.0} == key
    # all different rotations
    flat = np.round(mats.reshape(24, 9), 9)
    assert len({tuple(r) for r in flat}) == 24


def test_psnr_and_the_picture_grid():
    a = np.zeros((4, 4, 3))
    b = np.full((4, 4, 3), 0.1)
    assert np.isclose(common.psnr(a, b), 20.0)
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    b[1:, :] = 1.0
    assert np.isclose(common.psnr(a, b, mask), 20.0)
    assert common.psnr(a, a) == np.inf
    g = figures.grid([[np.ones((2, 3, 3)), np.zeros((4, 2, 3))], [np.ones((1, 1, 3))]])
    gap = figures.GAP
    assert g.shape == (4 + 1 + 3 * gap, 3 + 2 + 3 * gap, 3)
    assert np.all(g[gap:gap + 2, gap:gap + 3] == 1.0)


def test_uv_sphere_and_texture():
    verts, faces, uv = texture.uv_sphere(8, 4)
    assert np.allclose(np.linalg.norm(verts, axis=1), 1.0)
    assert verts.shape == (9 * 5, 3) and faces.shape == (2 * 8 * 4, 3) and uv.shape == (45, 2)
    assert uv.min() == 0.0 and uv.max() == 1.0
    # the seam: u = 0 and u = 1 are the same points
    assert np.allclose(verts[:5], verts[-5:])
    tex = texture.procedural_texture(16)
    assert tex.shape == (16, 32, 3) and tex.min() >= 0.0 and tex.max() <= 1.0


def test_fit_without_a_backend_is_exit_code_3(tmp_path):
    # EGL with no vendor library finds no device (as tests/cli/test_exit_codes.py)
    env = {**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent"}
    result = subprocess.run([sys.executable, "-m", "glraster.cli", "fit", "pose", "--out",
                             str(tmp_path / "p"), "--backend", "egl"], check=False,
                            capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 3, result.stderr
    assert not list(tmp_path.iterdir())
