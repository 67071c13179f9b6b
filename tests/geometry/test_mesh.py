"""load_mesh for each file format, scene flattening, render_scene with pyrender scenes."""

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")  # the `mesh` extra, installed by `make setup`

import glraster as gr
from glraster.geometry import camera as cam
from glraster.geometry.mesh import Mesh, load_mesh, scene_geometry
from glraster.gpu.render import render_scene

QUAD_OBJ = """\
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
vt 0 0
vt 1 0
vt 0 1
vt 1 1
vn 0 0 1
f 1/1/1 2/2/1 4/4/1 3/3/1
"""


def test_obj_with_uv_and_normals(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text(QUAD_OBJ)
    m = load_mesh(p)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    # the quad is split into two triangles over the same four vertices, in file order
    assert m.faces.shape == (2, 3) and sorted(set(m.faces.ravel())) == [0, 1, 2, 3]
    np.testing.assert_array_equal(m.uv, m.vertices[:, :2])   # vt equals (x, y) here
    np.testing.assert_array_equal(m.normals, np.tile([0.0, 0.0, 1.0], (4, 1)))


def test_obj_without_extras(tmp_path):
    p = tmp_path / "tri.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    m = load_mesh(p)
    assert m.uv is None and m.normals is None
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


@pytest.mark.parametrize("ext", ["ply", "stl", "glb"])
def test_box_round_trips_through_format(tmp_path, ext):
    box = trimesh.creation.box(extents=(1.0, 2.0, 4.0))
    p = tmp_path / f"box.{ext}"
    box.export(p)
    m = load_mesh(p)
    assert len(m.faces) == 12
    # Triangles are the same set of corner positions; every coordinate (+-0.5, +-1, +-2)
    # is exact in float32, so the comparison is exact.
    got = np.sort(m.vertices[m.faces].reshape(12, 9), axis=0)
    want = np.sort(box.vertices[box.faces].reshape(12, 9), axis=0)
    np.testing.assert_array_equal(got, want)


def test_trimesh_scene_applies_node_transforms(tmp_path):
    s = trimesh.Scene()
    move = trimesh.transformations.translation_matrix
    s.add_geometry(trimesh.creation.box(), transform=move([5, 0, 0]))
    s.add_geometry(trimesh.creation.box(), transform=move([0, -3, 0]))
    for src in (s, tmp_path / "two.glb"):
        if not isinstance(src, trimesh.Scene):
            s.export(src)
        m = load_mesh(src)
        assert len(m.faces) == 24
        np.testing.assert_array_equal(m.vertices.min(0), [-0.5, -3.5, -0.5])
        np.testing.assert_array_equal(m.vertices.max(0), [5.5, 0.5, 0.5])


def test_accepts_trimesh_and_mesh():
    box = trimesh.creation.box()
    m = load_mesh(box)
    np.testing.assert_array_equal(m.vertices, box.vertices)
    assert load_mesh(m) is m


def test_load_errors(tmp_path):
    with pytest.raises(ValueError, match="source"):
        load_mesh(tmp_path / "missing.obj")
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(ValueError, match=r"pts.obj' contains no triangles \(trimesh read it "
                                         r"as a PointCloud\)"):
        load_mesh(tmp_path / "pts.obj")
    with pytest.raises(ValueError, match="source must be a mesh file path, .* got int"):
        load_mesh(42)
    with pytest.raises(ValueError, match="faces"):
        Mesh(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ValueError, match="uv"):
        Mesh(np.zeros((3, 3)), [[0, 1, 2]], uv=np.zeros((2, 2)))


def _pyrender_quad_scene():
    pyrender = pytest.importorskip("pyrender")
    quad = trimesh.Trimesh([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]],
                           [[0, 1, 2], [0, 2, 3]], process=False)
    scene = pyrender.Scene()
    # quad node pushed 2 units down -z; camera node at the origin, shifted right by 0.25
    pose = np.eye(4)
    pose[2, 3] = -2.0
    scene.add(pyrender.Mesh.from_trimesh(quad, smooth=False), pose=pose)
    cam_pose = np.eye(4)
    cam_pose[0, 3] = 0.25
    scene.add(pyrender.IntrinsicsCamera(64.0, 64.0, 32.0, 32.0, znear=0.5, zfar=10.0),
              pose=cam_pose)
    return scene


def test_render_pyrender_scene_covers_expected_rectangle(ctx):
    """Quad x in [-0.75, 0.25], y in [-0.5, 0.5] (camera frame) at depth 2, f = 64 px and
    (pyrender's convention) the principal point at window (32, 32): it spans window
    x in [8, 40], y in [16, 48].  Those are pixel edges, so coverage is unambiguous."""
    r = render_scene(_pyrender_quad_scene(), (64, 64), ctx=ctx, outputs=("tri_id", "depth"))
    want = np.zeros((64, 64), bool)
    want[16:48, 8:40] = True
    np.testing.assert_array_equal(r.mask, want)
    geo = r.info["geometry"]
    assert geo.mesh.faces.shape == (2, 3)
    # view depth is 2 everywhere on the quad (exact: pose translation only); pyrender's
    # flat shading un-indexes the 4 corners into 6 vertices
    np.testing.assert_array_equal(geo.view_depth, np.full(len(geo.mesh.vertices), 2.0))


def test_render_scene_equals_rasterize_of_flattened_geometry(ctx):
    scene = _pyrender_quad_scene()
    geo = scene_geometry(scene, (40, 56))
    direct = gr.rasterize(cam.project(geo.mesh.vertices, None, geo.view, geo.proj), geo.tri,
                          (40, 56), ctx=ctx, outputs=("persp", "tri_id"))
    via = render_scene(scene, (40, 56), ctx=ctx, outputs=("persp", "tri_id"))
    # same float32 inputs on the same driver: bit-identical
    np.testing.assert_array_equal(via.tri_id, direct.tri_id)
    np.testing.assert_array_equal(via.persp, direct.persp)


def test_trimesh_gets_a_framing_camera(ctx):
    r = render_scene(trimesh.creation.icosphere(subdivisions=2), (48, 64), ctx=ctx,
                     outputs=("tri_id",))
    ys, xs = np.nonzero(r.mask)
    # the whole sphere is inside the image, with a margin, and fills a good part of it
    assert 0 < xs.min() and xs.max() < 63 and 0 < ys.min() and ys.max() < 47
    assert r.mask.mean() > 0.25


def test_scene_without_camera_needs_view_and_proj():
    pyrender = pytest.importorskip("pyrender")
    scene = pyrender.Scene()
    scene.add(pyrender.Mesh.from_trimesh(trimesh.creation.box()))
    with pytest.raises(ValueError, match="camera"):
        scene_geometry(scene)
    with pytest.raises(ValueError, match="resolution"):
        scene_geometry(scene, (0, 4), view=np.eye(4), proj=np.eye(4))


def test_interpolating_the_uv_of_a_mesh_without_uv_says_so(tmp_path):
    """A file without texture coordinates gives uv None; interpolating it names attr and
    the missing UVs (it said "attr must be numeric, got dtype object")."""
    import glraster as gr
    from glraster.types import Raster

    p = tmp_path / "tri.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    m = load_mesh(p)
    raster = Raster((2, 2), np.zeros((2, 2), bool), persp=np.zeros((2, 2, 3), np.float32),
                    tri_id=np.full((2, 2), -1, np.int32))
    with pytest.raises(ValueError, match=r"^attr is None: .* no texture coordinates has uv "
                                         r"None"):
        gr.interpolate(m.uv, raster, m.faces)
