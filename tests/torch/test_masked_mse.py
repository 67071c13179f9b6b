"""glraster.torch.fitting.texture.masked_mse: the value and gradients of autograd's
``torch.sum(m * (image - target) ** 2) / (torch.sum(m) * C)`` bit for bit (signed zeros
included), its backward fused."""

from __future__ import annotations

import pytest
import torch

from glraster.torch.fitting.texture import masked_mse


def _autograds(image, target, mask):
    m = mask[..., None].to(image.dtype)
    return torch.sum(m * (image - target) ** 2) / (torch.sum(m) * image.shape[-1])


def _bits(t):
    return t.view(torch.int32 if t.dtype == torch.float32 else torch.int64)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("shape", [(4, 32, 32, 3), (1, 7, 9, 1), (3, 5, 6, 4)])
@pytest.mark.parametrize("upstream", [1.0, -2.5, 3e-3])
def test_masked_mse_is_autograds_bit_for_bit(shape, dtype, upstream):
    gen = torch.Generator().manual_seed(sum(shape))
    image = torch.rand(shape, generator=gen, dtype=dtype)
    image[0, 0, :2] = 0.25                       # some differences exactly 0
    target = (torch.rand(shape, generator=gen, dtype=dtype) * 1.5 - 0.25)
    target[0, 0, :2] = 0.25
    mask = torch.rand(shape[:3], generator=gen) > 0.4
    mask[0, 0, 0] = False
    for wants in ((True, False), (True, True), (False, True)):
        a = image.clone().requires_grad_(wants[0])
        b = target.clone().requires_grad_(wants[1])
        want = _autograds(a, b, mask)
        got = masked_mse(a, b, mask)
        assert torch.equal(_bits(got), _bits(want))
        leaves = [t for t in (a, b) if t.requires_grad]
        want_grads = torch.autograd.grad(want * upstream, leaves)
        got_grads = torch.autograd.grad(got * upstream, leaves)
        for g, w in zip(got_grads, want_grads):
            assert torch.equal(_bits(g), _bits(w))   # (bits: -0.0 is not 0.0)
        assert any((g == 0).any() and torch.signbit(g[g == 0]).any() for g in got_grads)


def test_masked_mse_twice_and_without_gradients():
    gen = torch.Generator().manual_seed(5)
    image, target = torch.rand(2, 8, 8, 3, generator=gen), torch.rand(2, 8, 8, 3, generator=gen)
    mask = torch.rand(2, 8, 8, generator=gen) > 0.5
    with torch.no_grad():
        assert torch.equal(masked_mse(image, target, mask), _autograds(image, target, mask))
    leaf = image.clone().requires_grad_()
    first = masked_mse(leaf, target, mask)            # (the squares' buffer is reused:
    second = masked_mse(leaf, target * 0.5, mask)     # the first loss and its backward
    (g1,) = torch.autograd.grad(first, (leaf,))       # keep their own values)
    assert torch.equal(first, _autograds(image, target, mask))
    assert torch.equal(g1, torch.autograd.grad(_autograds(leaf, target, mask), (leaf,))[0])
    assert torch.equal(second, _autograds(image, target * 0.5, mask))
