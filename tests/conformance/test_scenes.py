"""The scene catalog: size, coverage of the required cases, determinism, validation."""

import json

import numpy as np
import pytest

from glraster.conformance.scenes import (ALL_OUTPUTS, list_scenes, load_scene, load_scene_file,
                             make_scene, resolve, scene_hash)


def window_xy(scene):
    """(V, 2) float64 window coordinates of the vertices with w > 0."""
    p = scene.pos.astype(np.float64)
    h, w = scene.resolution
    ok = p[:, 3] > 0
    return (p[ok, :2] / p[ok, 3:4] + 1) * np.array([w / 2, h / 2])


def test_catalog_has_at_least_25_scenes_with_valid_arrays():
    names = list_scenes()
    assert len(names) >= 25
    assert len(set(names)) == len(names)
    for n in names:
        s = load_scene(n)
        assert s.pos.dtype == np.float32 and s.pos.shape[1] == 4
        assert s.tri.dtype == np.int32 and s.tri.shape[1] == 3
        assert s.tri.min() >= 0 and s.tri.max() < len(s.pos)
        assert np.isfinite(s.pos).all()
        assert set(s.outputs) <= set(ALL_OUTPUTS)
        assert s.description


def test_scenes_are_deterministic_and_hash_stable():
    # Building the same recipe twice gives the same bytes: the goldens rely on it.
    from glraster.conformance.scenes import _entry, build_scene

    for n in ("soup_10k", "torus", "slivers"):
        a = build_scene(_entry(n))
        assert scene_hash(a.pos, a.tri, a.resolution) == load_scene(n).hash


def test_required_categories_are_present():
    names = set(list_scenes())
    for required in ("perspective_floor", "checker_quad", "icosphere", "torus", "slivers",
                     "subpixel_triangles", "guard_band", "near_plane_crossing",
                     "behind_camera", "w_extreme_ratios", "far_from_origin_4096",
                     "depth_fighting", "soup_10k", "mesh_100k"):
        assert required in names
    assert any(n.startswith("fan_") for n in names)
    assert any(n.startswith("grid_") for n in names)
    assert any(n.startswith("ortho_") for n in names)
    assert any(n.startswith("basic_") for n in names)


def test_slivers_reach_aspect_1e4():
    s = load_scene("slivers")
    v = window_xy(s)[s.tri]                       # (T, 3, 2)
    e = np.linalg.norm(v - v[:, [1, 2, 0]], axis=2)
    a, b = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    cross = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    aspect = e.max(1) ** 2 / cross                # longest edge / height
    # The recipe log-spaces aspect 10..1e4; float32 rounding of the apex moves it by <1 %.
    assert aspect.max() == pytest.approx(1e4, rel=0.02)
    assert aspect.min() < 20


def test_w_ratios_span_1e_minus3_to_1e3():
    w = load_scene("w_extreme_ratios").pos[:, 3].astype(np.float64)
    assert w.min() == pytest.approx(1e-3, rel=1e-6)   # float32 rounding of 1e-3
    assert w.max() == pytest.approx(1e3, rel=1e-6)


def test_behind_camera_and_near_plane_scenes_cross_the_planes():
    p = load_scene("behind_camera").pos
    assert (p[:, 3] < 0).any() and (p[:, 3] > 0).any()
    q = load_scene("near_plane_crossing").pos
    assert (q[:, 2] < -q[:, 3]).any()                 # before the near plane
    assert (q[:, 2] > q[:, 3]).any()                  # beyond the far plane


def test_guard_band_vertices_are_far_outside():
    p = load_scene("guard_band").pos.astype(np.float64)
    ndc = np.abs(p[:, :2] / p[:, 3:4])
    assert ndc.max() > 1e4
    assert (ndc.max(1) < 1).any()                     # and some inside the viewport


def test_far_from_origin_scene_is_small_triangles_in_a_4096_corner():
    s = load_scene("far_from_origin_4096")
    assert s.resolution == (4096, 4096)
    v = window_xy(s)
    assert v.min() > 3700
    size = np.ptp(v[s.tri], axis=1).max(1)
    assert size.max() < 30


def test_big_scenes_have_the_promised_triangle_counts():
    assert len(load_scene("soup_10k").tri) == 10_000
    assert len(load_scene("mesh_100k").tri) >= 100_000


def test_list_scenes_pattern():
    assert list_scenes("grid_*") == [n for n in list_scenes() if n.startswith("grid_")]
    assert list_scenes("torus,icosphere") == ["icosphere", "torus"]
    assert list_scenes("nothing*") == []


def test_user_scene_files_round_trip(tmp_path):
    pos = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]], np.float32)
    np.savez(tmp_path / "s.npz", pos=pos, tri=np.array([[0, 1, 2]]), resolution=[32, 48])
    s = load_scene_file(tmp_path / "s.npz")
    assert s.resolution == (32, 48) and s.name == "s"
    (tmp_path / "t.json").write_text(json.dumps(
        {"pos": pos.tolist(), "tri": [[0, 1, 2]], "resolution": [8, 8]}))
    assert resolve(str(tmp_path / "t.json")).resolution == (8, 8)
    (tmp_path / "r.json").write_text(json.dumps(
        {"resolution": [64, 64], "builder": "soup",
         "params": {"count": 5, "size_px": [2, 4], "seed": 1}}))
    assert len(load_scene_file(tmp_path / "r.json").tri) == 5
    (tmp_path / "m.json").write_text(json.dumps(
        {"pos": pos.tolist(), "tri": [[0, 1, 2]], "resolution": [8, 8], "samples": 4,
         "interpolation": "centroid", "tags": ["multisample"]}))
    m = load_scene_file(tmp_path / "m.json")
    assert (m.samples, m.interpolation, m.tags) == (4, "centroid", ("multisample",))
    np.savez(tmp_path / "m.npz", pos=pos, tri=np.array([[0, 1, 2]]), resolution=[8, 8],
             samples=np.array(2), interpolation=np.array("sample"))
    m = load_scene_file(tmp_path / "m.npz")
    assert (m.samples, m.interpolation) == (2, "sample")
    assert resolve("ms_fan_offcenter@2x").samples == 2   # a catalog scene at another count


@pytest.mark.parametrize("content, message", [
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 1]], "resolution": [4, 4]}, "tri index 1 is out of range"),
    ({"pos": [[0, 0, 0]], "tri": [[0, 0, 0]], "resolution": [4, 4]}, "pos must have shape"),
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0]], "resolution": [4]}, "resolution"),
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0]], "resolution": [0, 4]}, "resolution"),
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0.5]], "resolution": [4, 4]}, "integer"),
    ({"pos": [[0, 0, 0, 1e39]], "tri": [[0, 0, 0]], "resolution": [4, 4]}, "finite"),
    ({"tri": [[0, 0, 0]], "resolution": [4, 4]}, "missing field"),
    ({"resolution": [4, 4], "builder": "nope"}, "unknown builder"),
    ({"resolution": [4, 4], "builder": "soup", "params": {"bogus": 1}}, "bad parameters"),
    ({"resolution": [4, 4], "builder": "soup", "params": {"count": -5, "size_px": [2, 4]}},
     "bad parameters for builder 'soup': negative dimensions"),   # numpy's ValueError
    ({"resolution": [4, 4], "builder": "soup", "params": [5]}, "params must be an object"),
    # a field the format does not have is refused, not ignored (a misspelt "samples")
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0]], "resolution": [4, 4], "sample": 4},
     "unknown field 'sample'; a scene file's fields are pos, tri, resolution, name, "
     "description, outputs, tags, samples, interpolation"),
    ({"resolution": [4, 4], "builder": "soup", "param": {}, "cull": False},
     "unknown fields 'param', 'cull'; a recipe's fields are builder, params"),
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0]], "resolution": [4, 4], "samples": 3},
     "samples must be a power of two"),
    ({"pos": [[0, 0, 0, 1]], "tri": [[0, 0, 0]], "resolution": [4, 4],
      "interpolation": "flat"}, "interpolation"),
])
def test_bad_user_scene_files_raise_clear_errors(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(ValueError, match=message) as info:
        load_scene_file(path)
    assert str(path) in str(info.value)                # the error names the file


def test_bad_file_types_and_npz(tmp_path):
    with pytest.raises(ValueError, match="no such scene file"):
        load_scene_file(tmp_path / "missing.npz")
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(ValueError, match="unsupported scene file type"):
        load_scene_file(tmp_path / "x.txt")
    (tmp_path / "t.npz").write_text("x")             # not a zip archive at all
    with pytest.raises(ValueError, match="not a .npz file"):
        load_scene_file(tmp_path / "t.npz")
    np.savez(tmp_path / "m.npz", pos=np.zeros((3, 4)))
    with pytest.raises(ValueError, match="missing array"):
        load_scene_file(tmp_path / "m.npz")
    np.savez(tmp_path / "o.npz", pos=np.zeros((3, 4)), tri=np.array([[0, 1, 2]], object),
             resolution=[8, 8])                 # object arrays would need pickle
    with pytest.raises(ValueError, match=r"o.npz: array 'tri' cannot be read \(Object arrays"):
        load_scene_file(tmp_path / "o.npz")
    np.savez(tmp_path / "u.npz", pos=np.zeros((3, 4)), tri=[[0, 1, 2]], resolution=[8, 8],
             uv=np.zeros((3, 2)))
    with pytest.raises(ValueError, match="u.npz: unknown array 'uv'; a scene file's arrays "
                                         "are pos, tri, resolution, name, samples, "
                                         "interpolation"):
        load_scene_file(tmp_path / "u.npz")
    (tmp_path / "j.json").write_text("{not json")
    with pytest.raises(ValueError, match="invalid JSON"):
        load_scene_file(tmp_path / "j.json")
    with pytest.raises(ValueError, match="unknown scene"):
        load_scene("no_such_scene")


def test_scene_arrays_are_read_only():
    s = load_scene("basic_triangle")
    with pytest.raises(ValueError):
        s.pos[0, 0] = 1.0
    with pytest.raises(ValueError, match="outputs"):
        make_scene("x", s.pos, s.tri, (4, 4), outputs=("color",))
