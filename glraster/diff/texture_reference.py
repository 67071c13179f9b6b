"""Texture sampling with mipmaps: argument checks, the mip pyramid and the float64 reference
of the forward and backward (NumPy only; seed 003, "texture"; docs/differentiable.md,
"Texture").

Layouts (nvdiffrast's documented ones; B the batch, H x W the image, rows [y, x]):

    tex            (Bt, Ht, Wt, C)        2-D texture, Bt = 1 (broadcast) or B;
                   (Bt, 6, N, N, C)       cube map (boundary_mode="cube"), faces +x, -x,
                                          +y, -y, +z, -z
    uv             (B, H, W, 2)           (s, t): texel (i, j) = tex[b, j, i] has its centre
                                          at ((i + 0.5) / Wt, (j + 0.5) / Ht);
                   (B, H, W, 3)           cube: a direction (x, y, z), any length > 0
    uv_da          (B, H, W, 4)           (ds/dX, ds/dY, dt/dX, dt/dY) per image pixel;
                   (B, H, W, 6)           cube: (dx/dX, dx/dY, dy/dX, dy/dY, dz/dX, dz/dY)
    mip_level_bias (B, H, W)              added to the level
    mip            [level 1, level 2, ...] each (Bt, Ht_k, Wt_k, C) (cube (Bt, 6, N_k, N_k, C))
    out            (B, H, W, C)

The level (mipmap modes) is seed 003's: with J the Jacobian of the texel position
(s Wt, t Ht) with respect to the image pixel (X, Y), a = Wt ds/dX, b = Wt ds/dY,
c = Ht dt/dX, d = Ht dt/dY, the entries of J^T J are A = a^2 + c^2, B = b^2 + d^2,
C = ab + cd, its largest eigenvalue ``lenMajorSqr`` = (A + B)/2 + sqrt(((A - B)/2)^2 + C^2)
and level = 0.5 log2(lenMajorSqr) (+ bias), clamped to [0, number of levels - 1].
Without uv_da the level is the bias (0 without either).

The mip pyramid: level k + 1 has extents max(1, n // 2) of level k's n, down to 1 x 1.
Each texel is the mean of the finer level over its footprint: an even extent gives the
2 x 2 box; an odd extent n = 2m + 1 gives m texels, texel j weighting the finer texels
2j, 2j + 1, 2j + 2 by (m - j, m, j + 1) / (2m + 1) (per axis; 3 x 3 taps in 2-D), so that
every finer texel counts and the texel-centre convention holds at every level.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from glraster.diff import layout

__all__ = [
    "BOUNDARY_MODES", "FILTER_MODES", "OwnMips", "TextureArgs", "TextureSaved", "backward",
    "build_mips", "check_arguments", "forward", "level_shapes", "lookup_geometry",
    "mips_backward", "texel_sums",
]

FILTER_MODES = ("auto", "nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear")
BOUNDARY_MODES = ("wrap", "clamp", "zero", "cube")
MIP_MODES = ("linear-mipmap-nearest", "linear-mipmap-linear")
FILTER_CODE = {"nearest": 0, "linear": 1, "linear-mipmap-nearest": 2, "linear-mipmap-linear": 3}
BOUNDARY_CODE = {"wrap": 0, "clamp": 1, "zero": 2, "cube": 3}

# cube faces (+x, -x, +y, -y, +z, -z), GL's table 8.19: s_c = sigma_s d[axis_s],
# t_c = sigma_t d[axis_t], m = sigma_m d[axis_m] > 0, s = (s_c / m + 1) / 2 (t alike)
CUBE_FACES = np.array([
    # axis_s, sigma_s, axis_t, sigma_t, axis_m, sigma_m
    (2, -1, 1, -1, 0, +1),
    (2, +1, 1, -1, 0, -1),
    (0, +1, 2, +1, 1, +1),
    (0, +1, 2, -1, 1, -1),
    (0, +1, 1, -1, 2, +1),
    (0, -1, 1, -1, 2, -1),
], np.int64)

LN2 = math.log(2.0)


# --------------------------------------------------------------------------- arguments


@dataclass(frozen=True)
class TextureArgs:
    """Checked arguments of a texture call (arrays C-contiguous, of one float dtype).

    ``shapes`` lists (H_k, W_k) of every level used (base first); ``mip`` the given levels
    1 .. (all given, checked; the first ``levels - 1`` are used; None when the pyramid is
    built or the mode has no mipmaps); ``own_mips``: ``mip`` is tex's own pyramid built
    earlier (:class:`OwnMips`), whose level gradients the backward pulls back into the base
    as for a pyramid built in the call; ``filter_mode`` is resolved ('auto' replaced);
    ``levels`` = len(shapes)."""

    tex: np.ndarray
    uv: np.ndarray
    uv_da: np.ndarray | None
    bias: np.ndarray | None
    mip: tuple | None
    filter_mode: str
    boundary_mode: str
    shapes: tuple
    own_mips: bool = False

    @property
    def cube(self) -> bool:
        return self.boundary_mode == "cube"

    @property
    def levels(self) -> int:
        return len(self.shapes)

    @property
    def mipmapped(self) -> bool:
        return self.filter_mode in MIP_MODES

    @property
    def channels(self) -> int:
        return self.tex.shape[-1]


@dataclass(frozen=True)
class OwnMips:
    """Levels 1, 2, ... of tex's own pyramid, built earlier by :func:`build_mips` (or the
    GPU's :func:`glraster.diff.texture.build_mips`), passed as ``mip`` to skip building
    them again. Unlike a user's mip stack (a list), they get no gradient of their own: their
    gradients are pulled back into tex through the box filter, as for a pyramid built in
    the call, so tex's gradient is the same as with ``mip=None``."""

    levels: tuple


def level_shapes(height: int, width: int, max_mip_level=None) -> list[tuple[int, int]]:
    """(H_k, W_k) of the base and every mip level: halved (floor, at least 1) down to 1 x 1,
    at most ``max_mip_level`` levels after the base (None: all)."""
    shapes = [(int(height), int(width))]
    while shapes[-1] != (1, 1) and (max_mip_level is None or len(shapes) <= max_mip_level):
        h, w = shapes[-1]
        shapes.append((max(1, h // 2), max(1, w // 2)))
    return shapes


def _float_array(name, value, dtype, ndim_text):
    arr = layout.real_array(name, value)
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    return arr, out


def _finite(name, arr, out):
    bad = ~np.isfinite(out)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} must be finite, got NaN or Inf (or a value beyond "
                         f"{out.dtype}) at index {where}")
    return out


def check_arguments(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
                    boundary_mode="wrap", max_mip_level=None, dtype=np.float64) -> TextureArgs:
    """Every argument of :func:`forward` checked (ValueError naming it) and converted."""
    if not isinstance(boundary_mode, str) or boundary_mode not in BOUNDARY_MODES:
        raise ValueError(f"boundary_mode must be one of {BOUNDARY_MODES}, got {boundary_mode!r}")
    if not isinstance(filter_mode, str) or filter_mode not in FILTER_MODES:
        raise ValueError(f"filter_mode must be one of {FILTER_MODES}, got {filter_mode!r}")
    if max_mip_level is not None and (isinstance(max_mip_level, (bool, np.bool_)) or not
                                      isinstance(max_mip_level, numbers.Integral)
                                      or max_mip_level < 0):
        raise ValueError(f"max_mip_level must be None or an integer >= 0, got {max_mip_level!r}")
    cube = boundary_mode == "cube"

    arr, tex_ = _float_array("tex", tex, dtype, None)
    if cube:
        if arr.ndim != 5 or arr.shape[1] != 6 or arr.shape[2] != arr.shape[3]:
            raise ValueError("tex must have shape (B, 6, N, N, C) (a cube map of square faces)"
                             f" with boundary_mode='cube', got {arr.shape}")
    elif arr.ndim != 4:
        more = " (a 5-D tex is a cube map: pass boundary_mode='cube')" if arr.ndim == 5 else ""
        raise ValueError(f"tex must have shape (B, Ht, Wt, C), got {arr.shape}{more}")
    if min(arr.shape) < 1:
        raise ValueError(f"tex must have every extent >= 1, got shape {arr.shape}")
    tex_ = _finite("tex", arr, tex_)

    coords = 3 if cube else 2
    arr, uv_ = _float_array("uv", uv, dtype, None)
    if arr.ndim != 4 or arr.shape[-1] != coords:
        what = "a direction (x, y, z) per pixel with boundary_mode='cube'" if cube else "(s, t)"
        raise ValueError(f"uv must have shape (B, H, W, {coords}) ({what}), got {arr.shape}")
    if arr.shape[0] < 1:
        raise ValueError(f"uv must have a batch of at least 1, got shape {arr.shape}")
    uv_ = _finite("uv", arr, uv_)
    batch = uv_.shape[0]
    if tex_.shape[0] not in (1, batch):
        raise ValueError(f"tex has a batch of {tex_.shape[0]}, uv of {batch}: they must match "
                         "(or tex's be 1)")

    da = None
    if uv_da is not None:
        arr, da = _float_array("uv_da", uv_da, dtype, None)
        want = uv_.shape[:3] + (2 * coords,)
        if arr.shape != want:
            raise ValueError(f"uv_da must have shape {want} (uv's with the last axis twice as "
                             f"long), got {arr.shape}")
        da = _finite("uv_da", arr, da)
    bias = None
    if mip_level_bias is not None:
        arr, bias = _float_array("mip_level_bias", mip_level_bias, dtype, None)
        if arr.shape != uv_.shape[:3]:
            raise ValueError(f"mip_level_bias must have shape {uv_.shape[:3]} (B, H, W), "
                             f"got {arr.shape}")
        bias = _finite("mip_level_bias", arr, bias)

    if filter_mode == "auto":
        filter_mode = "linear-mipmap-linear" if (da is not None or bias is not None) else "linear"
    height, width = tex_.shape[-3], tex_.shape[-2]
    if filter_mode not in MIP_MODES:
        shapes = ((height, width),)
        mip_ = None
    elif mip is None:
        shapes = tuple(level_shapes(height, width, max_mip_level))
        mip_ = None
    else:
        own = isinstance(mip, OwnMips)
        if own:
            mip = mip.levels
        if isinstance(mip, np.ndarray) or not isinstance(mip, (list, tuple)):
            raise ValueError(f"mip must be None or a list of mip levels 1, 2, ... (arrays), "
                             f"got {type(mip).__name__}")
        full = level_shapes(height, width)
        if len(mip) > len(full) - 1:
            raise ValueError(f"mip has {len(mip)} levels, more than the {len(full) - 1} a "
                             f"{height}x{width} texture has below its base")
        used = len(mip) if max_mip_level is None else min(len(mip), int(max_mip_level))
        levels = []
        for k in range(len(mip)):
            name = f"mip[{k}]"
            arr, level = _float_array(name, mip[k], dtype, None)
            h, w = full[k + 1]
            want = tex_.shape[:-3] + (h, w, tex_.shape[-1])
            if arr.shape != want:
                raise ValueError(f"{name} (mip level {k + 1}) must have shape {want}, got "
                                 f"{arr.shape}")
            levels.append(_finite(name, arr, level))
        shapes = tuple(full[:used + 1])
        mip_ = tuple(levels)
        return TextureArgs(tex_, uv_, da, bias, mip_, filter_mode, boundary_mode, shapes, own)
    return TextureArgs(tex_, uv_, da, bias, mip_, filter_mode, boundary_mode, shapes)


# --------------------------------------------------------------------------- mip pyramid


def _axis_weights(n: int):
    """(m, taps, weights): output texel j of a level with extent n reads input texels
    taps[j] (m, 3) with weights[j] (m, 3); out-of-range taps have weight 0 (index 0)."""
    m = max(1, n // 2)
    j = np.arange(m)
    taps = np.stack([2 * j, 2 * j + 1, 2 * j + 2], axis=1)
    if n == 1:
        w = np.array([[1.0, 0.0, 0.0]])
    elif n % 2 == 0:
        w = np.tile([0.5, 0.5, 0.0], (m, 1))
    else:
        w = np.stack([m - j, np.full(m, m), j + 1], axis=1) / (2.0 * m + 1.0)
    taps = np.where(w > 0, taps, 0)
    return m, taps, w


def _downsample(level: np.ndarray) -> np.ndarray:
    """One pyramid step of (..., H, W, C)."""
    h, w = level.shape[-3], level.shape[-2]
    _, ty, wy = _axis_weights(h)
    _, tx, wx = _axis_weights(w)
    rows = np.einsum("...jkac,jk->...jac", level[..., ty, :, :], wy)   # (..., mh, W, C)
    return np.einsum("...ajkc,jk->...ajc", rows[..., :, tx, :], wx)


def _upsample_transpose(grad: np.ndarray, h: int, w: int) -> np.ndarray:
    """The transpose of :func:`_downsample` from a coarse level's gradient to (.., h, w, C)."""
    _, ty, wy = _axis_weights(h)
    _, tx, wx = _axis_weights(w)
    lead = grad.shape[:-3]
    c = grad.shape[-1]
    cols = np.zeros(lead + (grad.shape[-3], w, c))
    for k in range(3):
        np.add.at(cols, (..., slice(None), tx[:, k], slice(None)),
                  grad * wx[:, k][:, None])
    out = np.zeros(lead + (h, w, c))
    for k in range(3):
        np.add.at(out, (..., ty[:, k], slice(None), slice(None)),
                  cols * wy[:, k][:, None, None])
    return out


def build_mips(tex: np.ndarray, shapes) -> list[np.ndarray]:
    """Levels 1 .. len(shapes) - 1 of ``tex`` (..., H, W, C), in float64."""
    levels = [np.asarray(tex, np.float64)]
    for h, w in shapes[1:]:
        levels.append(_downsample(levels[-1]))
        assert levels[-1].shape[-3:-1] == (h, w)
    return levels[1:]


def mips_backward(grad_levels, shapes) -> np.ndarray:
    """dL/d base of a built pyramid from dL/d every level (base first): each level's
    gradient is pulled back through the pyramid step, coarsest first."""
    total = np.array(grad_levels[-1], np.float64)
    for k in range(len(shapes) - 1, 0, -1):
        h, w = shapes[k - 1]
        total = grad_levels[k - 1] + _upsample_transpose(total, h, w)
    return total


# --------------------------------------------------------------------------- sampling


@dataclass
class TextureSaved:
    """What :func:`backward` needs from :func:`forward`: the checked arguments and every
    level (base first, float64)."""

    args: TextureArgs
    levels: list


def _cube_face(d):
    """Face index (N,), s, t in [0, 1] (N,) and ds/dd, dt/dd (N, 3) of directions d (N, 3).
    The major axis is the largest |component| (ties: x before y before z)."""
    a = np.abs(d)
    axis = np.where((a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2]), 0,
                    np.where(a[:, 1] >= a[:, 2], 1, 2))
    positive = d[np.arange(len(d)), axis] >= 0
    face = 2 * axis + np.where(positive, 0, 1)
    f = CUBE_FACES[face]
    n = np.arange(len(d))
    m = f[:, 5] * d[n, f[:, 4]]
    ok = m > 0
    m_safe = np.where(ok, m, 1.0)
    sc = f[:, 1] * d[n, f[:, 0]]
    tc = f[:, 3] * d[n, f[:, 2]]
    s = np.where(ok, (sc / m_safe + 1.0) / 2.0, 0.5)
    t = np.where(ok, (tc / m_safe + 1.0) / 2.0, 0.5)
    ds = np.zeros((len(d), 3))
    dt = np.zeros((len(d), 3))
    ds[n, f[:, 0]] += f[:, 1] / (2.0 * m_safe)
    ds[n, f[:, 4]] -= sc * f[:, 5] / (2.0 * m_safe ** 2)
    dt[n, f[:, 2]] += f[:, 3] / (2.0 * m_safe)
    dt[n, f[:, 4]] -= tc * f[:, 5] / (2.0 * m_safe ** 2)
    ds[~ok] = 0.0
    dt[~ok] = 0.0
    return face, s, t, ds, dt, ok


def _cube_neighbour(face, i, j, n):
    """The texel of the cube that continues face ``face`` beyond its edge: (face, i, j)
    with one of i, j equal to -1 or n (the other inside). The texel centre's direction
    (integer, in units of half a texel) is projected onto the face its major axis names."""
    f = CUBE_FACES[face]
    sc = 2 * i + 1 - n
    tc = 2 * j + 1 - n
    d = np.zeros(face.shape + (3,), np.int64)
    idx = np.arange(face.size)
    d[idx, f[:, 0]] = f[:, 1] * sc
    d[idx, f[:, 2]] = f[:, 3] * tc
    d[idx, f[:, 4]] = f[:, 5] * n
    a = np.abs(d)
    axis = np.where((a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2]), 0,
                    np.where(a[:, 1] >= a[:, 2], 1, 2))
    new_face = 2 * axis + np.where(d[idx, axis] >= 0, 0, 1)
    g = CUBE_FACES[new_face]
    m = g[:, 5] * d[idx, g[:, 4]]
    s2 = g[:, 1] * d[idx, g[:, 0]]
    t2 = g[:, 3] * d[idx, g[:, 2]]
    return new_face, ((s2 + m) * n) // (2 * m), ((t2 + m) * n) // (2 * m)


class _Taps:
    """Texels read per pixel: global texel index (N, K) (-1: none), weight (N, K) and the
    weight's derivatives by s and t (N, K), K columns appended per level."""

    def __init__(self, n):
        self.index = np.zeros((n, 0), np.int64)
        self.weight = np.zeros((n, 0))
        self.ds = np.zeros((n, 0))
        self.dt = np.zeros((n, 0))

    def add(self, index, weight, ds, dt):
        self.index = np.concatenate([self.index, index], axis=1)
        self.weight = np.concatenate([self.weight, weight], axis=1)
        self.ds = np.concatenate([self.ds, ds], axis=1)
        self.dt = np.concatenate([self.dt, dt], axis=1)


def _level_geometry(shapes, faces, tex_batch):
    """Per level: first global texel index, and texels per image (face)."""
    offsets, first = [], 0
    for h, w in shapes:
        offsets.append(first)
        first += tex_batch * faces * h * w
    return np.array(offsets, np.int64), first


def _bilinear(level, s, t, image, shapes, offsets, boundary, face=None):
    """Bilinear taps at ``level`` (N,) per pixel: four columns (twelve for a cube map,
    whose corner tap is the mean of the three texels around the corner)."""
    hw = np.array(shapes, np.int64)
    h, w = hw[level, 0], hw[level, 1]
    x = s * w - 0.5
    y = t * h - 0.5
    i0 = np.floor(x).astype(np.int64)
    j0 = np.floor(y).astype(np.int64)
    fx, fy = x - i0, y - j0
    n = len(s)
    ii = np.stack([i0, i0 + 1, i0, i0 + 1], axis=1)
    jj = np.stack([j0, j0, j0 + 1, j0 + 1], axis=1)
    wx = np.stack([1 - fx, fx, 1 - fx, fx], axis=1)
    wy = np.stack([1 - fy, 1 - fy, fy, fy], axis=1)
    dwx = np.stack([-np.ones(n), np.ones(n), -np.ones(n), np.ones(n)], axis=1)
    dwy = np.stack([-np.ones(n), -np.ones(n), np.ones(n), np.ones(n)], axis=1)
    weight = wx * wy
    ds = dwx * wy * w[:, None]
    dt = wx * dwy * h[:, None]
    H, W = h[:, None], w[:, None]
    base = offsets[level][:, None]
    if boundary == "cube":
        fc = np.repeat(face[:, None], 4, axis=1)
        out_i = (ii < 0) | (ii >= W)
        out_j = (jj < 0) | (jj >= H)
        one = out_i ^ out_j
        nf, ni, nj = fc.copy(), ii.copy(), jj.copy()
        if one.any():
            r = _cube_neighbour(fc[one], ii[one], jj[one], np.broadcast_to(W, ii.shape)[one])
            nf[one], ni[one], nj[one] = r
        idx = base + ((image[:, None] * 6 + nf) * H + nj) * W + ni
        corner = out_i & out_j
        share = np.where(corner, 0.0, 1.0)
        index = np.stack([idx, idx, idx], axis=2)          # (N, 4, 3)
        shares = np.zeros((n, 4, 3))
        shares[..., 0] = share
        rows = np.nonzero(corner.any(axis=1))[0]
        for p in rows:
            k = int(np.nonzero(corner[p])[0][0])
            others = [q for q in range(4) if q != k]
            index[p, k] = idx[p, others]
            shares[p, k] = 1.0 / 3.0
        weight = (weight[..., None] * shares).reshape(n, 12)
        ds = (ds[..., None] * shares).reshape(n, 12)
        dt = (dt[..., None] * shares).reshape(n, 12)
        return index.reshape(n, 12), weight, ds, dt
    if boundary == "wrap":
        ii, jj = ii % W, jj % H
        valid = np.ones_like(ii, bool)
    elif boundary == "clamp":
        ii, jj = np.clip(ii, 0, W - 1), np.clip(jj, 0, H - 1)
        valid = np.ones_like(ii, bool)
    else:  # zero
        valid = (ii >= 0) & (ii < W) & (jj >= 0) & (jj < H)
    idx = np.where(valid, base + (image[:, None] * H + jj) * W + ii, -1)
    return idx, np.where(valid, weight, 0.0), np.where(valid, ds, 0.0), np.where(valid, dt, 0.0)


def _nearest(s, t, image, shapes, boundary, face=None):
    h, w = shapes[0]
    i = np.floor(s * w).astype(np.int64)
    j = np.floor(t * h).astype(np.int64)
    if boundary == "cube":
        i, j = np.clip(i, 0, w - 1), np.clip(j, 0, h - 1)
        return ((image * 6 + face) * h + j) * w + i
    if boundary == "wrap":
        i, j = i % w, j % h
    elif boundary == "clamp":
        i, j = np.clip(i, 0, w - 1), np.clip(j, 0, h - 1)
    else:
        valid = (i >= 0) & (i < w) & (j >= 0) & (j < h)
        return np.where(valid, (image * h + j) * w + i, -1)
    return (image * h + j) * w + i


def _level_of(args: TextureArgs, uv, da, bias, face_data):
    """Per pixel: the unclamped level and its derivatives by uv_da (N, 4|6) and by the cube
    direction (N, 3) (zeros for 2-D), seed 003's lenMajorSqr."""
    n = len(uv)
    dda = np.zeros((n, 0 if da is None else da.shape[1]))
    duv = np.zeros((n, 3))
    if da is None:
        level = np.zeros(n)
    else:
        h0, w0 = args.shapes[0]
        if args.cube:
            face, _s, _t, _ds, _dt, ok = face_data
            f = CUBE_FACES[face]
            idx = np.arange(n)
            m = f[:, 5] * uv[idx, f[:, 4]]
            m = np.where(ok, m, 1.0)
            ps = f[:, 1] * uv[idx, f[:, 0]]
            pt = f[:, 3] * uv[idx, f[:, 2]]
            # derivatives of (s_c, t_c, m) by X and Y
            psx, psy = f[:, 1] * da[idx, 2 * f[:, 0]], f[:, 1] * da[idx, 2 * f[:, 0] + 1]
            ptx, pty = f[:, 3] * da[idx, 2 * f[:, 2]], f[:, 3] * da[idx, 2 * f[:, 2] + 1]
            mx, my = f[:, 5] * da[idx, 2 * f[:, 4]], f[:, 5] * da[idx, 2 * f[:, 4] + 1]
            k = w0 / 2.0
            a = k * (psx / m - ps * mx / m ** 2)
            b = k * (psy / m - ps * my / m ** 2)
            c = k * (ptx / m - pt * mx / m ** 2)
            d = k * (pty / m - pt * my / m ** 2)
        else:
            a, b = da[:, 0] * w0, da[:, 1] * w0
            c, d = da[:, 2] * h0, da[:, 3] * h0
        A = a * a + c * c
        B = b * b + d * d
        C = a * b + c * d
        half = (A - B) / 2.0
        l2a = np.sqrt(half * half + C * C)
        major = (A + B) / 2.0 + l2a
        positive = major > 0
        safe = np.where(positive, major, 1.0)
        with np.errstate(divide="ignore"):
            level = np.where(positive, 0.5 * np.log2(safe), -np.inf)
        # d level / d(A, B, C); at l2a = 0 (isotropic footprint) the terms in l2a are taken 0
        inv = np.where(l2a > 0, 1.0 / np.where(l2a > 0, l2a, 1.0), 0.0)
        g = np.where(positive, 1.0 / (2.0 * LN2 * safe), 0.0)
        gA = g * (0.5 + half * inv / 2.0)
        gB = g * (0.5 - half * inv / 2.0)
        gC = g * C * inv
        ga = 2 * a * gA + b * gC
        gb = 2 * b * gB + a * gC
        gc = 2 * c * gA + d * gC
        gd = 2 * d * gB + c * gC
        if args.cube:
            face, _s, _t, _ds, _dt, ok = face_data
            gk = np.where(ok, k, 0.0)
            # through a = k (psx/m - ps mx/m^2) etc.: by psx.., by ps, pt, m
            g_psx, g_psy = ga * gk / m, gb * gk / m
            g_ptx, g_pty = gc * gk / m, gd * gk / m
            g_mx = -gk * (ga * ps + gc * pt) / m ** 2
            g_my = -gk * (gb * ps + gd * pt) / m ** 2
            g_ps = -gk * (ga * mx + gb * my) / m ** 2
            g_pt = -gk * (gc * mx + gd * my) / m ** 2
            g_m = gk * (-(ga * psx + gb * psy + gc * ptx + gd * pty) / m ** 2
                        + 2 * ((ga * ps + gc * pt) * mx + (gb * ps + gd * pt) * my) / m ** 3)
            for col, sigma, gx, gy, gv in ((0, 1, g_psx, g_psy, g_ps), (2, 3, g_ptx, g_pty, g_pt),
                                           (4, 5, g_mx, g_my, g_m)):
                axis = f[:, col]
                sg = f[:, sigma]
                np.add.at(dda, (idx, 2 * axis), sg * gx)
                np.add.at(dda, (idx, 2 * axis + 1), sg * gy)
                np.add.at(duv, (idx, axis), sg * gv)
        else:
            dda = np.stack([ga * w0, gb * w0, gc * h0, gd * h0], axis=1)
    if bias is not None:
        level = level + bias
    return level, dda, duv


def _evaluate(args: TextureArgs, levels, grad_out=None, touch=False):
    """Forward (and, with grad_out, backward) on flattened pixels. ``touch``: every texel
    read counts with weight 1 (for error bounds: sums over the pixels reading a texel)."""
    cube = args.cube
    batch, height, width, _ = args.uv.shape
    n = batch * height * width
    channels = args.channels
    uv = args.uv.reshape(n, -1)
    da = None if args.uv_da is None else args.uv_da.reshape(n, -1)
    bias = None if args.bias is None else args.bias.reshape(n)
    image = np.arange(n) // (height * width)
    tex_batch = args.tex.shape[0]
    if tex_batch == 1:
        image = np.zeros_like(image)
    faces = 6 if cube else 1
    offsets, total = _level_geometry(args.shapes, faces, tex_batch)
    flat = np.concatenate([lv.reshape(-1, channels) for lv in levels], axis=0)

    face_data = None
    if cube:
        face_data = _cube_face(uv)
        face, s, t, ds_duv, dt_duv, ok = face_data
    else:
        face, ok = None, np.ones(n, bool)
        s, t = uv[:, 0], uv[:, 1]

    taps = _Taps(n)
    level = np.zeros(n)
    frac = np.zeros(n)
    live_level = np.zeros(n, bool)
    mode = args.filter_mode
    if mode == "nearest":
        idx = _nearest(s, t, image, args.shapes, args.boundary_mode, face)
        taps.add(idx[:, None], np.where(idx >= 0, 1.0, 0.0)[:, None], np.zeros((n, 1)),
                 np.zeros((n, 1)))
    elif mode == "linear":
        taps.add(*_bilinear(np.zeros(n, np.int64), s, t, image, args.shapes, offsets,
                            args.boundary_mode, face))
    else:
        top = args.levels - 1
        raw, dlevel_dda, dlevel_duv = _level_of(args, uv, da, bias, face_data)
        level = np.clip(raw, 0.0, top)
        if mode == "linear-mipmap-nearest":
            l0 = np.floor(level + 0.5).astype(np.int64)
            l0 = np.minimum(l0, top)
            taps.add(*_bilinear(l0, s, t, image, args.shapes, offsets, args.boundary_mode, face))
        else:
            l0 = np.minimum(np.floor(level).astype(np.int64), top)
            frac = level - l0
            l1 = np.minimum(l0 + 1, top)
            live_level = (raw > 0) & (raw < top)
            t0 = _bilinear(l0, s, t, image, args.shapes, offsets, args.boundary_mode, face)
            t1 = _bilinear(l1, s, t, image, args.shapes, offsets, args.boundary_mode, face)
            raw0, raw1 = t0[1], t1[1]
            w0, w1 = (1 - frac)[:, None], frac[:, None]
            taps.add(t0[0], t0[1] * w0, t0[2] * w0, t0[3] * w0)
            taps.add(t1[0], t1[1] * w1, t1[2] * w1, t1[3] * w1)
    valid = taps.index >= 0
    if cube:
        taps.weight[~ok] = 0.0
    if touch:
        taps.weight = np.where(valid & ((taps.weight != 0) | (np.abs(taps.ds) + np.abs(taps.dt)
                                                              > 0)), 1.0, 0.0)
    gathered = np.where(valid[..., None], flat[np.where(valid, taps.index, 0)], 0.0)  # (N,K,C)
    out = np.einsum("nk,nkc->nc", taps.weight, gathered).reshape(batch, height, width, channels)
    if grad_out is None:
        return out, None

    g = grad_out.reshape(n, channels)
    # texture
    grad_flat = np.zeros((total, channels))
    contrib = taps.weight[..., None] * g[:, None, :]
    for c in range(channels):
        grad_flat[:, c] = np.bincount(np.where(valid, taps.index, 0).ravel(),
                                      weights=np.where(valid, contrib[..., c], 0.0).ravel(),
                                      minlength=total)
    grad_levels = []
    for k, (h, w) in enumerate(args.shapes):
        part = grad_flat[offsets[k]:offsets[k] + tex_batch * faces * h * w]
        grad_levels.append(part.reshape(levels[k].shape))
    # coordinates
    tg = np.einsum("nkc,nc->nk", gathered, g)                  # dL/d weight per tap
    gs = (taps.ds * tg).sum(axis=1)
    gt = (taps.dt * tg).sum(axis=1)
    grad_da = grad_bias = None
    grad_level = np.zeros(n)
    if mode == "linear-mipmap-linear":
        # d out / d frac = sample(l1) - sample(l0)
        base_w = np.concatenate([-raw0, raw1], axis=1)
        if cube:
            base_w[~ok] = 0.0
        grad_level = np.where(live_level, (base_w * tg).sum(axis=1), 0.0)
        if args.uv_da is not None:
            grad_da = (grad_level[:, None] * dlevel_dda).reshape(args.uv_da.shape)
        if args.bias is not None:
            grad_bias = grad_level.reshape(args.bias.shape)
    if args.uv_da is not None and grad_da is None:
        grad_da = np.zeros(args.uv_da.shape)
    if args.bias is not None and grad_bias is None:
        grad_bias = np.zeros(args.bias.shape)
    if cube:
        grad_uv = gs[:, None] * ds_duv + gt[:, None] * dt_duv
        if mode == "linear-mipmap-linear" and args.uv_da is not None:
            grad_uv = grad_uv + grad_level[:, None] * dlevel_duv
        grad_uv[~ok] = 0.0
    else:
        grad_uv = np.stack([gs, gt], axis=1)
    if mode == "nearest":
        grad_uv = np.zeros_like(grad_uv)
    grads = (grad_levels, grad_uv.reshape(args.uv.shape), grad_da, grad_bias)
    return out, grads


def lookup_geometry(args: TextureArgs) -> dict:
    """Per pixel (flattened, float64): ``s``, ``t`` (face coordinates for a cube map),
    ``face`` (cube; else zeros), ``raw_level`` (before clamping; 0 without mipmaps) and
    ``level`` (clamped to the pyramid). For tests and error analysis."""
    n = int(np.prod(args.uv.shape[:3]))
    uv = args.uv.reshape(n, -1).astype(np.float64)
    da = None if args.uv_da is None else args.uv_da.reshape(n, -1).astype(np.float64)
    bias = None if args.bias is None else args.bias.reshape(n).astype(np.float64)
    if args.cube:
        face_data = _cube_face(uv)
        face, s, t = face_data[:3]
    else:
        face_data, face, s, t = None, np.zeros(n, np.int64), uv[:, 0], uv[:, 1]
    raw = np.zeros(n)
    if args.mipmapped:
        raw = _level_of(args, uv, da, bias, face_data)[0]
    return {"s": s, "t": t, "face": face, "raw_level": raw,
            "level": np.clip(raw, 0.0, args.levels - 1)}


def texel_sums(saved: TextureSaved, values) -> np.ndarray:
    """Per texel of the base (tex's shape): the sum of ``values`` (B, H, W, C) over the
    pixels that read the texel, at any level, with weight 1, a built pyramid's levels pulled
    back through its (nonnegative) box filter. For error bounds."""
    args = saved.args
    values = np.asarray(values, np.float64).reshape(args.uv.shape[:3] + (args.channels,))
    _, (grad_levels, *_rest) = _evaluate(args, saved.levels, values, touch=True)
    if args.levels > 1 and (args.mip is None or args.own_mips):
        return mips_backward(grad_levels, args.shapes)
    return grad_levels[0]


def forward(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None):
    """Filtered texture lookups in float64 (see the module docstring for the layouts).

    Returns ``(out, saved)``: out (B, H, W, C) float64, saved a :class:`TextureSaved`.
    A cube-map direction (0, 0, 0) samples nothing (0, zero gradients).
    """
    args = check_arguments(tex, uv, uv_da, mip_level_bias, mip, filter_mode, boundary_mode,
                           max_mip_level)
    if args.levels == 1:
        levels = [args.tex]
    elif args.mip is not None:
        levels = [args.tex, *args.mip[:args.levels - 1]]
    else:
        levels = [args.tex, *build_mips(args.tex, args.shapes)]
    out, _ = _evaluate(args, levels)
    return out, TextureSaved(args, levels)


def backward(saved: TextureSaved, grad_out):
    """Gradients of :func:`forward`.

    Returns ``(grad_tex, grad_uv, grad_uv_da, grad_mip_level_bias, grad_mip)`` in float64:
    grad_tex of tex's shape (a built pyramid's level gradients pulled back into the base
    through its box filter; summed over the batch where tex broadcast); grad_uv of uv's;
    grad_uv_da / grad_mip_level_bias of theirs, or None when not given (zeros unless the
    mode is linear-mipmap-linear: the other modes are piecewise constant in the level);
    grad_mip a list of the user's mip levels' gradients, or None without ``mip`` (or with
    :class:`OwnMips`, whose gradients go into grad_tex).
    """
    args = saved.args
    want = args.uv.shape[:3] + (args.channels,)
    grad_out = layout.image("grad_out", grad_out, shape=want)
    _, (grad_levels, grad_uv, grad_da, grad_bias) = _evaluate(args, saved.levels, grad_out)
    grad_mip = None
    if args.mip is not None and not args.own_mips:
        grad_tex = grad_levels[0]
        grad_mip = list(grad_levels[1:]) + [np.zeros(m.shape) for m in args.mip[args.levels - 1:]]
    elif args.levels == 1:
        grad_tex = grad_levels[0]
    else:
        grad_tex = mips_backward(grad_levels, args.shapes)
    return grad_tex, grad_uv, grad_da, grad_bias, grad_mip
