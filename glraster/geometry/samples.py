"""Multisample positions: the standard patterns and their fixed-point offsets.

A sample position is an offset inside the pixel in pixel units, GL window convention
(x right, y up, the pixel's lower-left corner at (0, 0), its center at (0.5, 0.5)), as
``glGetMultisamplefv(GL_SAMPLE_POSITION)`` reports it (GL 4.5 core section 14.3.1.1).
GL leaves the positions to the implementation. :data:`STANDARD_POSITIONS` are the
"standard sample locations" of Vulkan 1.0 section 24.3 (also Direct3D's), which Mesa
llvmpipe uses at 4 samples; the reference takes them when it is given no positions.

For a fixed-point fill rule with 2^b subpixel steps, pixel (i, j) samples its center at
the fixed-point point (2^b i, 2^b j) (:func:`glraster.geometry.fill_rule.fixed_edges`);
sample s is at (2^b i + dx_s, 2^b j + dy_s) with (dx_s, dy_s) = (offset_s - 0.5) 2^b,
integers for every standard pattern at b >= 4 (:func:`fixed_offsets`).
"""

from __future__ import annotations

import numpy as np

from glraster.errors import ArgumentError

STANDARD_POSITIONS = {
    1: ((0.5, 0.5),),
    2: ((0.75, 0.75), (0.25, 0.25)),
    4: ((0.375, 0.125), (0.875, 0.375), (0.125, 0.625), (0.625, 0.875)),
    8: ((0.5625, 0.3125), (0.4375, 0.6875), (0.8125, 0.5625), (0.3125, 0.1875),
        (0.1875, 0.8125), (0.0625, 0.4375), (0.6875, 0.9375), (0.9375, 0.0625)),
}


def standard_positions(samples: int) -> np.ndarray:
    """(S, 2) float64 standard sample positions for ``samples`` S (ValueError if none)."""
    if samples not in STANDARD_POSITIONS:
        raise ArgumentError(
            "samples", f"there is no standard sample pattern for samples={samples!r}; "
                     f"give sample_positions (known: {sorted(STANDARD_POSITIONS)})")
    return np.array(STANDARD_POSITIONS[samples], np.float64)


def fixed_offsets(positions: np.ndarray, one: int) -> np.ndarray | None:
    """(S, 2) int64 offsets (offset - 0.5) * ``one`` of each sample from the pixel's
    fixed-point center, or None when some offset is not a whole number of fixed-point
    steps (then the fixed-point model does not apply)."""
    scaled = (np.asarray(positions, np.float64) - 0.5) * one
    rounded = np.rint(scaled)
    if not np.array_equal(scaled, rounded):
        return None
    return rounded.astype(np.int64)
