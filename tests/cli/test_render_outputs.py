"""`glraster render` to an .npz, and multisampled scenes rendered at their own samples:
the arrays bit for bit those of glraster.rasterize / glraster.reference.rasterize with the
scene's samples and interpolation, and an EXR refused for per-sample results."""

from __future__ import annotations

import json

import numpy as np
import pytest

import glraster as gr
from glraster.cli import exit_codes, main
from glraster.conformance.scenes import load_scene, load_scene_file
from glraster.io.png import bary_rgb
from glraster.types import first_covered_sample, per_pixel

OUTPUTS = ("persp", "screen", "depth", "tri_id")


def _render(*args) -> int:
    return main(["render", *map(str, args)])


def _tri_scene_file(tmp_path, **fields):
    path = tmp_path / "tri.json"
    path.write_text(json.dumps({
        "pos": [[-0.9, -0.8, 0.1, 1.0], [2.7, -0.6, 0.6, 3.0], [-0.2, 0.9, 0.3, 1.0]],
        "tri": [[0, 1, 2]], "resolution": [24, 32], **fields}))
    return path


@pytest.mark.parametrize("name", ["ms_fan_offcenter", "ms_perspective_centroid"])
def test_a_multisampled_scene_renders_at_its_samples_into_an_npz(tmp_path, gl_backend, ctx,
                                                                  name):
    """Every array, the mask and the sample positions exactly as rasterize gives them at
    the scene's samples and interpolation ("sample" and "centroid"), and the metadata."""
    scene = load_scene(name)
    assert _render(name, "-o", tmp_path / "x.npz", "--backend", gl_backend) == exit_codes.OK
    want = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=OUTPUTS,
                        samples=scene.samples, interpolation=scene.interpolation)
    with np.load(tmp_path / "x.npz") as got:
        assert sorted(got.files) == sorted(OUTPUTS + ("mask", "sample_positions", "metadata"))
        for key in OUTPUTS + ("mask", "sample_positions"):
            np.testing.assert_array_equal(got[key], getattr(want, key), err_msg=key)
            assert got[key].dtype == getattr(want, key).dtype, key
        assert got["mask"].shape == scene.resolution + (scene.samples,)
        meta = json.loads(str(got["metadata"]))
    assert (meta["scene"], meta["samples"], meta["interpolation"]) == \
        (name, scene.samples, scene.interpolation)
    assert meta["scene_hash"] == scene.hash and gl_backend in meta["producer"]


def test_the_reference_npz_is_the_float64_reference_at_the_scenes_samples(tmp_path):
    scene = load_scene("ms_fan_offcenter")
    assert _render(scene.name, "-o", tmp_path / "r.npz", "--reference") == exit_codes.OK
    want = gr.reference.rasterize(scene.pos, scene.tri, scene.resolution, outputs=OUTPUTS,
                                  samples=scene.samples, interpolation=scene.interpolation)
    with np.load(tmp_path / "r.npz") as got:
        for key in OUTPUTS + ("mask", "sample_positions"):
            np.testing.assert_array_equal(got[key], getattr(want, key), err_msg=key)
        assert got["persp"].dtype == np.float64       # not rounded: an .npz holds float64
        assert "rounded" not in json.loads(str(got["metadata"]))["producer"]


def test_a_single_sample_npz_holds_the_pixels_arrays(tmp_path):
    scene = load_scene("basic_perspective_triangle")
    assert _render(scene.name, "-o", tmp_path / "s.npz", "--reference",
                   "--outputs", "persp,tri_id") == exit_codes.OK
    want = gr.reference.rasterize(scene.pos, scene.tri, scene.resolution,
                                  outputs=("persp", "tri_id"))
    with np.load(tmp_path / "s.npz") as got:
        assert sorted(got.files) == ["mask", "metadata", "persp", "sample_positions", "tri_id"]
        np.testing.assert_array_equal(got["persp"], want.persp)
        np.testing.assert_array_equal(got["mask"], want.mask)
        np.testing.assert_array_equal(got["sample_positions"], [[0.5, 0.5]])
        assert "samples" not in json.loads(str(got["metadata"]))


def test_an_exr_of_a_multisampled_scene_is_refused_before_anything_renders(tmp_path, capsys):
    """Exit 2 naming -o and the .npz to write instead; no file, nothing rendered."""
    out = tmp_path / "fan.exr"
    assert _render("ms_fan_offcenter", "-o", out, "--reference") == exit_codes.USAGE
    err = capsys.readouterr().err.strip()
    assert err == (f"glraster render: argument -o/--output: ms_fan_offcenter has 4 samples a "
                   f"pixel and an EXR holds one value a pixel: write an .npz "
                   f"(-o {tmp_path / 'fan.npz'})")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["-o", "x.tiff"], "output must end in .exr or .npz, got 'x.tiff'"),
    (["-o", "x.npz", "--crop"], "--crop crops an EXR's data window"),
])
def test_outputs_the_render_cannot_write_name_their_option(tmp_path, capsys, monkeypatch,
                                                           args, message):
    monkeypatch.chdir(tmp_path)
    assert _render("basic_triangle", "--reference", *args) == exit_codes.USAGE
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_scene_files_samples_and_interpolation_are_rendered(tmp_path):
    """A .json scene file's samples / interpolation fields and an .npz's 0-d arrays of those
    names give the reference at that sample count (8 samples: the reference has no driver
    limit); the same scene without them is one sample a pixel."""
    path = _tri_scene_file(tmp_path, samples=8, interpolation="sample")
    assert _render(path, "-o", tmp_path / "j.npz", "--reference") == exit_codes.OK
    scene = load_scene_file(path)
    np.savez(tmp_path / "n.npz", pos=scene.pos, tri=scene.tri, resolution=scene.resolution,
             samples=np.array(8), interpolation=np.array("sample"))
    assert _render(tmp_path / "n.npz", "-o", tmp_path / "n_out.npz", "--reference") == 0
    want = gr.reference.rasterize(scene.pos, scene.tri, scene.resolution, samples=8,
                                  interpolation="sample")
    for out in ("j.npz", "n_out.npz"):
        with np.load(tmp_path / out) as got:
            assert got["persp"].shape == (24, 32, 8, 3)
            np.testing.assert_array_equal(got["persp"], want.persp)
            np.testing.assert_array_equal(got["sample_positions"], want.sample_positions)
    assert load_scene_file(_tri_scene_file(tmp_path)).samples == 1


def _read_png(path) -> np.ndarray:
    """(H, W, 3) uint8, row 0 at the bottom as glraster's arrays."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.read_image("uint8")[::-1]
    finally:
        inp.close()


def test_the_preview_of_per_sample_values_shows_each_pixels_first_covered_sample(tmp_path):
    scene = load_scene("ms_fan_offcenter")
    assert _render(scene.name, "-o", tmp_path / "r.npz", "--png", tmp_path / "r.png",
                   "--reference") == exit_codes.OK
    with np.load(tmp_path / "r.npz") as got:
        mask, persp = got["mask"], got["persp"]
    want = bary_rgb(per_pixel(persp, first_covered_sample(mask)), mask.any(axis=2))
    np.testing.assert_array_equal(_read_png(tmp_path / "r.png"), want)


def test_samples_and_interpolation_options_override_the_scenes(tmp_path, gl_backend, ctx,
                                                              capsys):
    """--samples 4 --interpolation centroid on a single-sample scene gives rasterize at 4
    samples, centroid; --samples 1 makes a multisampled scene an EXR; a count that is no
    power of two names --samples."""
    scene = load_scene("basic_perspective_triangle")
    assert _render(scene.name, "--samples", "4", "--interpolation", "centroid", "-o",
                   tmp_path / "c.npz", "--backend", gl_backend) == exit_codes.OK
    want = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=OUTPUTS,
                        samples=4, interpolation="centroid")
    with np.load(tmp_path / "c.npz") as got:
        for key in OUTPUTS + ("mask",):
            np.testing.assert_array_equal(got[key], getattr(want, key), err_msg=key)
        meta = json.loads(str(got["metadata"]))
    assert (meta["samples"], meta["interpolation"]) == (4, "centroid")
    assert _render("ms_fan_offcenter", "--samples", "1", "-o", tmp_path / "one.exr",
                   "--reference") == exit_codes.OK
    capsys.readouterr()
    assert _render(scene.name, "--samples", "3", "-o", tmp_path / "x.npz",
                   "--reference") == exit_codes.USAGE
    assert capsys.readouterr().err.strip() == (
        "glraster render: argument --samples: samples must be a power of two >= 1 (1, 2, 4, "
        "8, ...), got 3")
    assert not (tmp_path / "x.npz").exists()
