"""The third tier for antialias (DESIGN.md, "Differentiable ops"): whole images.

rasterize -> interpolate -> antialias on the GPU, L = sum of the image weighted by smooth
per-channel ramps. Directional finite differences of L, re-rendering at every step (coverage
NOT frozen: pixels change triangle), with vertex steps of 0.1 to 0.5 window pixels, against
the analytic gradient (antialias's position gradient plus the rasterize and interpolate
chain) along the same direction. Antialias is an approximation of box-filtered coverage,
so the two agree statistically, not to rounding: in sign always, and in magnitude within
the relative errors asserted (and printed) below.
"""

from __future__ import annotations

import numpy as np

from glraster.diff import antialias as gaa
from glraster.diff import interpolate as ginterp
from glraster.diff import rasterize as grast
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from tests.diff.test_antialias_reference import (
    antialias_backward,
    antialias_forward,
    mesh_scene,
    soup_scene,
)

RES = (96, 128)
STEPS_PX = (0.1, 0.25, 0.5)


class Pipeline:
    def __init__(self, ctx, pos, tri, colors, resolution=RES):
        self.ctx, self.tri, self.colors, self.resolution = ctx, tri, colors.astype(np.float32), \
            resolution
        self.th = gaa.antialias_construct_topology_hash(tri)
        height, width = resolution
        yy, xx = np.mgrid[0:height, 0:width]
        self.weights = np.stack([np.ones((height, width)), xx / width, 1 - yy / height],
                                -1)[None].astype(np.float32)
        self.pos = pos.astype(np.float32)

    def render(self, pos):
        pos = np.asarray(pos, np.float32)
        (rast, _), rsaved = RASTERIZE.forward(pos, tri=self.tri, resolution=self.resolution,
                                              ctx=self.ctx)
        (col, _), isaved = INTERPOLATE.forward(self.colors, rast, tri=self.tri, ctx=self.ctx)
        out, asaved = antialias_forward(col, rast, pos, self.tri, self.th, dtype=np.float32,
                                        ctx=self.ctx)
        return rsaved, out, isaved, asaved

    def loss(self, pos) -> float:
        return float((self.render(pos)[1].astype(np.float64) * self.weights).sum())

    def gradient(self) -> np.ndarray:
        rsaved, _, isaved, asaved = self.render(self.pos)
        g_col, g_pos_aa = antialias_backward(asaved, self.weights, deterministic=True)
        _, g_rast, _ = ginterp.backward(isaved, g_col, deterministic=True)
        (g_pos,) = grast.backward(rsaved, g_rast, deterministic=True)
        return g_pos_aa.astype(np.float64) + g_pos, g_pos_aa.astype(np.float64)


def directions(pos, resolution, seed=0):
    """Clip-space directions moving vertices by 1 window pixel: translations in x and y,
    a scale about the image centre (1 px at 40 px from it), and an independent random
    direction per vertex."""
    height, width = resolution
    w = pos[:, 3].astype(np.float64)
    out = {}
    d = np.zeros(pos.shape)
    d[:, 0] = 2 * w / width
    out["translate x"] = d
    d = np.zeros(pos.shape)
    d[:, 1] = 2 * w / height
    out["translate y"] = d
    d = np.zeros(pos.shape)
    d[:, :2] = pos[:, :2] / 40.0
    out["scale"] = d
    r = np.random.default_rng(seed).normal(size=(len(pos), 2))
    d = np.zeros(pos.shape)
    d[:, 0] = r[:, 0] * 2 * w / width
    d[:, 1] = r[:, 1] * 2 * w / height
    out["random"] = d
    return out


def scenes():
    m = mesh_scene(RES, level=2)
    c = mesh_scene(RES, level=3, eye=(2.0, 1.6, 1.3), fov=35.0, seed=4)
    s = soup_scene(RES, count=24, seed=9, layered=True)
    return {"icosphere": m, "close_sphere": c, "layered_soup": s}


def figures(ctx):
    rows = []
    for name, (pos, tri, colors) in scenes().items():
        pipe = Pipeline(ctx, pos, tri, colors)
        grad, grad_aa = pipe.gradient()
        for dname, d in directions(pipe.pos, RES).items():
            analytic = float((grad * d).sum())
            visibility = float((grad_aa * d).sum())
            for h in STEPS_PX:
                fd = (pipe.loss(pipe.pos + h * d) - pipe.loss(pipe.pos - h * d)) / (2 * h)
                rows.append((name, dname, h, fd, analytic, visibility,
                             abs(analytic - fd) / abs(fd)))
    return rows


def test_whole_image_directional_differences_agree_with_the_gradient(ctx):
    rows = figures(ctx)
    print()
    print(f"{'scene':13s} {'direction':12s} {'step px':>7s} {'finite diff':>12s} "
          f"{'analytic':>10s} {'(antialias)':>11s} {'rel err':>8s}")
    for name, dname, h, fd, an, vis, rel in rows:
        print(f"{name:13s} {dname:12s} {h:7.2f} {fd:12.3f} {an:10.3f} {vis:11.3f} {rel:8.3f}")
    rel = np.array([r[-1] for r in rows])
    print(f"relative error per step: median {np.median(rel):.3f}, p90 "
          f"{np.percentile(rel, 90):.3f}, max {rel.max():.3f} over {len(rel)}")
    # per scene and direction, the finite differences of the three steps averaged
    groups = {}
    for name, dname, h, fd, an, vis, _ in rows:
        groups.setdefault((name, dname), []).append((fd, an))
    mean_rel = {}
    for key, vals in groups.items():
        fd = np.mean([v[0] for v in vals])
        an = vals[0][1]
        mean_rel[key] = abs(an - fd) / abs(fd)
        print(f"{key[0]:13s} {key[1]:12s} mean over steps: finite diff {fd:9.3f}, analytic "
              f"{an:9.3f}, relative error {mean_rel[key]:.3f}")
    for name, dname, h, fd, an, vis, _ in rows:
        assert np.sign(fd) == np.sign(an), (name, dname, h, fd, an)
    # the silhouettes move one way under a scale: no cancellation between them
    assert max(v for k, v in mean_rel.items() if k[1] == "scale") < 0.12
    assert max(mean_rel.values()) < 0.6
    assert np.median(list(mean_rel.values())) < 0.3
    assert np.median(rel) < 0.35
