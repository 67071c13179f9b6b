"""glraster.studies.bench: scenes, a tiny case grid, the JSON-able result and the plot. No timing
is judged here (timings are benchmark figures, docs/performance.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from glraster.studies import bench


@pytest.mark.parametrize("name", ["terrain", "shards"])
def test_scenes_have_the_requested_size_and_are_in_view(name):
    scene = bench.make_bench_scene(name, 2000)
    assert abs(len(scene.faces) - 2000) <= 0.1 * 2000
    assert scene.pos.dtype == np.float32 and scene.pos.shape == (len(scene.vertices), 4)
    ndc = scene.pos[:, :3] / scene.pos[:, 3:4]
    assert (scene.pos[:, 3] > 0).all() and (np.abs(ndc[:, :2]) < 1).mean() > 0.5
    assert len(bench.make_bench_scene(name, 1).faces) == 1


def test_a_tiny_run_reports_every_field(tmp_path, gl_backend):
    steps = []
    result = bench.run("quick", backend=gl_backend, methods=("hw", "homogeneous"),
                       resolutions=(48,), counts=(1, 50), repeats=2, with_pyrender=False,
                       summaries=False,
                       progress=lambda i, n, label: steps.append((i, n)))
    assert steps[-1][0] == steps[-1][1] == 6
    assert len(result["cases"]) == 4
    for case in result["cases"]:
        assert case["warm_ms"] > 0 and case["first_ms"] > 0 and case["fill_ratio"] > 0
        assert case["error"]["coverage_mismatch"] == 0
        assert case["error"]["persp"]["worst_ratio"] <= 1
    json.dumps(result, default=float)
    bench.pareto_plot(result, str(tmp_path / "pareto.png"))
    assert (tmp_path / "pareto.png").stat().st_size > 1000


def test_unknown_names_are_rejected():
    with pytest.raises(ValueError, match="scene must be"):
        bench.make_bench_scene("teapot", 10)
    with pytest.raises(ValueError, match="preset must be"):
        bench.run("huge")
    with pytest.raises(ValueError, match="methods has unknown"):
        bench.run("quick", methods=("exact",))
