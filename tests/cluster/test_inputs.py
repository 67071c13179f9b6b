"""Dataset items, shard plans, the crash ledger and the batch command's usage errors: no
GL and no Ray cluster needed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from glraster.cli import exit_codes, main
from glraster.cluster import inputs, shards
from glraster.errors import ArgumentError
from glraster.geometry import camera


def _views(tmp_path, cameras, **extra):
    verts = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0], [0, 0, -1]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    np.savez(tmp_path / "mesh.npz", vertices=verts, faces=faces)
    path = tmp_path / "views.json"
    path.write_text(json.dumps({"mesh": "mesh.npz", "resolution": [48, 64],
                                "cameras": cameras, **extra}))
    return path, verts, faces


def test_a_views_file_is_one_scene_per_camera_projected_as_the_camera_module_does(tmp_path):
    """Each camera form gives exactly camera.project of the mesh with its matrices."""
    K = [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]]
    cams = [{"eye": [0, 0, 4], "target": [0, 0, 0], "fovy": 40, "near": 0.1, "far": 50},
            {"K": K, "R": np.eye(3).tolist(), "t": [0, 0, 4], "near": 0.1, "far": 50},
            {"view": camera.look_at([1, 1, 4], [0, 0, 0]).tolist(),
             "proj": camera.perspective(50, 64 / 48, 0.5, 20).tolist()}]
    path, verts, faces = _views(tmp_path, cams, outputs=["persp", "tri_id"])
    items = inputs.list_items(path)
    assert items == [f"{path}#0", f"{path}#1", f"{path}#2"]
    expected = [
        camera.project(verts, view=camera.look_at([0, 0, 4], [0, 0, 0]),
                       proj=camera.perspective(40, 64 / 48, 0.1, 50)),
        camera.project(verts, view=camera.view_from_opencv(np.eye(3), [0, 0, 4]),
                       proj=camera.from_intrinsics(K, 64, 48, 0.1, 50)),
        camera.project(verts, view=np.array(cams[2]["view"]), proj=np.array(cams[2]["proj"]))]
    for item, pos in zip(items, expected):
        scene = inputs.load_item(item)
        assert scene.resolution == (48, 64) and scene.outputs == ("persp", "tri_id")
        np.testing.assert_array_equal(scene.pos, pos)  # the same float64 product, rounded once
        np.testing.assert_array_equal(scene.tri, faces)


def test_bad_views_and_sources_name_what_is_wrong(tmp_path):
    path, _, _ = _views(tmp_path, [{"eye": [0, 0, 4]}])
    with pytest.raises(ValueError, match="camera 0 lacks .target."):
        inputs.list_items(path)
    with pytest.raises(ValueError, match="does not exist"):
        inputs.list_items(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no scene"):
        inputs.list_items(tmp_path / "empty")
    (tmp_path / "x.exr").write_bytes(b"")
    with pytest.raises(ValueError, match="must be a folder"):
        inputs.list_items(tmp_path / "x.exr")


def test_folders_and_lists_keep_a_sorted_fixed_order(tmp_path):
    for name in ("b.npz", "a.json", "c.txt", ".hidden.npz", "sub/d.npz"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("{}")
    assert inputs.list_items(tmp_path) == [str(tmp_path / n) for n in ("a.json", "b.npz",
                                                                       "sub/d.npz")]
    (tmp_path / "list.txt").write_text("# scenes\nb.npz\n\n/abs/x.npz\n")
    assert inputs.list_items(tmp_path / "list.txt") == [str(tmp_path / "b.npz"), "/abs/x.npz"]


def test_the_plan_cuts_items_in_order_and_refuses_a_bad_size():
    plan = shards.plan([f"s{i}" for i in range(10)], 4)
    assert [s.items for s in plan] == [("s0", "s1", "s2", "s3"), ("s4", "s5", "s6", "s7"),
                                       ("s8", "s9")]
    assert [s.file for s in plan] == ["shard-00000.npz", "shard-00001.npz", "shard-00002.npz"]
    for bad in (0, -1, 2.5, True, "4"):
        with pytest.raises(ValueError, match="shard_size must be a positive integer"):
            shards.plan(["a"], bad)


def test_a_shard_file_says_which_items_it_finished(tmp_path):
    shard = shards.Shard(3, ("a.npz", "b.npz"))
    lines = shards.write_shard(tmp_path, shard, [{"depth": np.ones((2, 3), np.float32)},
                                                 "ValueError: bad"])
    assert lines == [{"scene": "a.npz", "shard": "shard-00003.npz",
                      "keys": {"depth": "s0000.depth"}},
                     {"scene": "b.npz", "shard": "shard-00003.npz", "keys": {},
                      "error": "ValueError: bad"}]
    assert shards.finished(tmp_path, shard) == lines
    assert shards.finished(tmp_path, shards.Shard(3, ("a.npz", "c.npz"))) is None  # re-planned
    with np.load(tmp_path / shard.file) as z:
        np.testing.assert_array_equal(z["s0000.depth"], np.ones((2, 3), np.float32))
    (tmp_path / shard.file).write_bytes(b"PK\x03\x04 torn")
    assert shards.finished(tmp_path, shard) is None


def test_the_crash_ledger_blames_an_item_after_two_deaths_at_it(tmp_path):
    """Attempt 1 dies somewhere (unknown); attempts 2 and 3 die at item 1; attempt 4 sees two
    deaths there and skips it. The ledger is gone once the shard is done."""
    shard = shards.Shard(0, ("a", "b", "c"))
    first = shards.CrashLedger(tmp_path, shard)
    first.starting(0)          # not recorded: a first attempt marks only that it started
    for _ in range(2):
        ledger = shards.CrashLedger(tmp_path, shard)
        assert ledger.crashes(1) < shards.CRASHES_BEFORE_ERROR
        ledger.starting(0)
        ledger.starting(1)     # ... and dies here
    last = shards.CrashLedger(tmp_path, shard)
    assert [last.crashes(k) for k in range(3)] == [0, 2, 0]
    last.done()
    assert not (tmp_path / shards.LEDGER_DIR).exists()


def test_batch_and_check_usage_errors_exit_2_before_starting_ray(tmp_path, capsys):
    assert main(["batch", str(tmp_path / "missing"), str(tmp_path / "out")]) == exit_codes.USAGE
    assert "does not exist" in capsys.readouterr().err
    assert main(["batch", str(tmp_path), str(tmp_path / "out")]) == exit_codes.USAGE
    assert main(["batch"]) == exit_codes.USAGE
    (tmp_path / "s.json").write_text("{}")
    assert main(["batch", str(tmp_path), str(tmp_path / "o"), "--shard-size", "0"]) == 2
    assert "--shard-size" in capsys.readouterr().err
    assert main(["batch", str(tmp_path), str(tmp_path / "o"), "--outputs", "colour"]) == 2
    assert main(["check", "--drivers", "llvmpipe"]) == exit_codes.USAGE
    assert "need --ray" in capsys.readouterr().err
    assert main(["check", "--ray", "--drivers", "LLVM pipe"]) == exit_codes.USAGE
    assert main(["check", "--ray", "--methods", "nope"]) == exit_codes.USAGE
    assert main(["check", "--ray", "--mutants"]) == exit_codes.USAGE


def test_without_ray_the_commands_name_the_extra_to_install(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if not installed
    (tmp_path / "s.json").write_text(json.dumps({"pos": [[0, 0, 0, 1]] * 3, "tri": [[0, 1, 2]],
                                                 "resolution": [4, 4]}))
    assert main(["batch", str(tmp_path), str(tmp_path / "out")]) == exit_codes.USAGE
    assert "pip install 'glraster[ray]'" in capsys.readouterr().err
    assert not list((tmp_path / "out").glob("*.npz"))


def test_actor_slots_share_a_nodes_cpus_among_its_drivers_and_give_gpu_drivers_a_gpu():
    from glraster.cluster.fleet import _actor_slots

    small = {"id": "a", "name": "a", "cpus": 2, "gpus": 0, "slots": 2}
    big = {"id": "b", "name": "b", "cpus": 8, "gpus": 2, "slots": 8}
    slots = _actor_slots({"llvmpipe": [small, big], "softpipe": [small], "nvidia": [big]},
                         ["llvmpipe", "softpipe", "nvidia"])
    count = {}
    for driver, node, cpus, gpus in slots:
        count[(driver, node["id"])] = count.get((driver, node["id"]), 0) + 1
        assert gpus == (1.0 if driver == "nvidia" else 0.0)
    assert count == {("llvmpipe", "a"): 1, ("softpipe", "a"): 1, ("llvmpipe", "b"): 4,
                     ("nvidia", "b"): 2}
    tiny = {"id": "c", "name": "c", "cpus": 1, "gpus": 0, "slots": 1}
    shares = [cpus for _, _, cpus, _ in _actor_slots({"llvmpipe": [tiny], "softpipe": [tiny]},
                                                     ["llvmpipe", "softpipe"])]
    assert shares == [0.5, 0.5]  # never more CPUs asked than the node has


def test_driver_names_from_renderer_strings():
    from glraster.cluster.runtime import check_driver_names, driver_name

    assert driver_name("llvmpipe (LLVM 15.0.6, 256 bits)") == "llvmpipe"
    assert driver_name("softpipe") == "softpipe"
    assert driver_name("zink (llvmpipe (LLVM 15.0.6, 256 bits))") == "zink"
    assert driver_name("AMD Radeon RX 6800 (radeonsi, navi21, LLVM 15.0.6, DRM 3.49)") == \
        "radeonsi"
    assert driver_name("NVIDIA H200/PCIe/SSE2", "NVIDIA Corporation") == "nvidia"
    assert driver_name("Mesa Intel(R) UHD Graphics 620 (KBL GT2)") == "iris"
    assert check_driver_names("llvmpipe, softpipe") == ["llvmpipe", "softpipe"]
    for bad in ("", "llvmpipe,,softpipe", "llvmpipe,llvmpipe", "Mesa Intel"):
        with pytest.raises(ValueError, match="drivers"):
            check_driver_names(bad)


def test_a_views_file_sets_samples_and_interpolation_for_every_camera(tmp_path):
    """"samples" / "interpolation" reach each camera's scene, which render_scene renders
    at them (tests/cluster/test_render_scene.py)."""
    cams = [{"eye": [0, 0, 4], "target": [0, 0, 0], "fovy": 40, "near": 0.1, "far": 50},
            {"view": np.eye(4).tolist()}]
    path, _, _ = _views(tmp_path, cams, samples=4, interpolation="sample")
    scenes = [inputs.load_item(item) for item in inputs.list_items(path)]
    assert [(s.samples, s.interpolation) for s in scenes] == [(4, "sample")] * 2
    (tmp_path / "plain").mkdir()
    plain, _, _ = _views(tmp_path / "plain", cams)
    assert inputs.load_item(inputs.list_items(plain)[0]).samples == 1


@pytest.mark.parametrize("extra, cameras, message", [
    ({"sample": 4}, None, r"unknown field 'sample'; a views file's fields are mesh, "
                          r"resolution, cameras, outputs, samples, interpolation"),
    ({"samples": 3}, None, r"samples must be a power of two"),
    ({"interpolation": "middle"}, None, r"interpolation must be one of"),
    ({}, [{"eye": [0, 0, 4], "target": [0, 0, 0], "fovy": 40, "near": 0.1, "far": 50,
           "samples": 4}],
     r"camera 0: unknown field 'samples'; an eye/target/up camera's fields are eye, "),
    ({}, [{"K": np.eye(3).tolist(), "R": np.eye(3).tolist(), "t": [0, 0, 4], "near": 0.1,
           "far": 50, "eye": [0, 0, 4]}],
     r"camera 0: unknown field 'eye'; a K/R/t camera's fields are K, R, t, near, far"),
    ({}, [{"proj": np.eye(4).tolist(), "fovy": 40}],
     r"camera 0: unknown field 'fovy'; a view/proj camera's fields are view, proj"),
    ({}, [[0, 0, 4]], r"camera 0 must be an object, got list"),
])
def test_a_views_file_field_it_does_not_have_is_named(tmp_path, extra, cameras, message):
    """A misspelt or misplaced field is an error, never ignored (as in scene files)."""
    default = [{"eye": [0, 0, 4], "target": [0, 0, 0], "fovy": 40, "near": 0.1, "far": 50}]
    path, _, _ = _views(tmp_path, cameras or default, **extra)
    with pytest.raises(ArgumentError, match=message) as info:
        inputs.list_items(path)
    assert info.value.argument in ("path", "samples", "interpolation")
