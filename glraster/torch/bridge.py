"""The one autograd bridge: any :class:`glraster.diff.op.Op` as a torch function.

:class:`Call` checks the tensors (CPU, strided, float32 or float64 of one dtype; integer
``tri``, ``ranges``), hands NumPy views of them to ``op.check`` (the one validation) and
runs the core the dtype selects (float32: OpenGL, its context current for the whole core
call; float64: the float64 reference) in one autograd Function, whose backward runs ``core.backward(saved, *grads, needs=...)`` (None
grads: zero; ``needs``: the inputs that require grad). Inputs and outputs are saved for
backward, so that an in-place change of one after the forward makes the backward raise
(the cores keep views of both). No double backward.
"""

from __future__ import annotations

import contextlib
import functools
import inspect

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster.diff.op import dtype_of
from glraster.errors import ArgumentError
from glraster.torch.context import RasterizeGLContext

FLOATS, INTS = (torch.float32, torch.float64), (torch.int32, torch.int64)


def tensor(name: str, value, dtypes=FLOATS) -> np.ndarray:
    """A NumPy view of ``value``, once it is a dense CPU tensor of one of ``dtypes``."""
    if not isinstance(value, torch.Tensor):
        problem = f"be a torch.Tensor, got {type(value).__name__}"
    elif value.device.type != "cpu":
        problem = (f"be on the CPU (glraster.torch reads tensors back to host memory), got "
                   f"device {value.device}")
    elif value.layout != torch.strided:
        problem = f"be a dense (strided) tensor, got layout {value.layout}"
    elif value.dtype not in dtypes:
        problem = f"have dtype {' or '.join(map(str, dtypes))}, got {value.dtype}"
    else:
        return value.detach().numpy()
    raise ArgumentError(name, f"{name} must {problem}")


def integers(name: str, value) -> np.ndarray | None:
    """``tri`` or ``ranges`` (None stays None) as a NumPy view of an int32/int64 tensor."""
    return None if value is None else tensor(name, value, INTS)


def flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ArgumentError(name, f"{name} must be True or False, got {value!r}")
    return bool(value)


def context(glctx) -> RasterizeGLContext:
    if not isinstance(glctx, RasterizeGLContext):
        raise ArgumentError("glctx", f"glctx must be a RasterizeGLContext (or "
                                     f"RasterizeCudaContext), got {type(glctx).__name__}")
    return glctx


def to_torch(array, dtype) -> torch.Tensor:
    """A tensor sharing ``array``'s memory when it is contiguous, writable and of ``dtype``."""
    array = np.asarray(array)
    if array.dtype != dtype or not array.flags.c_contiguous or not array.flags.writeable:
        array = np.array(array, dtype=dtype, order="C")
    return torch.from_numpy(array)


class Call:
    """One checked call of ``op`` on ``inputs`` (tensors or None in ``op.inputs`` order, a
    variadic tail flattened) with keyword ``params``; an ArgumentError naming the argument
    before anything runs. ``arrays``, ``params``: the checked values; float32 calls get
    ``ctx`` = ``glctx``'s OpenGL context (glraster's default when None), made only once the
    input is known good. ``frozen``: indices of outputs whose gradient is dropped."""

    def __init__(self, op, inputs, glctx=None, frozen=(), **params):
        glctx = None if glctx is None else context(glctx)
        names = [n for n in op.inputs if not n.startswith("*")]
        names += [f"{op.inputs[-1][1:]}[{k}]" for k in range(len(inputs) - len(names))]
        views = [None if t is None and n in _optional(op) else tensor(n, t)
                 for n, t in zip(names, inputs)]
        for name, value in zip(names, inputs):  # the first input is never optional
            if value is not None and value.dtype != inputs[0].dtype:
                raise ArgumentError(name, f"{name} must have the dtype of {names[0]} "
                                          f"({inputs[0].dtype}), got {value.dtype}: "
                                          "float32 runs on the GPU, float64 through the "
                                          "float64 reference, and one op does not mix them")
        self.op, self.inputs, self.frozen = op, tuple(inputs), tuple(frozen)
        self.arrays, self.params = op.check(*views, **params, ctx=None)
        self.dtype = dtype_of(self.arrays)
        if self.dtype == np.float32:  # (imported here: float64 needs no OpenGL)
            from glraster.gpu.context import default_context
            self.params["ctx"] = default_context() if glctx is None else glctx.context

    def __call__(self, forward=None) -> tuple[torch.Tensor, ...]:
        """The outputs; ``forward()`` gives ``(outputs, saved)`` (default: the core's)."""
        core = self.op.core(self.dtype)
        if forward is None:
            forward = lambda: core.forward(*self.arrays, **self.params)  # noqa: E731
        gl = self.params.get("ctx") if self.dtype == np.float32 else None
        return _Function.apply((core, self.dtype, self.frozen, gl), forward, *self.inputs)


def _current(gl):
    """``gl`` current for a whole core call (its own ``with ctx:`` blocks then nest, not a
    dozen context switches); nothing for float64."""
    return contextlib.nullcontext() if gl is None else gl


@functools.cache
def _optional(op) -> frozenset[str]:  # the inputs op.check lets be None
    return frozenset(p.name for p in inspect.signature(op.check).parameters.values()
                     if p.default is None)


class _Function(torch.autograd.Function):
    @staticmethod
    def forward(fctx, how, forward, *inputs):
        fctx.core, fctx.dtype, fctx.frozen, fctx.gl = how
        with _current(fctx.gl):
            outputs, fctx.saved = forward()
        outputs = tuple(to_torch(out, fctx.dtype) for out in outputs)
        fctx.save_for_backward(*inputs, *outputs)
        fctx.shapes = [None if t is None else t.shape for t in inputs]
        fctx.set_materialize_grads(False)
        return outputs

    @staticmethod
    @once_differentiable
    def backward(fctx, *grads):
        needs = tuple(fctx.needs_input_grad[2:])
        if not any(needs) or all(g is None for g in grads):
            return (None,) * (2 + len(needs))
        fctx.saved_tensors  # raises if an input or output changed in place since the forward
        grads = [None if g is None or k in fctx.frozen else np.ascontiguousarray(g.numpy())
                 for k, g in enumerate(grads)]
        with _current(fctx.gl):
            result = tuple(fctx.core.backward(fctx.saved, *grads, needs=needs))
        result += (None,) * (len(needs) - len(result))  # own mips: no gradients of their own
        return (None, None) + tuple(
            to_torch(g, fctx.dtype).sum_to_size(shape) if need and g is not None else None
            for g, shape, need in zip(result, fctx.shapes, needs))  # sum: broadcast inputs
