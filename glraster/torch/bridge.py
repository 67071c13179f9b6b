"""The one autograd bridge: any :class:`glraster.diff.op.Op` as a torch function.

:class:`Call` checks the tensors (CPU, strided, float32 or float64 of one dtype; integer
``tri``, ``ranges``), hands NumPy views of them to ``op.check`` (the one validation) and
runs the core the dtype selects (float32: OpenGL, its context current for the whole core
call; float64: the float64 reference) in one autograd Function, whose backward runs
``core.backward(saved, *grads, needs=...)`` (None grads: zero; ``needs``: the inputs that
require grad). Inputs, ``tri``, ``ranges`` and outputs are saved for backward, so that an
in-place change of one after the forward makes the backward raise (the cores keep views of
them); a call that can have no gradient (no grad mode, no input requiring one) runs without
the Function, and one repeating such a call bit for bit not at all (:mod:`glraster.diff.memo`).
No double backward. Tensors are known by :func:`upload_entry`: an unchanged one is not
uploaded again (:mod:`glraster.gpu.uploads`), nor rast decoded again (:mod:`glraster.diff.checked`).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import weakref

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster.diff import checked, memo
from glraster.diff.op import dtype_of
from glraster.diff.ops import RASTERIZE
from glraster.errors import ArgumentError
from glraster.torch.context import RasterizeGLContext

FLOATS, INTS = (torch.float32, torch.float64), (torch.int32, torch.int64)
INTEGER_PARAMS = ("tri", "ranges")  # checked, known and saved like the inputs
KEYED_BYTES = 1024  # smaller tensors are not keyed: a key costs more than their upload


# The public ops' decorator: under torch.compile, TorchDynamo runs them as written (a graph
# break), as their NumPy views of tensors cannot be of its fake ones (test_compile.py).
eager = torch.compiler.disable


def tensor(name: str, value, dtypes=FLOATS) -> np.ndarray:
    """A NumPy view of ``value``, once it is a dense CPU tensor of one of ``dtypes``."""
    if not isinstance(value, torch.Tensor):
        problem = f"be a torch.Tensor, got {type(value).__name__}"
    elif not value.is_cpu:
        problem = (f"be on the CPU (glraster.torch reads tensors back to host memory), got "
                   f"device {value.device}")
    elif value.layout != torch.strided:
        problem = f"be a dense (strided) tensor, got layout {value.layout}"
    elif value.dtype not in dtypes:
        problem = f"have dtype {' or '.join(map(str, dtypes))}, got {value.dtype}"
    else:  # (detach only what autograd tracks: a tensor of no grad is its own view)
        return (value.detach() if value.requires_grad else value).numpy()
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


def to_torch(array, dtype, gl=None) -> torch.Tensor:
    """A tensor sharing ``array``'s memory when it is contiguous, writable and of ``dtype``;
    ``gl``'s upload cache adopts it if a buffer holds its bytes (owner: the array's life)."""
    tensor = torch.from_numpy(array := np.require(array, dtype, "CW"))
    if gl is not None:  # (autograd keeps a saved output's memory, not its Python object)
        gl.uploads.adopt(upload_entry(tensor, array))
    return tensor


def upload_entry(value: torch.Tensor, owner=None):
    """``(region, key, owner)`` of a contiguous tensor of KEYED_BYTES or more (else None) for
    :mod:`glraster.gpu.uploads`: the key names the tensor (a view's base: the owner, held
    weakly, or ``owner``), address, version (bumped in place, shared by views), shape, dtype."""
    if value is None or value.nbytes < KEYED_BYTES or not value.is_contiguous() \
            or value.is_inference():   # (inference tensors have no version counter)
        return None
    base = value._base if value._base is not None else value
    address = value.data_ptr()
    return ((address, value.nbytes), (id(base), address, value._version, value.shape,
            value.dtype), weakref.ref(base if owner is None else owner))


class Call:
    """One checked call of ``op`` on ``inputs`` (tensors or None in ``op.inputs`` order, a
    variadic tail flattened) with keyword ``params``; an ArgumentError naming the argument
    before anything runs. ``arrays``, ``params``: the checked values; float32 calls get
    ``ctx`` = ``glctx``'s OpenGL context (glraster's default when None), made only once the
    input is known good. ``frozen``: indices of outputs whose gradient is dropped.
    ``tri``, ``ranges``: None or integer tensors (:func:`integers`), checked first, ``kept``."""

    def __init__(self, op, inputs, glctx=None, frozen=(), **params):
        glctx = None if glctx is None else context(glctx)
        kept = []
        for name in INTEGER_PARAMS:
            value = params.get(name)
            if value is not None and not isinstance(value, np.ndarray):  # (arrays: checked)
                params[name] = integers(name, value)
                kept.append(value)
        names, optional = _signature(op, len(inputs))
        dtype = getattr(inputs[0], "dtype", None)  # the first input is never optional
        self.views = views = [None if value is None and name in optional else
                              tensor(name, value) for name, value in zip(names, inputs)]
        for name, value in zip(names, inputs):
            if value is not None and value.dtype != dtype:
                raise ArgumentError(name, f"{name} must have the dtype of {names[0]} "
                                          f"({dtype}), got {value.dtype}: "
                                          "float32 runs on the GPU, float64 through the "
                                          "float64 reference, and one op does not mix them")
        self.op, self.inputs, self.frozen, self.kept = op, tuple(inputs), tuple(frozen), kept
        self.entries = [*map(upload_entry, (*inputs, *kept))]  # (for the check, the forward)
        with checked.declared(self.entries):
            self.arrays, self.params = op.check(*views, **params, ctx=None)
        self.dtype = dtype_of(self.arrays)
        if self.dtype == np.float32:  # (glraster.gpu imported here: float64 needs no OpenGL)
            self.params["ctx"] = glctx.context if glctx is not None else \
                importlib.import_module("glraster.gpu.context").default_context()

    def __call__(self, forward=None) -> tuple[torch.Tensor, ...]:
        """The outputs; ``forward()`` gives ``(outputs, saved)`` (default: the core's)."""
        core, held = self.op.core(self.dtype), (*self.inputs, *self.kept)
        entries = self.entries if forward is None else [*map(upload_entry, held)]  # (layers)
        gl = self.params["ctx"] if self.dtype == np.float32 else None
        repeatable = gl is not None and forward is None and not torch.is_inference_mode_enabled() \
            and not any(t is not None and t.is_inference() for t in held)  # (nor peelers')
        forward = forward or functools.partial(core.forward, *self.arrays, **self.params)
        how = (core, self.dtype, self.frozen, gl, len(self.inputs), entries)
        if torch.is_grad_enabled() and any(t is not None and t.requires_grad for t in self.inputs):
            outputs = _Function.apply(how, forward, *held)
        elif repeatable and (found := memo.lookup(gl, self.op, self.params, self.views)):
            outputs = tuple(map(torch.from_numpy, found))
        else:  # no gradient possible: no autograd node, nothing saved
            outputs = tuple(to_torch(out, self.dtype, gl) for out in _run(gl, entries, forward)[0])
            if repeatable:
                memo.remember(gl, self.op, self.params, self.views, [t.numpy() for t in outputs],
                              lambda ts=held + outputs: [t._version for t in ts if t is not None])
        if self.op is RASTERIZE:  # its rast: ids of tri, not decoded again while unchanged
            checked.made(upload_entry(outputs[0]), len(self.params["tri"]))
        return outputs


@functools.cache
def _signature(op, count: int):  # the inputs' names (a variadic tail numbered), the optional
    names = [n for n in op.inputs if not n.startswith("*")]
    names += [f"{op.inputs[-1][1:]}[{k}]" for k in range(count - len(names))]
    return tuple(names), frozenset(p.name for p in inspect.signature(op.check).parameters
                                   .values() if p.default is None)


def _run(gl, entries, work):
    """``work()``, for float32 with ``gl`` current for the whole core call (its own ``with
    ctx:`` blocks then switch nothing) and ``entries`` declared to its upload cache."""
    if gl is None:
        return work()
    with gl:
        added = gl.uploads.declare(entries)
        try:
            return work()
        finally:
            gl.uploads.undeclare(added)


class _Function(torch.autograd.Function):
    @staticmethod
    def forward(fctx, how, forward, *tensors):
        fctx.core, fctx.dtype, fctx.frozen, fctx.gl, fctx.count, entries = how
        outputs, fctx.saved = _run(fctx.gl, entries, forward)
        outputs = tuple(to_torch(out, fctx.dtype, fctx.gl) for out in outputs)
        fctx.save_for_backward(*tensors, *outputs)
        fctx.entries = entries + [upload_entry(t) for t in outputs]  # valid while saved
        fctx.shapes = [None if t is None else t.shape for t in tensors[:fctx.count]]
        fctx.set_materialize_grads(False)
        return outputs

    @staticmethod
    @once_differentiable
    def backward(fctx, *grads):
        nothing = (None,) * len(fctx.needs_input_grad)
        needs = tuple(fctx.needs_input_grad[2:2 + fctx.count])
        if not any(needs) or all(g is None for g in grads):
            return nothing
        fctx.saved_tensors  # raises if a saved tensor changed in place since (keys stay)
        arrays = [None if g is None or k in fctx.frozen else np.ascontiguousarray(g.numpy())
                  for k, g in enumerate(grads)]
        work = functools.partial(fctx.core.backward, fctx.saved, *arrays, needs=needs)
        result = tuple(_run(fctx.gl, fctx.entries + [*map(upload_entry, grads)], work))
        result += (None,) * (len(needs) - len(result))  # own mips: no gradients of their own
        grads = tuple(to_torch(g, fctx.dtype, fctx.gl).sum_to_size(shape) if need and g is not
                      None else None for g, shape, need in zip(result, fctx.shapes, needs))
        return (None, None) + grads + nothing[2 + len(grads):]
