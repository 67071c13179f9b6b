"""The one interface every differentiable op implements, and that the front ends bridge.

An op (:class:`Op`) names its differentiable array inputs and its outputs, and has two
*cores* with one signature, chosen by the inputs' dtype:

- float32 -> the GPU core (OpenGL shaders), float64 -> the float64 reference core.
- ``core.forward(*inputs, **params) -> (outputs, saved)``
    * ``inputs``: the differentiable arrays in :attr:`Op.inputs` order, each an
      ``np.ndarray`` of the op's float dtype, or None where the input is optional and
      absent. An op whose last input is variadic (texture's mip levels) takes the rest of
      the positional arguments as that list.
    * ``params``: everything else (``tri``, ``resolution``, modes, ``ctx``, ...),
      keyword-only. The reference core accepts ``ctx`` and ignores it.
    * ``outputs``: a tuple of arrays in :attr:`Op.outputs` order.
    * ``saved``: the op's typed ``Saved`` record, the same class from both cores.
- ``core.backward(saved, *grads, needs=None) -> grads of the inputs``
    * ``grads``: one per output, in order; None means zero.
    * ``needs``: None (all) or one bool per input: the inputs whose gradient is wanted.
      The result has one entry per input (the variadic tail flattened): an array of that
      input's shape and dtype, or None where the input is absent, not wanted, or has no
      gradient.

Inputs are validated once, at the boundary: :meth:`Op.check` turns user input into the
checked arrays and parameters (a :class:`glraster.errors.ArgumentError` naming the argument
otherwise), and the cores trust what they are given. :meth:`Op.output_shapes` gives the
outputs' shapes from the checked inputs without running anything, which a tracing front end
(``glraster.jax``) needs before the call.

:data:`OPS` lists the ops by name (:mod:`glraster.diff.ops` defines them).
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from glraster.errors import ArgumentError


class Core(Protocol):
    """What a GPU core and a reference core both provide (module or object)."""

    def forward(self, *inputs, **params) -> tuple[tuple[np.ndarray, ...], Any]: ...

    def backward(self, saved, *grads, needs: tuple[bool, ...] | None = None) -> tuple: ...


@dataclass(frozen=True, eq=False)
class Op:
    """A differentiable op (equal only to itself: the records are module constants, and
    front ends key their per-op caches by them, so the hash is the identity's).

    name          : the public name ("rasterize", "interpolate", "texture", "antialias")
    inputs        : names of the differentiable array inputs, in order (a trailing "*mip"
                    is variadic)
    outputs       : names of the outputs, in order
    check         : ``check(*inputs, **params) -> (inputs, params)``, the validated
                    NumPy arrays (one float dtype) and parameters
    output_shapes : ``output_shapes(*inputs, **params) -> tuple of shapes`` for checked
                    inputs (dtype: the inputs')
    gpu, reference: import paths of the two cores ("module" or "module:attribute")
    """

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    check: Callable
    output_shapes: Callable
    gpu: str
    reference: str

    def core(self, dtype) -> Core:
        """The core for inputs of ``dtype``: float64 -> reference, float32 -> GPU."""
        dtype = np.dtype(dtype)
        if dtype == np.float32:
            return _load(self.gpu)
        if dtype == np.float64:
            return _load(self.reference)
        raise ArgumentError(self.inputs[0], f"{self.name} runs on float32 (GPU) or "
                                            f"float64 (reference) inputs, got {dtype}")

    def forward(self, *inputs, **params):
        """Check, then run the core the dtype selects: ``(outputs, saved)``."""
        inputs, params = self.check(*inputs, **params)
        return self.core(dtype_of(inputs)).forward(*inputs, **params)


def dtype_of(inputs) -> np.dtype:
    """The float dtype of checked inputs (the first array among them)."""
    for value in inputs:
        if isinstance(value, np.ndarray):
            return value.dtype
    raise ValueError("an op needs at least one array input")


@functools.cache  # (every call of a core looks it up)
def _load(path: str):
    module, _, attribute = path.partition(":")
    loaded = importlib.import_module(module)
    return getattr(loaded, attribute) if attribute else loaded
