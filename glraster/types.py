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
    """

    resolution: tuple
    mask: np.ndarray
    persp: np.ndarray | None = None
    screen: np.ndarray | None = None
    depth: np.ndarray | None = None
    tri_id: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(n for n in OUTPUTS if getattr(self, n) is not None)
