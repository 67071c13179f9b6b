"""End to end: images through rasterize -> interpolate, fitted by gradient descent on the
float32 (OpenGL) path, as a user of the torch layer would."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from tests.torch import scenes

TRI = torch.tensor(scenes.TRI)


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


def _render(glctx, pos, colors):
    rast, _ = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
    return dr.interpolate(colors, rast, TRI, glctx=glctx)[0]


def test_fitting_vertex_colours_drives_the_loss_down(glctx):
    pos = torch.tensor(scenes.POS, dtype=torch.float32)
    target = _render(glctx, pos, torch.tensor(scenes.COLORS, dtype=torch.float32)).detach()
    colors = torch.full((7, 3), 0.5, dtype=torch.float32, requires_grad=True)
    opt = torch.optim.Adam([colors], lr=0.05)
    losses = []
    for _ in range(150):
        opt.zero_grad()
        loss = ((_render(glctx, pos, colors) - target) ** 2).mean()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    # every vertex is seen by some pixel, so the colours are identifiable: the loss falls by
    # orders of magnitude (1e-3 of the start is loose; Adam at lr 0.05 reaches ~1e-6 here)
    assert losses[-1] < 1e-3 * losses[0], losses[::15]
    # Adam's momentum may overshoot later on, not in the first steps
    assert np.all(np.diff(losses[:5]) < 0), "the first steps must each lower the loss"


def test_a_gradient_step_on_positions_lowers_the_loss(glctx):
    # Frozen coverage: the interior colours still move with the vertices. A small step
    # against the gradient (1e-3 clip units: << the 0.04 px edge margin) lowers the loss.
    colors = torch.tensor(scenes.COLORS, dtype=torch.float32)
    target = _render(glctx, torch.tensor(scenes.POS, dtype=torch.float32), colors).detach()
    start = scenes.POS.copy()
    start[:, :2] += 0.004 * np.random.default_rng(1).standard_normal((7, 2))
    pos = torch.tensor(start, dtype=torch.float32, requires_grad=True)
    loss = ((_render(glctx, pos, colors) - target) ** 2).sum()
    loss.backward()
    step = 1e-3 * pos.grad / pos.grad.abs().max()
    with torch.no_grad():
        after = ((_render(glctx, pos - step, colors) - target) ** 2).sum()
    assert after < loss.item()
