"""What a batch worker renders for one scene (glraster.cluster.dataset.render_scene), on a
context of this process: no Ray cluster needed."""

from __future__ import annotations

import json

import numpy as np

import glraster as gr
from glraster.cluster import dataset, shards
from glraster.conformance.scenes import load_scene


def test_a_multisampled_scene_keeps_its_samples_mask_and_positions(ctx, tmp_path):
    """The scene's samples and interpolation, the per-sample arrays bit for bit as
    rasterize returns them, and the shard's manifest keys naming mask and positions."""
    scene = load_scene("ms_fan_offcenter")
    arrays = dataset.render_scene(ctx, scene, ("persp", "tri_id"))
    want = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx,
                        outputs=("persp", "tri_id"), samples=4, interpolation="sample")
    assert sorted(arrays) == ["mask", "persp", "sample_positions", "tri_id"]
    for key, value in arrays.items():
        np.testing.assert_array_equal(value, getattr(want, key), err_msg=key)
    assert arrays["persp"].shape == (64, 64, 4, 3)
    [line] = shards.write_shard(tmp_path, shards.Shard(0, ("fan.json",)), [arrays])
    with np.load(tmp_path / line["shard"]) as shard:
        assert json.loads(str(shard["manifest"]))[0]["keys"] == line["keys"]
        np.testing.assert_array_equal(shard[line["keys"]["mask"]], want.mask)


def test_a_single_sample_scene_is_its_outputs_alone(ctx):
    scene = load_scene("basic_triangle")
    assert sorted(dataset.render_scene(ctx, scene, None)) == sorted(scene.outputs)
