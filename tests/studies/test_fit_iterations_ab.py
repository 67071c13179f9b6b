"""The fit-iterations-ab study (glraster/studies/fit_iterations_ab.py) at tiny sizes
(docs/performance.md quotes its long form). Timings are never checked: the tests check
that the envmap workload is the envmap fit's shading, that a worker runs the tree it was
given, and that a commit's temporary worktree comes and goes."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from glraster.studies import fit_iterations_ab as ab

REPO = Path(__file__).resolve().parents[2]
TINY = ["--rounds", "1", "--iterations", "4", "--size", "16", "--envmap-resolution", "16",
        "--envmap-mesh", "8", "6", "--envmap-env-size", "8"]


def test_the_study_runs_its_short_form(gl_backend, capsys, monkeypatch, tmp_path):
    script = REPO / "glraster" / "studies" / "fit_iterations_ab.py"
    out = tmp_path / "rows.json"
    monkeypatch.setenv("GLRASTER_BACKEND", gl_backend)     # the workers' backend
    monkeypatch.setattr(sys, "argv", [str(script), "--before", str(REPO), *TINY,
                                      "--json", str(out)])
    namespace = runpy.run_path(str(script))
    assert namespace["main"]() == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert [row.split(" | ")[0] for row in rows[1:]] == [
        "| cube 4x4", "| cube 16x16", "| pose 16²", "| texture mip=None, constant tex 16²",
        "| envmap 16²"]
    assert out.exists()


def test_the_envmap_workload_is_the_fits_shading(ctx, tmp_path):
    import glraster.torch as dr
    from glraster.torch.fitting import envmap

    glctx = dr.RasterizeGLContext(context=ctx)
    scene = envmap.make_scene(glctx, mesh=(10, 8), env_size=8)
    path = tmp_path / "scene.npz"
    ab.write_envmap_scene(path, mesh=(10, 8), env_size=8, pool=2)
    with np.load(path) as data:
        arrays = {k: torch.from_numpy(np.array(v)) for k, v in data.items()}
    for name in ("verts", "tri", "normals", "env"):
        assert torch.equal(arrays[name], getattr(scene, name)), name
    mvp, eye = arrays["mvp"][1], arrays["eye"][1]
    material = arrays["kd0"], arrays["ks0"], arrays["p0"]
    mine, covered = ab.envmap_render(dr, glctx, arrays, mvp, eye, *material, 24)
    fits, fits_covered = envmap.render_envmap(glctx, scene, mvp, eye, *material, 24,
                                              env=scene.env)
    assert covered.any() and torch.equal(covered, fits_covered)
    assert torch.equal(mine, fits)


def test_the_envmap_iteration_moves_the_material(ctx, tmp_path, monkeypatch):
    import glraster.torch as dr

    path = tmp_path / "scene.npz"
    ab.write_envmap_scene(path, mesh=(10, 8), env_size=8, pool=2)
    seen = []
    monkeypatch.setattr(torch.optim.Adam, "step", lambda self, *a, **k: seen.append(
        [p.grad.clone() for g in self.param_groups for p in g["params"]]))
    ab.envmap_iteration(dr, dr.RasterizeGLContext(context=ctx), path, 16)(2)
    assert len(seen) == 2 and all(torch.isfinite(g).all() and g.abs().sum() > 0
                                  for grads in seen for g in grads)


def test_a_worker_refuses_a_tree_it_does_not_import(tmp_path):
    # tmp_path holds no glraster: the worker imports another one (or none) and is refused
    with pytest.raises(RuntimeError, match="worker"):
        ab._start(tmp_path.resolve(), 4, 4, ["texture"], None)


def test_a_worker_keeps_the_callers_pythonpath_after_its_tree(tmp_path, monkeypatch):
    # packages found through PYTHONPATH (a --target install) stay importable in the worker
    from glraster.studies.revision import tree_environment

    monkeypatch.setenv("PYTHONPATH", "/opt/site-a" + ":" + "/opt/site-b")
    assert tree_environment(tmp_path)["PYTHONPATH"].split(":") == [
        str(tmp_path), "/opt/site-a", "/opt/site-b"]
    monkeypatch.delenv("PYTHONPATH")
    assert tree_environment(tmp_path)["PYTHONPATH"] == str(tmp_path)


def test_before_commit_is_a_temporary_worktree(tmp_path):
    repo = tmp_path / "repo"
    git = lambda *a: subprocess.run(["git", "-C", str(repo), *a], check=True,  # noqa: E731
                                    capture_output=True, text=True).stdout.strip()
    repo.mkdir()
    git("init", "--quiet")
    (repo / "marker.txt").write_text("old\n")
    git("add", "marker.txt")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "--quiet", "-m", "old")
    commit = git("rev-parse", "HEAD")
    (repo / "marker.txt").write_text("new\n")
    with ab.BeforeTree(commit=commit, repo=repo) as tree:
        assert (tree / "marker.txt").read_text() == "old\n"
        assert str(tree) in git("worktree", "list")
    assert not tree.exists() and str(tree) not in git("worktree", "list")


def test_options_are_checked(capsys):
    with pytest.raises(SystemExit):
        ab.main(["--rounds", "1"])
    assert "--before-commit" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ab.main(["--before", str(REPO), "--rounds", "0"])
    assert "--rounds must be at least 1" in capsys.readouterr().err
