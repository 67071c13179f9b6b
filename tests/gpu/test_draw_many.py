"""pipeline.draw_many: items drawn into their own framebuffers before any read back give
bit for bit the pixels of one pipeline.draw per item."""

from __future__ import annotations

import numpy as np

from glraster.diff import rasterize as dr
from glraster.geometry import synthetic
from glraster.gpu import pipeline
from glraster.gpu.context import FRAMEBUFFER_SLOTS


def test_draw_many_equals_one_draw_per_item(ctx):
    pos, tri = synthetic.random_soup(40, seed=3)
    rng = np.random.default_rng(3)
    batch = FRAMEBUFFER_SLOTS  # the most one draw_many takes
    items = np.stack([pos + rng.normal(0, 0.2, pos.shape) * [1, 1, 0, 0]
                      for _ in range(batch)]).astype(np.float32)
    job = dr._Forward(items, tri.astype(np.int32), (9, 7), None, True, "persp", ctx)
    alone = [pipeline.draw(ctx, *job.spec(b), (9, 7))["drawn"] for b in range(batch)]
    outs = [{"drawn": np.empty((9, 7), np.int32)} for _ in range(batch)]
    draws = [(*job.spec(b), outs[b]) for b in range(batch)]
    values = pipeline.draw_many(ctx, draws, (9, 7))
    assert len(values) == batch and values[1]["drawn"] is outs[1]["drawn"]
    assert (alone[0] > 0).any()  # something is drawn
    assert not np.array_equal(alone[0], alone[1])  # and differs between items
    for b in range(batch):
        np.testing.assert_array_equal(values[b]["drawn"], alone[b])
