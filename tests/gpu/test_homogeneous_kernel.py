"""The compiled per-triangle setup (glraster.gpu.homogeneous_kernel) against its NumPy
formulation (glraster.gpu.homogeneous.setup_numpy in float64), bit for bit.

Bits, not values: the records are compared as uint32, so a different sign of zero, a
NaN turned into something else or one ulp anywhere fails. The triangles cover the
branches of the setup: random ones inside and around the viewport, ones crossing the
near plane (some w <= 0, the anchor from the remaining vertices), ones wholly behind the
eye (no anchor vertex: the viewport centre), zero-area and repeated-vertex ones (det = 0:
scale 0), tiny and huge w, far-from-origin ones at 16k viewports, and vertices at zero
(the signs of zero through np.clip and the sums).
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff.rasterize import RECORD_STRIDE, setup_records
from glraster.gpu import homogeneous
from glraster.gpu.homogeneous_kernel import records

RESOLUTIONS = [(4, 4), (256, 256), (777, 999), (16384, 16384)]


def _triangles(seed: int, n: int = 400) -> np.ndarray:
    """(T, 3, 4) float32 clip-space triangles mixing every case the setup branches on."""
    rng = np.random.default_rng(seed)
    parts = []
    w = rng.uniform(0.5, 3.0, (n, 3, 1))
    parts.append(np.concatenate([rng.uniform(-1.2, 1.2, (n, 3, 3)) * w, w], -1))   # random
    w = rng.uniform(-1.0, 2.0, (n, 3, 1))                                            # near plane
    parts.append(np.concatenate([rng.uniform(-2, 2, (n, 3, 3)), w], -1))
    w = -rng.uniform(0.1, 2.0, (n, 3, 1))                                            # behind
    parts.append(np.concatenate([rng.uniform(-2, 2, (n, 3, 3)), w], -1))
    flat = parts[0][:n // 4].copy()                                                  # degenerate
    flat[:, 2] = flat[:, 0]
    collinear = parts[0][:n // 4].copy()
    collinear[:, 2] = 0.5 * (collinear[:, 0] + collinear[:, 1])
    zero = np.zeros((8, 3, 4))
    zero[:, :, 3] = 1.0
    zero[1:, 0, :] = 0.0                                       # w = 0 vertices, all-zero rows
    zero[2:, 1, :2] = -0.0
    zero[4:, :, 0] = -0.0
    parts += [flat, collinear, zero]
    far = parts[0][:n // 2].copy()                                                   # far away
    far[..., :2] += rng.uniform(-0.999, 0.999, (n // 2, 1, 2)) * far[..., 3:]
    far[..., :2] = far[..., 3:] * np.clip(far[..., :2] / far[..., 3:], -1, 1)
    tiny = parts[0][:n // 4] * np.array([1, 1, 1, 1e-30])                           # tiny w
    huge = parts[0][:n // 4] * 1e30
    parts += [far, tiny, huge]
    return np.concatenate(parts).astype(np.float32)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


@pytest.mark.parametrize("resolution", RESOLUTIONS)
@pytest.mark.parametrize("seed", [0, 1])
def test_records_are_the_numpy_formulas_bit_for_bit(resolution, seed):
    clip = _triangles(seed)
    expected = homogeneous.setup_numpy(clip, resolution, np.float64, np.float32)
    got = homogeneous.setup(clip, resolution, fp64=False)
    assert got.dtype == np.float32 and got.shape == (len(clip), homogeneous.STRIDE)
    mismatch = np.flatnonzero((_bits(got) != _bits(expected)).any(1))
    assert not len(mismatch), (f"{len(mismatch)} records differ, first triangle "
                               f"{mismatch[0]}: {got[mismatch[0]]} vs {expected[mismatch[0]]}")


def test_the_cases_are_reached():
    """The scene exercises what it claims: anchors clamped and at the viewport centre,
    det = 0, signed zeros among the records (else the bit test above proves less)."""
    clip = _triangles(0)
    rec = homogeneous.setup_numpy(clip, (256, 256), np.float64, np.float32)
    centre = (rec[:, 0] == 128) & (rec[:, 1] == 128)
    assert centre.sum() >= 400                        # behind the eye: no anchor vertex
    assert ((rec[:, 2:8] == 0).all(1)).sum() >= 100   # scale 0 (det 0 or not finite)
    assert np.signbit(rec[rec == 0]).any() and (~np.signbit(rec[rec == 0])).any()
    w = clip[..., 3]
    assert ((w > 0).any(1) & (w <= 0).any(1)).sum() >= 100


def _setup_records_numpy(clip, resolution):
    """setup_records as the NumPy formulas: the 24 values, z_j / k, a pad."""
    rec = np.zeros((len(clip), RECORD_STRIDE), np.float32)
    rec[:, :24] = homogeneous.setup_numpy(clip, resolution, np.float64, np.float32)
    c = clip.astype(np.float64)
    k = np.abs(c[..., 3]).max(1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        rec[:, 24:27] = np.nan_to_num(c[..., 2] / k, nan=0.0, posinf=0.0, neginf=0.0)
    return rec


@pytest.mark.parametrize("resolution", [(256, 256), (777, 999)])
def test_rasterize_records_from_indices_bit_for_bit(resolution):
    """The rasterize op's records, read from (pos, tri) without gathering, equal the NumPy
    formulas on the gathered triangles."""
    clip = _triangles(2)
    pos = clip.reshape(-1, 4)
    rng = np.random.default_rng(3)
    tri = rng.permutation(len(pos)).reshape(-1, 3).astype(np.int32)
    expected = _setup_records_numpy(pos[tri], resolution)
    got = setup_records(pos, tri, resolution)
    assert (_bits(got) == _bits(expected)).all()


def test_partial_output_rows_and_empty():
    """The kernel writes every column it owns (the rest of a wider row is left alone) and
    accepts no triangles."""
    clip = _triangles(4, 40)
    pos = clip.reshape(-1, 4)
    tri = np.arange(len(pos), dtype=np.int32).reshape(-1, 3)
    out = np.full((len(tri), 30), np.nan, np.float32)
    records(pos, tri, 64, 48, out, True)
    assert np.isnan(out[:, 28:]).all() and not np.isnan(out[:, :28]).any()
    empty = np.empty((0, RECORD_STRIDE), np.float32)
    records(pos, tri[:0], 64, 48, empty, True)
    assert setup_records(pos, tri[:0], (48, 64)).shape == (0, RECORD_STRIDE)
