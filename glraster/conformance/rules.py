"""Measuring a driver's rasterization rules: subpixel precision, tie rule and snapping.

GL leaves the tie rule (which triangle owns a pixel center on a shared edge) and the
subpixel precision (at least 4 bits) to the driver (GL 4.6 core section 14.6.1, GL 3.3
section 3.6.1), so a conformance check must judge coverage against the rules of the
driver under test. :func:`detect` renders one small probe scene (:func:`probe_scene`) and
compares the triangle ids of every pixel with the prediction of the parameterized
reference (:func:`glraster.reference.rasterize` with a
:class:`~glraster.geometry.fill_rule.FillRule`) for each candidate rule
(:func:`glraster.geometry.fill_rule.candidates`: 1 .. 12 subpixel bits x 6 tie rules x 5
snappings). The detected rule is the unique candidate that predicts every probe pixel;
otherwise the driver is "unidentified" and its coverage is judged by the edge band.

The probe scene, 256 x 256 px, every triangle alone in its own cell (w = 1, window
coordinates exact in float32, every vertex not under test on a pixel center or corner,
which snaps exactly at any precision and with any rounding):

- tie probes: triangles whose edges pass exactly through pixel centers, in the eight
  directions (left, right, bottom and top edges; four diagonals), in both windings;
- snapping probes (x: left edges): an edge near the centers of a column c, vertical at
  x = c + delta, or slanted from c + a delta to c + b delta with (a, b) = (1, -1), (-1, 2),
  (-3, 2) (EDGE_SHAPES), delta = +-k 2^-m (k = 1, 3; m = 1 .. 14). Its vertices snap onto
  c, to its left or to its right depending on the precision and the rounding, which
  decides whether the centers on the edge are covered; the slanted shapes tell apart
  roundings whose zero sets agree. Offsets below the center of column 0 give negative
  fixed-point values, where truncation and floor, round-half-up and round-half-away
  differ. The same probes transposed, with the inside on the other side (top edges),
  test y.

Every candidate predicts a different image of this scene (checked by
tests/conformance/test_rules.py), so at most one can match.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from glraster import reference as _reference
from glraster.errors import ArgumentError
from glraster.geometry.fill_rule import MAX_SUBPIXEL_BITS, FillRule, candidates
from glraster.geometry.window import window_float32

PROBE_RESOLUTION = (256, 256)  # (height, width): powers of two keep clip -> window exact
SNAP_OFFSETS = tuple((s, k, m) for s in (1, -1) for k in (1, 3)
                     for m in range(1, MAX_SUBPIXEL_BITS + 3))  # delta = s k 2^-m
CELL_ROWS = 3                  # a snapping probe: rows j .. j + 2


@dataclass(frozen=True)
class ProbeScene:
    """The rule probes: T triangles in clip space and what each one tests.

    pos : (3 T, 4) float32 clip positions (w = 1), tri : (T, 3) int32, resolution (H, W);
    labels : (T,) str, e.g. "tie: left edge, ccw" or "snap x: left edge at +3*2^-9";
    window : (T, 3, 2) float64 intended window positions (exactly the driver's float32).
    """

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple
    labels: tuple
    window: np.ndarray


def _delta(s, k, m) -> float:
    return s * k * 2.0 ** -m


def _delta_text(s, k, m) -> str:
    return f"{'+' if s > 0 else '-'}{k}*2^-{m}"


def _tie_triangles(x0: float, y0: float):
    """(label, three window vertices) for the eight edge directions through pixel centers,
    inside the 6 x 6 cell at corner (x0, y0)."""
    c, r = x0 + 2.5, y0 + 2.5                   # a pixel center of the cell
    i, j = x0 + 2, y0 + 2                       # its lower-left corner
    return [
        ("left edge", [(c, j - 1), (c + 3, j), (c, j + 2)]),
        ("right edge", [(c, j - 1), (c - 3, j), (c, j + 2)]),
        ("bottom edge", [(i - 1, r), (i, r + 3), (i + 2, r)]),
        ("top edge", [(i - 1, r), (i, r - 3), (i + 2, r)]),
        # slope +1 through the centers (i - 0.5, j - 0.5), (c, r), (i + 1.5, j + 1.5)
        ("diagonal edge, inside below-right", [(i - 1, j - 1), (i + 2, j + 2), (i + 2, j - 1)]),
        ("diagonal edge, inside above-left", [(i - 1, j - 1), (i + 2, j + 2), (i - 1, j + 2)]),
        # slope -1 through (i - 0.5, j + 1.5), (c, r), (i + 1.5, j - 0.5)
        ("anti-diagonal edge, inside above-right",
         [(i - 1, j + 2), (i + 2, j - 1), (i + 2, j + 2)]),
        ("anti-diagonal edge, inside below-left",
         [(i - 1, j + 2), (i + 2, j - 1), (i - 1, j - 1)]),
    ]


# Snapping probe edges: (name, a, b): the edge runs from (c + a delta, j + 0.5) to
# (c + b delta, j + 2.5) near the pixel centers of column c, so the center (c, j + 1.5) lies
# on it when the two snapped offsets cancel (a = b: a vertical edge, also through
# (c, j + 0.5)... when delta snaps to 0). Unequal a, b tell roundings apart whose zero sets
# agree: truncate and floor, round-half-even and round-half-up.
EDGE_SHAPES = {"vertical": (1, 1), "pair": (1, -1), "pair -1:2": (-1, 2), "pair -3:2": (-3, 2)}


def _snap_triangle(side: str, c: float, j: float, delta: float, shape: str, border: bool):
    """A triangle with a ``side`` ("left" or "right") edge of ``shape`` (EDGE_SHAPES) at
    offset ``delta`` from the pixel centers of column c; the third vertex 3 px inside (at
    x = 0 for a right edge in column 0), on a center x and a corner y."""
    a, b = EDGE_SHAPES[shape]
    inner = 0.0 if border and side == "right" else (c + 3 if side == "left" else c - 3)
    return [(c + a * delta, j + 0.5), (inner, j + 1.5), (c + b * delta, j + 2.5)]


def _snap_probes(border: bool, side: str):
    """(label, side, shape, delta) of the snapping probes of column 0 (``border``: the
    snapped values there are negative, which truncate / floor and round-half-up / -away
    treat differently) or of an interior column."""
    out = []
    for s, k, m in SNAP_OFFSETS:
        d = _delta(s, k, m)
        for shape, (a, b) in EDGE_SHAPES.items():
            if shape != "vertical" and s < 0:
                continue                        # the pairs hold both signs already
            if border:
                if shape == "pair -3:2":        # tells half-even from half-up: interior
                    continue
                lo, hi = 0.5 + min(a, b) * d, 0.5 + max(a, b) * d
                if shape == "vertical" and s > 0:
                    continue                    # positive offsets: the interior has them
                if lo < 0 or hi > 1.5:
                    continue
            elif shape == "pair -1:2":
                continue                        # tells truncate from floor: column 0 only
            text = (f"at {_delta_text(s, k, m)}" if shape == "vertical" else
                    f"from {a:+d}*delta to {b:+d}*delta, delta = {_delta_text(s, k, m)}")
            if border and side == "right" and 0.5 + min(a, b) * d <= 0:
                continue                        # no room left of the edge
            out.append((f"{shape} edge {text}" + (" in column 0" if border else ""),
                        side, shape, d))
    return out


def _transposed(verts):
    return [(y, x) for x, y in verts]


@lru_cache(maxsize=1)
def probe_scene() -> ProbeScene:
    """The rule probe scene (built once; see the module docstring for its layout)."""
    height, width = PROBE_RESOLUTION
    labels, window, snapped_axis = [], [], []

    def add(label, verts, transpose=False, axis=None):
        labels.append(label)
        window.append(_transposed(verts) if transpose else verts)
        snapped_axis.append(axis)

    # x: left edges (inside to the right); y: the same probes transposed with the inside
    # on the other side, top edges (inside below). Either axis alone tells every candidate
    # apart; the other one checks that the driver snaps y as it snaps x.
    for axis, transpose, side, name in (("x", False, "left", "left"),
                                        ("y", True, "right", "top")):
        # Column 0 (row 0 for y), from row 8 up.
        j = 8.0
        for label, side, shape, d in _snap_probes(True, side):
            add(f"snap {axis}: {name} {label}", _snap_triangle(side, 0.5, j, d, shape, True),
                transpose, axis)
            j += CELL_ROWS
        # Interior: three columns of cells, centers c = 12.5, 24.5, 36.5, from row 48 up.
        columns = (12.5, 24.5, 36.5)
        row = dict.fromkeys(columns, 48.0)
        for n, (label, side, shape, d) in enumerate(_snap_probes(False, side)):
            c = columns[n % len(columns)]
            add(f"snap {axis}: {name} {label}",
                _snap_triangle(side, c, row[c], d, shape, False), transpose, axis)
            row[c] += CELL_ROWS
    for n, (label, verts) in enumerate(_tie_triangles(0, 0)):
        for winding in ("ccw", "cw"):
            x0 = 100 + 8 * (2 * n + (winding == "cw"))
            shifted = [(x + x0, y + 200) for x, y in verts]
            pts = shifted if _area(shifted) > 0 else shifted[::-1]
            add(f"tie: {label}, {winding}", pts if winding == "ccw" else pts[::-1])

    window = np.asarray(window, np.float64)                     # (T, 3, 2)
    T = len(window)
    clip = np.zeros((T, 3, 4), np.float64)
    clip[..., 0] = window[..., 0] * 2 / width - 1
    clip[..., 1] = window[..., 1] * 2 / height - 1
    clip[..., 3] = 1.0
    pos = clip.reshape(-1, 4).astype(np.float32)
    got = window_float32(pos, PROBE_RESOLUTION).reshape(T, 3, 2).astype(np.float64)
    if not np.array_equal(got, window):
        bad = int(np.flatnonzero((got != window).any(axis=(1, 2)))[0])
        raise RuntimeError(f"rule probe {labels[bad]!r}: window position not exact in "
                           f"float32 ({window[bad].tolist()} -> {got[bad].tolist()})")
    _check_disjoint(window, labels, snapped_axis)
    tri = np.arange(3 * T, dtype=np.int32).reshape(T, 3)
    return ProbeScene(pos, tri, PROBE_RESOLUTION, tuple(labels), window)


def _area(verts) -> float:
    (ax, ay), (bx, by), (cx, cy) = verts
    return (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)


def _check_disjoint(window, labels, snapped_axis):
    """No two probe triangles can cover the same pixel, even with the vertices of their
    snapping probes moved by half a pixel along the probed axis (1 subpixel bit): pixel p
    can be covered when its center p + 0.5 lies within [lo, hi] (within [lo - 0.5,
    hi + 0.5] along the probed axis)."""
    slack = np.zeros((len(window), 2))
    for t, axis in enumerate(snapped_axis):
        if axis is not None:
            slack[t, "xy".index(axis)] = 0.5
    lo = np.ceil(window.min(axis=1) - slack - 0.5)
    hi = np.floor(window.max(axis=1) + slack - 0.5)
    for t in range(len(window)):
        overlap = (lo[t + 1:] <= hi[t]).all(1) & (hi[t + 1:] >= lo[t]).all(1)
        if overlap.any():
            u = t + 1 + int(np.flatnonzero(overlap)[0])
            raise RuntimeError(f"rule probes {labels[t]!r} and {labels[u]!r} overlap")
        if (window[t] < 0).any() or (window[t, :, 0] > PROBE_RESOLUTION[1]).any() \
                or (window[t, :, 1] > PROBE_RESOLUTION[0]).any():
            raise RuntimeError(f"rule probe {labels[t]!r} leaves the viewport")


@lru_cache(maxsize=1)
def _tie_region() -> np.ndarray:
    """(H, W) bool: the pixels the tie probes can cover."""
    s = probe_scene()
    out = np.zeros(s.resolution, bool)
    for label, verts in zip(s.labels, s.window):
        if label.startswith("tie:"):
            (x0, y0), (x1, y1) = np.floor(verts.min(0)).astype(int), np.ceil(verts.max(0)).astype(int)
            out[y0:y1 + 1, x0:x1 + 1] = True
    return out


def predict(rule: FillRule | None) -> np.ndarray:
    """(H, W) int32 triangle ids of the probe scene under ``rule`` (the parameterized
    reference; None: a float64 point-in-triangle test without snapping). Cached."""
    return _predict(rule).copy()


@lru_cache(maxsize=None)
def _predict(rule):
    s = probe_scene()
    return _reference.rasterize(s.pos, s.tri, s.resolution, outputs=("tri_id",),
                                fill_rule=rule).tri_id


@dataclass
class RuleDetection:
    """Outcome of :func:`detect`.

    rule      : the detected :class:`FillRule`, None when unidentified
    status    : "identified", "unidentified" or "error" (``message`` says why)
    matching  : every candidate that predicts every probe pixel (the detected rule alone
                when identified; several when the probes cannot tell them apart)
    closest   : (rule, mismatching pixels) of the nearest candidates, best first
    pixels    : pixels compared;  candidates : candidates tried
    mismatched_probes : labels of the probe triangles where the closest candidate is wrong
    reported_subpixel_bits : the driver's GL_SUBPIXEL_BITS, when known
    """

    rule: FillRule | None
    status: str
    matching: list = field(default_factory=list)
    closest: list = field(default_factory=list)
    pixels: int = 0
    candidates: int = 0
    mismatched_probes: list = field(default_factory=list)
    message: str = ""
    seconds: float = 0.0
    reported_subpixel_bits: int | None = None
    ids: np.ndarray | None = field(default=None, repr=False)  # the driver's probe image

    @property
    def identified(self) -> bool:
        return self.rule is not None

    def summary(self) -> str:
        """One line for report headers."""
        reported = ("" if self.reported_subpixel_bits is None
                    else f"; GL_SUBPIXEL_BITS {self.reported_subpixel_bits}")
        if self.identified:
            return (f"rules detected: {self.rule.name} (the one of {self.candidates} "
                    f"candidates that predicts all {self.pixels} probe pixels{reported}); "
                    "coverage judged exactly")
        return f"rules unidentified: {self.message}{reported}; coverage judged by the edge band"


def _probe_of_pixel(ids: np.ndarray, predicted: np.ndarray, labels) -> list:
    """Labels of the probe triangles involved in the pixels where ids differ."""
    differ = ids != predicted
    involved = set(ids[differ].tolist()) | set(predicted[differ].tolist())
    involved.discard(-1)
    if not involved:  # a pixel covered where no triangle was predicted, nor drawn
        return ["(a pixel outside every probe)"]
    return [labels[t] for t in sorted(involved)]


def detect(render, candidate_rules=None, *, reported_subpixel_bits=None) -> RuleDetection:
    """Detect the rules of the driver behind ``render``.

    render : callable (pos (V, 4) float32, tri (T, 3) int32, resolution (H, W)) -> (H, W)
        int32 triangle ids, -1 where empty (rows from the bottom, as glraster.rasterize).
        A GPU context (:func:`detect_on`), a fault-injection mutant, or the reference with
        some rule (a synthetic driver, for tests).
    candidate_rules : FillRules to try (default: every rule of the model)
    """
    t0 = time.perf_counter()
    rules = list(candidate_rules) if candidate_rules is not None else candidates()
    s = probe_scene()
    try:
        ids = np.asarray(render(s.pos, s.tri, s.resolution))
    except Exception as exc:  # a driver that cannot draw the probes is unidentified
        return RuleDetection(None, "error", candidates=len(rules),
                             message=f"the probe scene could not be rendered: "
                                     f"{type(exc).__name__}: {exc}",
                             seconds=time.perf_counter() - t0,
                             reported_subpixel_bits=reported_subpixel_bits)
    if ids.shape != tuple(s.resolution):
        raise ArgumentError(
            "render", f"render must return ({s.resolution[0]}, {s.resolution[1]}) ids, "
                      f"got shape {ids.shape}")
    # The tie probes' vertices are pixel centers and corners, exact at any precision and
    # with any rounding: their pixels depend on the tie rule alone, so they first set
    # aside every candidate of another tie rule (unless no tie rule fits them).
    region = _tie_region()
    ties = {r.tie for r in rules}
    fitting = {t for t in ties
               if np.array_equal(_predict(FillRule(8, t, "round-half-even"))[region], ids[region])}
    tried = [r for r in rules if r.tie in fitting] if fitting else rules
    scored = []
    for rule in tried:
        scored.append((int((_predict(rule) != ids).sum()), rule))
    matching = [r for n, r in scored if n == 0]
    scored.sort(key=lambda nr: nr[0])
    closest = [(r, n) for n, r in scored[:3]]
    out = RuleDetection(None, "unidentified", matching=matching, closest=closest,
                        pixels=int(ids.size), candidates=len(rules),
                        reported_subpixel_bits=reported_subpixel_bits, ids=ids)
    if len(matching) == 1:
        out.rule, out.status = matching[0], "identified"
        out.message = f"{matching[0].name}"
    elif matching:
        out.message = (f"{len(matching)} candidates predict every probe pixel "
                       f"({', '.join(r.name for r in matching[:4])}): the probes cannot "
                       "tell them apart")
    else:
        best, n = closest[0]
        out.mismatched_probes = _probe_of_pixel(ids, _predict(best), s.labels)
        shown = "; ".join(out.mismatched_probes[:4]) + (
            f"; ... ({len(out.mismatched_probes)} probes)" if len(out.mismatched_probes) > 4
            else "")
        out.message = (f"no candidate rule predicts every probe pixel; closest {best.name} "
                       f"with {n} pixels differing, at: {shown}")
    out.seconds = time.perf_counter() - t0
    return out


def detect_on(ctx, render=None) -> RuleDetection:
    """:func:`detect` on a GPU context (``render``: optional replacement of the draw, with
    glraster.rasterize's arguments and result, e.g. a fault-injection mutant's)."""
    if render is None:
        from glraster.gpu.rasterize import rasterize as render

    def ids(pos, tri, resolution):
        return render(pos, tri, resolution, ctx=ctx, outputs=("tri_id",)).tri_id

    return detect(ids, reported_subpixel_bits=getattr(ctx, "subpixel_bits", None))
