"""pyrender depth cross-check (pyrender runs in a subprocess with PYOPENGL_PLATFORM=egl)."""

import numpy as np
import pytest

pytest.importorskip("pyrender")  # the `mesh` extra, installed by `make setup`

from glraster.geometry import camera as cam
from glraster.studies.crosscheck import (crosscheck_pyrender, default_camera, default_mesh,
                                 pyrender_depth, silhouette_band)


@pytest.fixture(scope="module")
def report(tmp_path_factory, gl_context):
    # Through a file, with an explicit camera, so loading and the K/view path are covered.
    mesh = default_mesh()
    path = tmp_path_factory.mktemp("cc") / "torus.ply"
    mesh.to_trimesh().export(path)
    K, view, near, far = default_camera(mesh, (120, 160))
    return crosscheck_pyrender(str(path), resolution=(120, 160), K=K, view=view,
                               near=near, far=far, ctx=gl_context)


def test_median_relative_depth_difference(report):
    assert report.compared > 2500
    # The target is 1e-4.  Measured ~8e-8: about one step of pyrender's 24-bit
    # depth (2^-24 z (f-n)/(n f) = 6e-8 relative here), so 1e-6 still leaves 10x margin.
    assert report.median_rel <= 1e-6, report.summary()


def test_max_difference_is_explained_by_the_error_model(report):
    # pyrender against the float64 reference stays inside the bound built from the
    # float32 depth-plane model, one 24-bit step and float32 linearization.
    assert report.ref_max_bound_ratio <= 1.0, report.summary()
    # glraster's own contribution is small: max within ~20 steps of 24-bit depth.
    assert report.max_rel_quanta <= 20, report.summary()


def test_msaa_sample_position_explains_pixel_center_offset(report):
    # pyrender's resolved depth is MSAA sample 0 of llvmpipe's 4x pattern, not the pixel
    # center; sampling glraster at the center instead is off by ~1e-3 on this tilted torus.
    assert report.sample.startswith("sample0 (0.375, 0.125)"), report.summary()
    assert report.median_rel_by_sample["center"] > 100 * report.median_rel


@pytest.mark.gl   # pyrender's own EGL context, in a subprocess
def test_pyrender_depth_rows_start_at_bottom():
    """A quad covering only the lower half of the image must show up in rows 0..H/2-1."""
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 0, 0], [-1, 0, 0]], float) * [4, 4, 1]
    F = np.array([[0, 1, 2], [0, 2, 3]])
    K = np.array([[20.0, 0, 15.5], [0, 20.0, 11.5], [0, 0, 1]])
    view = cam.look_at([0, 0, 2], [0, 0, 0])
    depth, info = pyrender_depth(V, F, K, (24, 32), view, 0.5, 5.0)
    assert depth.shape == (24, 32)
    assert (depth[:12] > 0).all() and (depth[12:] == 0).all()
    # the quad is at view depth 2 everywhere; 24-bit steps are ~2e-7 relative here
    np.testing.assert_allclose(depth[:12], 2.0, rtol=1e-5)
    assert len(info["sample_positions"]) == 4


def test_silhouette_band_marks_outline_and_depth_jumps():
    m = np.zeros((7, 9), bool)
    m[1:6, 1:8] = True
    d = np.where(m, 1.0, 0.0)
    d[:, 5:] *= 2.0                      # occlusion edge between columns 4 and 5
    band = silhouette_band(m, m, d, margin=0, jump=0.02)
    assert band[1, 1] and band[3, 4] and band[3, 5] and not band[3, 2]
    assert silhouette_band(m, m, d, margin=1)[3, 3]


def test_skewed_intrinsics_are_rejected():
    with pytest.raises(ValueError, match="K"):
        pyrender_depth(np.zeros((3, 3)), [[0, 1, 2]], [[10, 1, 5], [0, 10, 5], [0, 0, 1]],
                       (8, 8), np.eye(4), 0.1, 10)


def test_cli_crosscheck_pyrender(tmp_path, capsys, gl_backend):
    import argparse
    import json

    from glraster.cli.commands import crosscheck as cmd

    parser = argparse.ArgumentParser(prog="glraster")
    cmd.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["crosscheck", "pyrender", "--backend", gl_backend,
                              "--width", "64", "--height", "48",
                              "--json", str(tmp_path / "r.json")])
    assert args.func(args) == 0
    assert "PASS" in capsys.readouterr().out
    assert json.loads((tmp_path / "r.json").read_text())["median_rel"] <= 1e-4
