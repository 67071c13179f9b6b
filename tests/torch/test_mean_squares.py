"""glraster.torch.fitting.common.mean_squares: the values and gradients of
``torch.mean((image - target) ** 2, dim=(1, ...))`` bit for bit, its backward fused."""

from __future__ import annotations

import pytest
import torch

from glraster.torch.fitting.common import mean_squares


@pytest.mark.parametrize("shape, target_shape", [((8, 32, 32, 3), (1, 32, 32, 3)),
                                                 ((3, 17, 5, 4), (3, 17, 5, 4)),
                                                 ((1, 7, 9, 1), (1, 7, 9, 1)),
                                                 ((5, 11), (1, 11))])
def test_mean_squares_is_autograds_mean_of_squares_bit_for_bit(shape, target_shape):
    gen = torch.Generator().manual_seed(sum(shape))
    image = torch.rand(shape, generator=gen).requires_grad_()
    target = (torch.rand(target_shape, generator=gen) * 1.5 - 0.25).requires_grad_()
    weights = torch.rand(shape[0], generator=gen) * 3 - 1     # (an upstream gradient)
    dims = tuple(range(1, len(shape)))
    want = torch.mean((image - target) ** 2, dim=dims)
    got = mean_squares(image, target)
    assert torch.equal(got, want)
    want_grads = torch.autograd.grad((want * weights).sum(), (image, target))
    got_grads = torch.autograd.grad((got * weights).sum(), (image, target))
    assert torch.equal(got_grads[0], want_grads[0])
    torch.testing.assert_close(got_grads[1], want_grads[1])   # (a sum: order may differ)


def test_mean_squares_without_gradients_wanted():
    image, target = torch.rand(2, 4, 4, 3), torch.rand(1, 4, 4, 3)
    with torch.no_grad():
        assert torch.equal(mean_squares(image, target),
                           torch.mean((image - target) ** 2, dim=(1, 2, 3)))
    leaf = image.clone().requires_grad_()
    (grad,) = torch.autograd.grad(mean_squares(leaf, target).sum(), (leaf,))
    assert torch.equal(grad, torch.autograd.grad(
        torch.mean((leaf - target) ** 2, dim=(1, 2, 3)).sum(), (leaf,))[0])
