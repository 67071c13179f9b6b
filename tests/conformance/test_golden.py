"""Golden EXRs: present for every scene, small, reproduced bit for bit by the reference."""

import shutil

import numpy as np

from glraster.io import exr
from glraster.conformance import golden
from glraster.conformance.scenes import list_scenes, load_scene

BUDGET = 20 * 1024 * 1024


def test_every_scene_has_a_golden_and_the_folder_fits_the_budget():
    d = golden.golden_dir()
    names = list_scenes()
    assert sorted(p.stem for p in d.glob("*.exr")) == sorted(names)
    assert golden.folder_size() < BUDGET


def test_reference_reproduces_every_golden_bit_for_bit():
    # Exactness, not a tolerance: the reference is deterministic float64 NumPy and the
    # golden stores its float32 rounding.
    results = golden.check()
    bad = [f"{r.name}: {r.message}" for r in results if not r.ok]
    assert not bad, "\n".join(bad)


def test_golden_metadata_names_scene_hash_producer_and_version():
    g = exr.read_raster(golden.golden_path("torus"))
    assert g.metadata["scene"] == "torus"
    assert g.metadata["scene_hash"] == load_scene("torus").hash
    assert "reference" in g.metadata["producer"]
    assert g.metadata["version"]
    assert "upright" in g.metadata["orientation"]


def test_large_viewport_golden_is_cropped_to_coverage():
    g = exr.read_raster(golden.golden_path("far_from_origin_4096"))
    y0, y1, x0, x1 = g.window
    assert g.resolution == (4096, 4096)
    assert y0 > 3700 and x0 > 3700 and (y1 - y0) * (x1 - x0) < 400 * 400


def test_check_detects_a_single_changed_bit(tmp_path):
    shutil.copy(golden.golden_path("basic_triangle"), tmp_path / "basic_triangle.exr")
    g = exr.read_raster(tmp_path / "basic_triangle.exr")
    persp = g.full("persp")
    ys, xs = np.nonzero(g.full("tri_id") >= 0)
    persp[ys[0], xs[0], 1] = np.nextafter(persp[ys[0], xs[0], 1], np.float32(2))
    exr.write_raster(tmp_path / "basic_triangle.exr", persp=persp, screen=g.full("screen"),
                     depth=g.full("depth"), tri_id=g.full("tri_id"), metadata=g.metadata)
    res = golden.check_scene(load_scene("basic_triangle"), directory=tmp_path)
    assert not res.ok and res.mismatches["persp"] == 1 and res.mismatches["screen"] == 0


def test_check_reports_missing_and_stale_goldens(tmp_path):
    res = golden.check_scene(load_scene("basic_triangle"), directory=tmp_path)
    assert not res.ok and "no golden file" in res.message
    shutil.copy(golden.golden_path("torus"), tmp_path / "basic_triangle.exr")
    res = golden.check_scene(load_scene("basic_triangle"), directory=tmp_path)
    assert not res.ok and "hash" in res.message


def test_update_writes_requested_scenes_only(tmp_path):
    paths = golden.update(["tiny_viewport", "basic_triangle"], directory=tmp_path)
    assert sorted(p.name for p in paths) == ["basic_triangle.exr", "tiny_viewport.exr"]
    assert all(r.ok for r in golden.check(["tiny_viewport", "basic_triangle"], directory=tmp_path))
    # Up-to-date goldens are not rewritten unless forced.
    assert golden.update(["tiny_viewport"], directory=tmp_path) == []
    assert len(golden.update(["tiny_viewport"], directory=tmp_path, force=True)) == 1


def test_golden_cli_exit_codes(tmp_path, capsys):
    import argparse

    from glraster.cli.commands import golden as cmd

    parser = argparse.ArgumentParser()
    cmd.register(parser.add_subparsers())
    args = parser.parse_args(["golden", "check", "basic_*", "--dir", str(golden.golden_dir())])
    assert args.func(args) == 0
    # a golden missing beside one that is there is a failure (exit 1)
    shutil.copy(golden.golden_path("tiny_viewport"), tmp_path / "tiny_viewport.exr")
    args = parser.parse_args(["golden", "check", "basic_triangle", "tiny_viewport",
                              "--dir", str(tmp_path)])
    assert args.func(args) == 1
    (tmp_path / "tiny_viewport.exr").unlink()
    # bad names are a usage error through the CLI's main (exit 2), nothing written
    from glraster.cli import main

    assert main(["golden", "update", "no_such_*", "--dir", str(tmp_path)]) == 2
    assert "no scene matches" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_golden_check_of_a_missing_folder_is_a_usage_error(tmp_path, capsys, monkeypatch):
    """A folder that is not there, or holds none of the goldens asked for, is named once
    (exit 2), not reported as 39 missing goldens; with no --dir the message names
    $GLRASTER_GOLDEN_DIR when that chose it."""
    from glraster.cli import main

    assert main(["golden", "check", "--dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path} holds none of the {len(list_scenes())} golden EXR(s) asked for" in err
    missing = tmp_path / "nowhere"
    assert main(["golden", "check", "--dir", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "--dir" in err and f"no golden folder at {missing}" in err
    monkeypatch.setenv("GLRASTER_GOLDEN_DIR", str(missing))
    assert main(["golden", "check", "basic_triangle"]) == 2
    assert "GLRASTER_GOLDEN_DIR" in capsys.readouterr().err
    assert not missing.exists()
