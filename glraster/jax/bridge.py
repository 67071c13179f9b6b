"""The one bridge from :class:`glraster.diff.op.Op` to JAX: ``jax.custom_vjp`` over
``jax.pure_callback``.

:func:`apply` runs an op on JAX arrays, differentiable with ``jax.grad`` / ``jax.vjp``,
inside ``jax.jit`` and under ``jax.vmap``:

- **Validation, once, at the boundary.** Concrete inputs (eager calls) go through
  :meth:`Op.check <glraster.diff.op.Op.check>` as they are; traced inputs (inside
  ``jit``/``vmap``/``grad``) have no values yet, so ``Op.check`` runs on zero arrays of
  their shapes and dtypes (every shape, dtype and parameter error is raised at trace time,
  an :class:`glraster.errors.ArgumentError`), and the values (finite, ids in range) are
  checked by ``Op.check`` inside the forward callback, where they exist. JAX reports an
  exception raised in a callback as a ``JaxRuntimeError`` whose message holds the
  original one.
- **Forward**: ``jax.pure_callback`` with the result shapes of
  :meth:`Op.output_shapes <glraster.diff.op.Op.output_shapes>`, calling
  ``Op.core(dtype).forward``: float32 runs on OpenGL, float64 (with ``jax_enable_x64``)
  the float64 reference.
- **Backward: the forward is recomputed.** The core's ``saved`` record is a Python object,
  and JAX residuals must be JAX values, so the residuals are the inputs themselves and the
  backward callback runs ``core.forward`` again to get ``saved``, then ``core.backward``.
  The price is one more forward per backward; docs/jax.md measures it.
- **vmap** (``vmap_method="broadcast_all"``): the callback gets every input with the mapped
  axes in front. Where the op has a batch axis B (every op except rasterize in range mode),
  the mapped axes are folded into B, so a vmapped call is ONE call of the core (one draw
  of all images); inputs that broadcast over B (a (V, 4) ``pos``, a batch-1 texture) are
  repeated, and their gradients summed back. Range-mode rasterize runs the core once per
  mapped entry.

Parameters that are not arrays, and ``tri``/``ranges`` (integer arrays: they decide shapes
and do not get gradients), are static: they are checked once and closed over.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import weakref
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from glraster.diff.op import Op
from glraster.diff.rasterizer_context import RasterizerContext
from glraster.errors import ArgumentError

__all__ = ["apply", "concrete", "is_traced"]

# Rank of each input when it carries the batch axis B in front (checked layout; see
# glraster.diff.ops): an input of one rank less has no B axis and broadcasts over B.
BATCHED_RANK = {
    "rasterize": {"pos": 3},
    "interpolate": {"attr": 3, "rast": 4, "rast_db": 4},
    "texture": {"tex": 4, "uv": 4, "uv_da": 4, "mip_level_bias": 3, "*mip": 4},
    "antialias": {"color": 4, "rast": 4, "pos": 3},
}


def is_traced(value) -> bool:
    """True for a JAX tracer (a value inside jit/vmap/grad, without a concrete value)."""
    return isinstance(value, jax.core.Tracer)


def static(name: str, value):
    """``value`` unchanged, for a static argument (``tri``, ``ranges``, every parameter): a
    tracer, or a tuple or list holding one, is an ArgumentError (it has no value while JAX
    traces)."""
    items = value if isinstance(value, (tuple, list)) else (value,)
    if any(is_traced(v) for v in items):
        raise ArgumentError(name, f"{name} must be concrete (NumPy, Python numbers, or a JAX "
                                  f"array made outside jax.jit): it decides the output's "
                                  f"shapes and takes no gradient; inside jit, close over it "
                                  f"or pass it as a static argument, got a traced value "
                                  f"{value}")
    return value


def concrete(name: str, value):
    """``value`` as a NumPy array (None stays None), for static array arguments (``tri``,
    ``ranges``): :func:`static`."""
    return None if value is None else np.asarray(static(name, value))


def _input_names(op: Op, count: int) -> list[str]:
    fixed = [n for n in op.inputs if not n.startswith("*")]
    names = list(fixed[:count])
    variadic = [n for n in op.inputs if n.startswith("*")]
    names += [f"{variadic[0][1:]}[{k}]" for k in range(count - len(fixed))] if variadic else []
    return names


def _rank_of(op: Op, name: str, params: dict) -> int:
    table = BATCHED_RANK[op.name]
    key = "*mip" if name.startswith("mip[") else name
    rank = table[key]
    if op.name == "texture" and key in ("tex", "*mip") and params.get("boundary_mode") == "cube":
        rank += 1   # cube maps (B, 6, N, N, C)
    return rank


def apply(op: Op, inputs: Sequence, params: dict):
    """Run ``op`` on ``inputs`` (JAX/NumPy arrays or None, in ``op.inputs`` order, the
    variadic tail flattened) with keyword ``params``. Returns the outputs, a tuple of JAX
    arrays in ``op.outputs`` order, differentiable with respect to every array input.

    Arrays are converted with ``jnp.asarray`` (a float64 NumPy array without
    ``jax_enable_x64`` becomes float32, as everywhere in JAX).
    """
    for name, value in params.items():   # (resolution, modes, max_mip_level, boost, ...)
        static(name, value)
    names = _input_names(op, len(inputs))
    arrays = [None if v is None else jnp.asarray(v) for v in inputs]
    for name, value in zip(names, arrays):
        if value is not None and value.dtype not in (jnp.float32, jnp.float64):
            raise ArgumentError(name, f"{name} must be a float32 or float64 array, got "
                                      f"{value.dtype}")
    traced = any(is_traced(v) for v in inputs if v is not None)
    if traced:
        probe = [None if v is None else np.zeros(v.shape, v.dtype) for v in arrays]
        checked, checked_params = op.check(*probe, **params)
    else:
        checked, checked_params = op.check(*(None if v is None else np.asarray(v)
                                             for v in arrays), **params)
    dtype = next(c.dtype for c in checked if c is not None)
    layout = tuple(None if c is None else tuple(c.shape) for c in checked)
    key = (op.name, layout, dtype.str, traced, _frozen(checked_params))
    call = _CACHE.get(key)
    if call is None:
        call = _CACHE[key] = _build(op, names, layout, dtype, checked_params, traced)
        while len(_CACHE) > CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
    return call(*(a.astype(dtype) for a in arrays if a is not None))


# The jitted call per op, input layout, dtype and static parameters: building one means
# tracing and compiling an XLA computation (~0.1 s), which an eager call would otherwise
# pay every time. Oldest first out; a context's calls go with it.
CACHE_SIZE = 256
_CACHE: dict = {}
_CONTEXT_TOKENS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_SERIAL = itertools.count()


def _context_token(glctx: RasterizerContext) -> tuple:
    """A front end's context in cache keys: a token, not the context, so that the cache
    does not keep a dropped context (and its OpenGL context) alive; its calls are dropped
    with it."""
    token = _CONTEXT_TOKENS.get(glctx)
    if token is None:
        token = _CONTEXT_TOKENS[glctx] = ("context", next(_SERIAL))
        weakref.finalize(glctx, _forget_calls, token).atexit = False
    return token


def _forget_calls(token) -> None:
    for key in [k for k in _CACHE if ("ctx", token) in k[-1]]:
        _CACHE.pop(key, None)


def _frozen(value):
    """A hashable stand-in for a static parameter: arrays by dtype, shape and bytes,
    containers element-wise, a front end's context by its token, anything else itself
    (topology hashes hash by identity, and the key keeps them alive)."""
    if isinstance(value, RasterizerContext):
        return _context_token(value)
    if isinstance(value, np.ndarray):
        return ("ndarray", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return (type(value).__name__,) + tuple(_frozen(v) for v in value)
    return value


def _build(op: Op, names, layout, dtype, checked_params: dict, traced: bool):
    """The jitted custom_vjp call of ``op`` for inputs of ``layout`` (shapes, None where
    absent) and ``dtype``."""
    present = [k for k, shape in enumerate(layout) if shape is not None]
    shapes = [layout[k] for k in present]
    probe = [None if shape is None else np.zeros(shape, dtype) for shape in layout]
    out_shapes = tuple(tuple(s) for s in op.output_shapes(*probe, **checked_params))
    result_types = tuple(jax.ShapeDtypeStruct(s, dtype) for s in out_shapes)
    grad_types = tuple(jax.ShapeDtypeStruct(s, dtype) for s in shapes)
    core = op.core(dtype)
    ranks = [_rank_of(op, names[k], checked_params) for k in present]
    # range-mode rasterize has no batch axis to fold a vmapped axis into
    foldable = not (op.name == "rasterize" and checked_params.get("ranges") is not None)
    glctx = checked_params.get("ctx")
    # a front end's context is held weakly (its calls are dropped with it, _context_token)
    glctx_ref = weakref.ref(glctx) if isinstance(glctx, RasterizerContext) else None
    static = {k: v for k, v in checked_params.items() if glctx_ref is None or k != "ctx"}
    del glctx, checked_params

    def params():
        """The checked params, with the front end's context if it has one."""
        return static if glctx_ref is None else dict(static, ctx=glctx_ref())

    def core_params():
        """The params for the core; a front end's context is made on first use, here in
        the callback, so that float64 and bad input never open OpenGL."""
        if glctx_ref is None:
            return static
        return dict(static, ctx=glctx_ref().context if dtype == np.float32 else None)

    def current():
        """The OpenGL context, current for a whole core call (its own ``with ctx:`` blocks
        then switch nothing); nothing for float64."""
        ctx = core_params().get("ctx")
        return contextlib.nullcontext() if ctx is None else ctx

    def full(values):
        """The core's positional inputs from the present arrays (None where absent)."""
        args = [None] * len(layout)
        for k, v in zip(present, values):
            args[k] = v
        return args

    def run_forward(values, check: bool = traced):
        args = full(values)
        if check:    # the values were not seen at trace time: check them now
            args, _ = op.check(*args, **params())
        return core.forward(*args, **core_params())

    def forward_host(*values):
        values = [np.asarray(v, dtype) for v in values]
        with current():
            return _batched(values, shapes, ranks, out_shapes, foldable,
                            lambda vs: tuple(run_forward(vs)[0]), reduce_inputs=False)

    def backward_host(*values_and_grads):
        values = [np.asarray(v, dtype) for v in values_and_grads[:len(present)]]
        grads = [np.asarray(g, dtype) for g in values_and_grads[len(present):]]

        def one(vs_and_gs):
            vs, gs = vs_and_gs[:len(present)], vs_and_gs[len(present):]
            _, saved = run_forward(vs, check=False)   # checked by the forward already
            result = core.backward(saved, *gs)
            out = []
            for k, v in zip(present, vs):
                g = result[k] if k < len(result) else None
                out.append(np.zeros(v.shape, dtype) if g is None
                           else np.asarray(g, dtype).reshape(v.shape))
            return tuple(out)

        with current():
            return _batched(values + grads, shapes + list(out_shapes),
                            ranks + [None] * len(out_shapes), shapes, foldable, one,
                            reduce_inputs=True, n_inputs=len(present))

    @jax.custom_vjp
    def call(*values):
        return tuple(jax.pure_callback(forward_host, result_types, *values,
                                       vmap_method="broadcast_all"))

    def call_fwd(*values):
        return call(*values), values

    def call_bwd(values, cotangents):
        return tuple(jax.pure_callback(backward_host, grad_types, *values, *cotangents,
                                       vmap_method="broadcast_all"))

    call.defvjp(call_fwd, call_bwd)
    return jax.jit(call)


def _batched(values, base_shapes, ranks, out_shapes, foldable, run, *, reduce_inputs,
             n_inputs=None):
    """Call ``run`` on ``values`` whose shapes are ``base_shapes`` with mapped axes in
    front (vmap): fold them into the batch axis B where ``foldable``, else loop.

    values      : list of arrays, each (*M, *base_shape) with the same mapped shape M
    ranks       : per value, its rank with a B axis (None: an output cotangent, which
                  always has B in front)
    out_shapes  : the shapes ``run`` returns for unmapped values
    run         : list of arrays (unmapped layout) -> tuple of arrays
    reduce_inputs: the results are gradients of the inputs (the first ``n_inputs`` values):
                  sum them over the repeats made to broadcast an input over B
    """
    lead = values[0].shape[:values[0].ndim - len(base_shapes[0])] if values else ()
    if not lead:
        return tuple(run(values))
    count = math.prod(lead)
    if count == 0 or not foldable:
        flat = [v.reshape((count,) + tuple(s)) for v, s in zip(values, base_shapes)]
        results = [run([v[i] for v in flat]) for i in range(count)]
        return tuple(np.stack([r[j] for r in results]).reshape(lead + tuple(s))
                     if count else np.zeros(lead + tuple(s), values[0].dtype)
                     for j, s in enumerate(out_shapes))
    batch = _batch_axis(base_shapes, ranks)
    folded, kinds = [], []
    for v, s, r in zip(values, base_shapes, ranks):
        v = v.reshape((count,) + tuple(s))
        if r is not None and len(s) == r - 1:           # no B axis: repeat over B
            v = np.broadcast_to(v[:, None], (count, batch) + tuple(s))
            kinds.append("missing")
        elif batch > 1 and s[0] == 1:                   # B of 1 broadcast over B
            v = np.broadcast_to(v, (count, batch) + tuple(s[1:]))
            kinds.append("one")
        else:
            kinds.append("full")
        folded.append(np.ascontiguousarray(v.reshape((count * v.shape[1],) + v.shape[2:])))
    results = run(folded)
    out = []
    for j, (res, s) in enumerate(zip(results, out_shapes)):
        kind = kinds[j] if reduce_inputs and j < n_inputs else "full"
        res = np.asarray(res)
        if kind == "missing":
            res = res.reshape((count, batch) + tuple(s)).sum(axis=1)
        elif kind == "one":
            res = res.reshape((count, batch) + tuple(s[1:])).sum(axis=1, keepdims=True)
        res = res.reshape(lead + tuple(s))
        out.append(res)
    return tuple(out)


def _batch_axis(base_shapes, ranks) -> int:
    """B of an unmapped call: the largest leading size among the inputs that have a B axis
    (the others broadcast)."""
    sizes = [s[0] for s, r in zip(base_shapes, ranks) if r is None or len(s) == r]
    return max(sizes, default=1)
