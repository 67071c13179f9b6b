"""Calls no gradient flows through, remembered per OpenGL context with their outputs: a
later such call whose inputs are bit for bit the same gets copies of those outputs and
runs no GL work.

The case it serves is the fitting loop that renders its target under ``torch.no_grad()``
and then the same views again with the parameters being fitted, where those parameters
enter only after the GL ops (a material, a light): the second render's rasterize,
interpolate and texture calls repeat the first's exactly (as a user's nvdiffrast-style
loop does; glraster's own envmap fit shares those calls itself). The ops are deterministic
functions of their inputs and keyword arguments, so a remembered result is the result.

A front end (:mod:`glraster.torch.bridge`) decides which calls no gradient flows through
and hands them here with a ``stamp``: a callable giving the version counters of the
arrays' owners (inputs and outputs), so that an entry whose input or output was changed
in place since is never used (torch bumps a tensor's version on every in-place change;
writes that bypass it, through a NumPy view or ``.data``, are not seen, as for the upload
cache). An entry holds the call's arrays themselves, not copies; it matches a new call of
the same op with equal keyword arguments (arrays among them by content) whose inputs are
bitwise equal to its own (so -0.0 differs from 0.0): views of the memory it holds are,
others are compared. At most :data:`ENTRIES` calls per
context are held, the least recently used dropped first, each of at most
:data:`MAX_BYTES` (inputs and outputs), which bounds the memory held; :func:`forget`
drops them.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np

from glraster.diff.address import address

__all__ = ["ENTRIES", "MAX_BYTES", "forget", "lookup", "remember"]

ENTRIES = 8              # remembered calls per context
MAX_BYTES = 64 << 20     # inputs + outputs of a remembered call, bytes
PROBE = 64               # elements of an array compared first (:func:`_same_bits`)
_GOLDEN = (5 ** 0.5 - 1) / 2  # the probe's offsets: multiples of it mod 1, well spread

_lock = threading.Lock()
_by_context: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # ctx -> [_Entry]


class _Entry:
    __slots__ = ("signature", "params", "inputs", "outputs", "stamp", "stamped")

    def __init__(self, signature, params, inputs, outputs, stamp):
        self.signature, self.params, self.inputs, self.outputs = (signature, params, inputs,
                                                                  outputs)
        self.stamp, self.stamped = stamp, stamp()

    def matches(self, params: dict, inputs) -> bool:
        # the inputs first: in a fit's loop they are what differs from call to call
        return (all(_same(new, old) for new, old in zip(inputs, self.inputs))
                and params.keys() == self.params.keys()
                and all(_same(params[k], self.params[k]) for k in params)
                and self.stamp() == self.stamped)  # nothing held changed in place since


def _same(a, b) -> bool:
    """Arrays: the same bits; plain values: equal; other objects (a topology hash): the
    same object."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
                and a.shape == b.shape and a.dtype == b.dtype
                and (_same_memory(a, b) or _same_bits(a, b)))
    if isinstance(a, (str, int, float, bool, tuple, type(None))):
        return type(a) is type(b) and a == b
    return a is b


def _same_memory(a: np.ndarray, b: np.ndarray) -> bool:
    # a view of the memory the entry holds (alive, unchanged by its stamp): the same bits
    return address(a) == address(b) and a.strides == b.strides


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """a and b (of one shape and dtype) hold the same bits: where both are C-contiguous, a
    sample of PROBE elements spread over them first (:func:`_probe`; unequal arrays in a
    fit's loop differ almost everywhere, and a sample that differs decides), then all
    their bytes as 8-byte words (measured 1.6x faster than 4-byte ones on 3 MB); else
    element by element."""
    if a.flags.c_contiguous and b.flags.c_contiguous and a.ndim:
        a, b = a.reshape(-1), b.reshape(-1)
        if a.size > PROBE:
            at = _probe(a.size)
            if not np.array_equal(_bits(a[at]), _bits(b[at])):
                return False
        if a.nbytes % 8 == 0:
            return np.array_equal(a.view(np.uint64), b.view(np.uint64))
    return np.array_equal(_bits(a), _bits(b))


def _probe(size: int) -> np.ndarray:
    """PROBE element indices below ``size``, one in each of PROBE equal blocks, at an
    offset that varies from block to block: a plain stride can land on one channel of
    interleaved attributes (the normals of (V, 6) normals + reflections, the same in every
    call) or one column of images (an empty border), which agree while the arrays differ
    elsewhere (measured: 6 full comparisons an envmap iteration, 1.4 ms)."""
    k = np.arange(PROBE)
    step = size // PROBE
    return k * step + (k * _GOLDEN % 1.0 * step).astype(np.int64)  # (offsets < step)


def _bits(a: np.ndarray) -> np.ndarray:
    return a.view(f"u{a.itemsize}") if a.dtype.kind == "f" else a


def _signature(op, inputs) -> tuple:
    return (op, tuple(None if a is None else (a.shape, a.dtype) for a in inputs))


def _without_context(params: dict) -> dict:
    # the context is the table's weak key: an entry holding it would keep it alive
    return {k: v for k, v in params.items() if k != "ctx"}


def lookup(ctx, op, params: dict, inputs) -> list[np.ndarray] | None:
    """Copies of the outputs of a remembered call of ``op`` on ``ctx`` with these
    ``params`` (the checked keyword arguments) and ``inputs`` (arrays or None, in the
    op's order), or None."""
    signature, params = _signature(op, inputs), _without_context(params)
    with _lock:
        entries = _by_context.get(ctx, [])
        for k, entry in enumerate(entries):
            if entry.signature == signature and entry.matches(params, inputs):
                entries.append(entries.pop(k))  # the most recently used last
                return [np.array(out) for out in entry.outputs]
    return None


def remember(ctx, op, params: dict, inputs, outputs, stamp) -> None:
    """Hold the call (when at most MAX_BYTES) as ``ctx``'s most recently used one;
    ``stamp()``: the version counters of its arrays' owners, now and at every lookup."""
    if sum(a.nbytes for a in (*inputs, *outputs) if a is not None) > MAX_BYTES:
        return
    entry = _Entry(_signature(op, inputs), _without_context(params), tuple(inputs),
                   tuple(outputs), stamp)
    with _lock:
        entries = _by_context.setdefault(ctx, [])
        entries.append(entry)
        del entries[:-ENTRIES]


def forget(ctx=None) -> None:
    """Drop the calls held for ``ctx`` (every context's when None)."""
    with _lock:
        if ctx is None:
            _by_context.clear()
        else:
            _by_context.pop(ctx, None)
