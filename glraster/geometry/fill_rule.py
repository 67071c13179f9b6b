"""Fixed-point coverage rules: vertex snapping and edge setup, parameterized per driver.

A :class:`FillRule` is ``(subpixel_bits, tie, snap)``: vertices snap to 2^-subpixel_bits px
with the rounding ``snap``, and a pixel center lying exactly on an edge is covered when the
edge's side owns it by ``tie``. Mesa llvmpipe's rule (docs/llvmpipe.md) is the instance
:data:`LLVMPIPE` = (8, "bottom-left", "round-half-even"); the reference rasterizes with the
rule of the driver under test, glraster.conformance.rules measures it on the GPU, and
GPU-side culling drops what llvmpipe's rule culls. For unclipped triangles inside the
viewport the model reproduces llvmpipe's coverage bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster.errors import ArgumentError

SUBPIXEL_BITS = 8  # llvmpipe: FIXED_ORDER = 8, so positions snap to 1/256 px
FIXED_ONE = 1 << SUBPIXEL_BITS

# Tie rules, named in GL window coordinates (y up). For the four corner rules a center on
# an edge belongs to the triangle on the named horizontal side of a non-horizontal edge
# ("left": the edge is the triangle's left edge, its inside to the right), and for a
# horizontal edge to the triangle on the named vertical side ("bottom": the edge is the
# triangle's bottom edge). "all": every edge owns its centers (both triangles of a shared
# edge cover them); "none": no edge does (a center on any edge is never covered).
TIES = ("bottom-left", "top-left", "top-right", "bottom-right", "all", "none")
# Roundings of the fixed-point value a = (x_w - 0.5) 2^subpixel_bits to an integer.
SNAPS = ("round-half-even", "round-half-up", "round-half-away", "truncate", "floor")
# Subpixel precisions the model covers (GL asks for at least 4; 1 .. 3 are kept so that a
# driver below the minimum is named, not just unidentified).
MAX_SUBPIXEL_BITS = 12


@dataclass(frozen=True)
class FillRule:
    """A driver's coverage rule.

    subpixel_bits : int   vertices snap to 2^-subpixel_bits px (1 .. MAX_SUBPIXEL_BITS)
    tie           : str   which edges own the centers on them, one of :data:`TIES`
    snap          : str   the rounding of (x_w - 0.5) 2^subpixel_bits, one of :data:`SNAPS`
    """

    subpixel_bits: int = SUBPIXEL_BITS
    tie: str = "bottom-left"
    snap: str = "round-half-even"

    def __post_init__(self):
        if not (isinstance(self.subpixel_bits, (int, np.integer))
                and 1 <= self.subpixel_bits <= MAX_SUBPIXEL_BITS):
            raise ArgumentError(
                "subpixel_bits", f"subpixel_bits must be an integer in 1 .. {MAX_SUBPIXEL_BITS}, "
                                 f"got {self.subpixel_bits!r}")
        if self.tie not in TIES:
            raise ArgumentError("tie", f"tie must be one of {TIES}, got {self.tie!r}")
        if self.snap not in SNAPS:
            raise ArgumentError("snap", f"snap must be one of {SNAPS}, got {self.snap!r}")

    @property
    def one(self) -> int:
        """Fixed-point units per pixel, 2^subpixel_bits."""
        return 1 << int(self.subpixel_bits)

    @property
    def name(self) -> str:
        return f"{self.subpixel_bits} subpixel bits, {self.tie}, {self.snap}"

    @property
    def window_limit(self) -> float:
        """|x_w| below which the fixed-point setup stays exact in int64 (snapped
        coordinates below 2^30, edge products below 2^61): 2^22 px at 8 bits."""
        return float(1 << (30 - int(self.subpixel_bits)))

    @property
    def edge_band_px(self) -> float:
        """Half-width of the edge band for the triangles the rule does not model (clipped
        ones get new float vertices): 4 fixed-point steps, at least 4/256 px."""
        return max(4.0, 4.0 * FIXED_ONE / self.one) / FIXED_ONE

    def __str__(self) -> str:
        return self.name


LLVMPIPE = FillRule(SUBPIXEL_BITS, "bottom-left", "round-half-even")


def candidates(bits=None, ties=TIES, snaps=SNAPS) -> list[FillRule]:
    """Every rule of the model (default: 1 .. MAX_SUBPIXEL_BITS bits x TIES x SNAPS)."""
    bits = range(1, MAX_SUBPIXEL_BITS + 1) if bits is None else bits
    return [FillRule(b, t, s) for b in bits for t in ties for s in snaps]


def snap(window: np.ndarray, subpixel_bits: int = SUBPIXEL_BITS,
         mode: str = "round-half-even") -> np.ndarray:
    """Fixed-point vertex positions X = round((x_w - 0.5) 2^subpixel_bits): the subtraction
    in float32, the scaling exact, then the rounding ``mode`` (one of :data:`SNAPS`;
    llvmpipe's calc_fixed_position, lp_setup_tri.c, rounds to nearest even). The one
    snapping of the project: the reference's edge setup (:func:`fixed_edges`) and GPU-side
    culling both use it.

    window: (...) float32 window coordinates (glraster.geometry.window.window_float32).
    Returns float32 of the same shape holding integers exactly (a rounded float32 is
    representable: every float32 of magnitude 2^23 or more is an integer), inf / nan where
    the input is; the caller converts, after masking out what it does not model (the
    reference keeps |x_w| below :attr:`FillRule.window_limit`).
    """
    window = np.asarray(window, dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        fixed = window - np.float32(0.5)
        fixed *= np.float32(1 << subpixel_bits)
        if mode == "round-half-even":
            return np.rint(fixed, out=fixed)
        a = fixed.astype(np.float64)               # a + 1/2 is exact in float64
        if mode == "round-half-up":
            out = np.floor(a + 0.5)
        elif mode == "round-half-away":
            out = np.copysign(np.floor(np.abs(a) + 0.5), a)
        elif mode == "truncate":
            out = np.trunc(a)
        elif mode == "floor":
            out = np.floor(a)
        else:
            raise ArgumentError("mode", f"mode must be one of {SNAPS}, got {mode!r}")
        return out.astype(np.float32)


def _owns(dcdx: np.ndarray, dcdy: np.ndarray, tie: str) -> np.ndarray:
    """Whether an edge owns the centers on it. The inward normal of edge (dcdx, dcdy) is
    (-dcdx, dcdy) in GL window coordinates: dcdx < 0 is a left edge, dcdx == 0 and
    dcdy > 0 a bottom edge."""
    if tie == "all":
        return np.ones(dcdx.shape, bool)
    if tie == "none":
        return np.zeros(dcdx.shape, bool)
    vertical, horizontal = tie.split("-")
    side = dcdx < 0 if horizontal == "left" else dcdx > 0
    level = dcdy > 0 if vertical == "bottom" else dcdy < 0
    return side | ((dcdx == 0) & level)


def fixed_edges(window: np.ndarray, rule: FillRule = LLVMPIPE):
    """A fixed-point edge setup of ``rule`` for triangles given by float32 window positions.

    window: (T, 3, 2) float32. Returns (edges, ok): edges (T, 3, 3) int64 holding
    (dcdx, dcdy, c) per edge and ok (T,) bool (False: zero area after snapping, culled).

    Vertices snap to X = snap((x_w - 0.5) 2^bits), so pixel (i, j) samples the fixed-point
    point (2^bits i, 2^bits j). After ordering the vertices so that the opposite vertex
    lies on the positive side, per edge i -> i+1: dcdx = Y_i - Y_{i+1}, dcdy = X_i - X_{i+1},
    c = dcdx X_i - dcdy Y_i, plus 1 when the edge owns its centers (:data:`TIES`; llvmpipe:
    dcdx < 0 or (dcdx == 0 and dcdy > 0), a bottom-left rule in GL window coordinates). A
    sample is covered when c - dcdx x + dcdy y >= 1 on all three edges.
    """
    snapped = snap(window, rule.subpixel_bits, rule.snap).astype(np.int64)
    x, y = snapped[..., 0].copy(), snapped[..., 1].copy()
    side = (y[:, 0] - y[:, 1]) * (x[:, 0] - x[:, 2]) - (x[:, 0] - x[:, 1]) * (y[:, 0] - y[:, 2])
    flip = side < 0
    x[flip, 1], x[flip, 2] = x[flip, 2], x[flip, 1].copy()
    y[flip, 1], y[flip, 2] = y[flip, 2], y[flip, 1].copy()
    nxt = [1, 2, 0]
    dcdx = y - y[:, nxt]
    dcdy = x - x[:, nxt]
    c = dcdx * x - dcdy * y
    c += _owns(dcdx, dcdy, rule.tie)
    return np.stack([dcdx, dcdy, c], axis=-1), side != 0


def llvmpipe_edges(window: np.ndarray):
    """llvmpipe's fixed-point edge setup: :func:`fixed_edges` with :data:`LLVMPIPE`
    (8 subpixel bits, bottom-left, round-half-even).

    window: (T, 3, 2) float32. Returns (edges (T, 3, 3) int64 (dcdx, dcdy, c), ok (T,) bool).
    """
    return fixed_edges(window, LLVMPIPE)
