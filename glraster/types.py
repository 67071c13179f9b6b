"""Result types and output names shared by the GPU and the reference (NumPy only).

Conventions (docs/conventions in README): arrays are indexed ``[y, x]`` with row 0 at the
bottom (GL window coordinates); pixel (x, y) has its center at (x + 0.5, y + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Every output a raster can hold, in canonical order.
OUTPUTS = ("persp", "screen", "depth", "tri_id")
# The outputs holding values compared against a tolerance (tri_id is compared exactly).
VALUE_OUTPUTS = ("persp", "screen", "depth")
# Where a multisampled fragment's barycentrics are evaluated (GLSL qualifiers: none,
# ``centroid``, ``sample``; GL 4.5 core section 14.3.1, GLSL 4.50 section 4.5).
INTERPOLATIONS = ("center", "centroid", "sample")
# The single sample of a 1-sample raster: the pixel center, in pixel units.
CENTER_SAMPLE = ((0.5, 0.5),)


@dataclass
class Raster:
    """Per-pixel rasterization result. Arrays are indexed ``[y, x]``, row 0 at the bottom.

    persp  : (H, W, 3) float32 or None   perspective-correct barycentrics (b0, b1, b2)
    screen : (H, W, 3) float32 or None   window-space (noperspective) barycentrics
    depth  : (H, W)    float32 or None   window z in [0, 1]; 1.0 where empty
    tri_id : (H, W)    int32 or None     index into ``tri``; -1 where empty
    mask   : (H, W)    bool              pixel covered by some triangle

    Empty pixels hold barycentrics 0, depth 1.0, triangle id -1. An output that was not
    requested is None. Reference rasters hold float64 values.

    Multisampled (``samples`` S > 1): per-sample arrays carry a sample axis after W,
    ``tri_id`` (H, W, S), ``depth`` (H, W, S), ``mask`` (H, W, S); ``persp`` / ``screen`` are
    (H, W, S, 3) with ``interpolation="sample"`` (a value at every sample position) and
    (H, W, 3) with "center" / "centroid": one value per pixel, that of the fragment covering
    the pixel's lowest-numbered covered sample (:func:`first_covered_sample`), evaluated at
    the pixel center or at its centroid point. ``sample_positions`` (S, 2) float64 holds
    the sample offsets inside the pixel, in pixel units, GL window convention (y up; the
    center is (0.5, 0.5)), as the driver reports them; :attr:`coverage` is the covered
    fraction of each pixel's samples.
    """

    resolution: tuple
    mask: np.ndarray
    persp: np.ndarray | None = None
    screen: np.ndarray | None = None
    depth: np.ndarray | None = None
    tri_id: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    samples: int = 1
    interpolation: str = "center"
    sample_positions: np.ndarray | None = None

    def __post_init__(self):
        if self.sample_positions is None and self.samples == 1:
            self.sample_positions = np.array(CENTER_SAMPLE)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(n for n in OUTPUTS if getattr(self, n) is not None)

    @property
    def coverage(self) -> np.ndarray:
        """(H, W) float32: the covered fraction of each pixel's samples (0 or 1 when
        ``samples`` is 1)."""
        if self.mask.ndim == 3:
            return self.mask.mean(axis=2, dtype=np.float32)
        return self.mask.astype(np.float32)


def first_covered_sample(mask: np.ndarray) -> np.ndarray:
    """(H, W) int64 index of each pixel's lowest-numbered covered sample (0 where none is)
    from a per-sample ``mask`` (H, W, S) bool: the sample whose fragment gives a
    multisampled raster's per-pixel ``persp`` / ``screen`` ("center", "centroid")."""
    return np.argmax(mask, axis=2)


def per_pixel(values: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """``values`` (H, W, S, ...) at one sample per pixel, ``sample`` (H, W) int: (H, W, ...)."""
    index = sample.reshape(sample.shape + (1,) * (values.ndim - 2))
    return np.take_along_axis(values, index, axis=2)[:, :, 0]
