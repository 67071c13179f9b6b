"""The texture op's float64 reference core: the mip pyramid and filtered lookups, forward
and backward, in NumPy (docs/differentiable.md, "Texture").

The core signature of :mod:`glraster.diff.op` (the same as the GPU core,
:mod:`glraster.diff.texture`): ``forward(tex, uv, uv_da, mip_level_bias, *mip, filter_mode,
boundary_mode, max_mip_level, own_mips, ctx) -> ((out,), saved)`` on arrays checked by
:func:`glraster.diff.texture_args.check` (layouts there), and ``backward(saved, grad_out,
needs=None) -> (grad_tex, grad_uv, grad_uv_da, grad_mip_level_bias, *grad_mip)``.

The level (mipmap modes) is nvdiffrast's: with J the Jacobian of the texel position
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
from dataclasses import dataclass

import numpy as np

from glraster import validate
from glraster.diff.texture_args import TextureArgs, TextureSaved, level_shapes, wanted

__all__ = ["backward", "build_mips", "forward", "level_shapes", "lookup_geometry",
           "mips_backward", "texel_sums"]

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
    direction (N, 3) (zeros for 2-D), the squared length of the major axis."""
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



# --------------------------------------------------------------------------- the lookup


def _pixels(args: TextureArgs):
    """Flattened per-pixel inputs: uv (N, 2|3), uv_da (N, 4|6) or None, bias (N,) or None
    and the texture image each pixel reads (N,) (0 where tex broadcasts)."""
    batch, height, width, _ = args.uv.shape
    n = batch * height * width
    uv = args.uv.reshape(n, -1)
    da = None if args.uv_da is None else args.uv_da.reshape(n, -1)
    bias = None if args.bias is None else args.bias.reshape(n)
    image = np.arange(n) // (height * width)
    if args.tex.shape[0] == 1:
        image = np.zeros_like(image)
    return uv, da, bias, image


@dataclass
class _Lookup:
    """The texels every pixel reads and what the gradients need (N flattened pixels).

    taps        : the texels read (global index over every level), weights, d weight/ds,dt
    total       : texels over every level
    ok          : (N,) bool, the direction samples (cube; all True in 2-D)
    face_data   : :func:`_cube_face`'s result (cube), else None
    level_weights : linear-mipmap-linear: the two levels' bilinear weights (N, K), (N, K)
    live_level  : (N,) bool, the level is inside (0, top), so that its gradient flows
    dlevel_dda, dlevel_duv : d level / d uv_da (N, 4|6), d level / d direction (N, 3)
    """

    taps: _Taps
    total: int
    ok: np.ndarray
    face_data: tuple | None
    level_weights: tuple | None = None
    live_level: np.ndarray | None = None
    dlevel_dda: np.ndarray | None = None
    dlevel_duv: np.ndarray | None = None


def _lookup(args: TextureArgs, touch: bool = False) -> _Lookup:
    """The taps of every pixel for ``args.filter_mode``. ``touch``: every texel read counts
    with weight 1 (for error bounds: sums over the pixels reading a texel)."""
    uv, da, bias, image = _pixels(args)
    n = len(uv)
    offsets, total = _level_geometry(args.shapes, 6 if args.cube else 1, args.tex.shape[0])
    if args.cube:
        face_data = _cube_face(uv)
        face, s, t, _, _, ok = face_data
    else:
        face_data, face, ok = None, None, np.ones(n, bool)
        s, t = uv[:, 0], uv[:, 1]
    lk = _Lookup(_Taps(n), total, ok, face_data)

    def bilinear(level):
        return _bilinear(level, s, t, image, args.shapes, offsets, args.boundary_mode, face)

    if args.filter_mode == "nearest":
        idx = _nearest(s, t, image, args.shapes, args.boundary_mode, face)
        lk.taps.add(idx[:, None], np.where(idx >= 0, 1.0, 0.0)[:, None], np.zeros((n, 1)),
                    np.zeros((n, 1)))
    elif args.filter_mode == "linear":
        lk.taps.add(*bilinear(np.zeros(n, np.int64)))
    else:
        _mip_taps(args, lk, bilinear, uv, da, bias)
    taps = lk.taps
    if args.cube:
        taps.weight[~ok] = 0.0
    if touch:
        read = (taps.weight != 0) | (np.abs(taps.ds) + np.abs(taps.dt) > 0)
        taps.weight = np.where((taps.index >= 0) & read, 1.0, 0.0)
    return lk


def _mip_taps(args: TextureArgs, lk: _Lookup, bilinear, uv, da, bias) -> None:
    """The mipmap modes' taps at the pixel's level, clamped to the pyramid: the nearest
    level's bilinear taps, or both neighbouring levels' blended by the level's fraction."""
    top = args.levels - 1
    raw, lk.dlevel_dda, lk.dlevel_duv = _level_of(args, uv, da, bias, lk.face_data)
    level = np.clip(raw, 0.0, top)
    if args.filter_mode == "linear-mipmap-nearest":
        lk.taps.add(*bilinear(np.minimum(np.floor(level + 0.5).astype(np.int64), top)))
        return
    l0 = np.minimum(np.floor(level).astype(np.int64), top)
    frac = level - l0
    lk.live_level = (raw > 0) & (raw < top)
    t0, t1 = bilinear(l0), bilinear(np.minimum(l0 + 1, top))
    lk.level_weights = (t0[1], t1[1])
    for (index, weight, ds, dt), w in ((t0, (1 - frac)[:, None]), (t1, frac[:, None])):
        lk.taps.add(index, weight * w, ds * w, dt * w)


def _gathered(lk: _Lookup, levels, channels: int) -> np.ndarray:
    """(N, K, C) the values of the texels each pixel reads (0 for no texel)."""
    flat = np.concatenate([lv.reshape(-1, channels) for lv in levels], axis=0)
    valid = lk.taps.index >= 0
    return np.where(valid[..., None], flat[np.where(valid, lk.taps.index, 0)], 0.0)


def _texel_gradients(args: TextureArgs, lk: _Lookup, g: np.ndarray, levels) -> list:
    """dL/d every level read (base first, each of its level's shape) from g (N, C):
    each tap's weight times g, summed per texel."""
    taps = lk.taps
    valid = taps.index >= 0
    index = np.where(valid, taps.index, 0).ravel()
    contrib = taps.weight[..., None] * g[:, None, :]
    grad_flat = np.zeros((lk.total, args.channels))
    for c in range(args.channels):
        grad_flat[:, c] = np.bincount(index, weights=np.where(valid, contrib[..., c], 0.0).ravel(),
                                      minlength=lk.total)
    out, first = [], 0
    for level in levels:
        out.append(grad_flat[first:first + level.size // args.channels].reshape(level.shape))
        first += level.size // args.channels
    return out


def _level_gradient(args: TextureArgs, lk: _Lookup, tap_grads: np.ndarray) -> np.ndarray:
    """dL/d level (N,) in linear-mipmap-linear: d out / d frac = sample(l1) - sample(l0),
    zero where the level is clamped."""
    raw0, raw1 = lk.level_weights
    base_w = np.concatenate([-raw0, raw1], axis=1)
    if args.cube:
        base_w[~lk.ok] = 0.0
    return np.where(lk.live_level, (base_w * tap_grads).sum(axis=1), 0.0)


def _coordinate_gradients(args: TextureArgs, lk: _Lookup, gathered, g, want):
    """(grad_uv, grad_uv_da, grad_mip_level_bias) from g (N, C), each None where not
    wanted (``want``: three bools) or not given; uv_da and the bias have zero gradients
    except in linear-mipmap-linear (the other modes are piecewise constant in the level)."""
    want_uv, want_da, want_bias = want
    want_da &= args.uv_da is not None
    want_bias &= args.bias is not None
    tap_grads = np.einsum("nkc,nc->nk", gathered, g)          # dL/d weight per tap
    trilinear = args.filter_mode == "linear-mipmap-linear"
    level_into_uv = args.cube and args.uv_da is not None
    grad_level = None
    if trilinear and (want_da or want_bias or (want_uv and level_into_uv)):
        grad_level = _level_gradient(args, lk, tap_grads)
    grad_da = grad_bias = grad_uv = None
    if want_da:
        grad_da = (np.zeros(args.uv_da.shape) if grad_level is None
                   else (grad_level[:, None] * lk.dlevel_dda).reshape(args.uv_da.shape))
    if want_bias:
        grad_bias = (np.zeros(args.bias.shape) if grad_level is None
                     else grad_level.reshape(args.bias.shape))
    if want_uv and args.filter_mode == "nearest":
        grad_uv = np.zeros(args.uv.shape)
    elif want_uv:
        gs = (lk.taps.ds * tap_grads).sum(axis=1)
        gt = (lk.taps.dt * tap_grads).sum(axis=1)
        if args.cube:
            _, _, _, ds_duv, dt_duv, ok = lk.face_data
            grad_uv = gs[:, None] * ds_duv + gt[:, None] * dt_duv
            if grad_level is not None:
                grad_uv = grad_uv + grad_level[:, None] * lk.dlevel_duv
            grad_uv[~ok] = 0.0
        else:
            grad_uv = np.stack([gs, gt], axis=1)
        grad_uv = grad_uv.reshape(args.uv.shape)
    return grad_uv, grad_da, grad_bias


# --------------------------------------------------------------------------- the core


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
    values = np.asarray(values, np.float64).reshape(-1, args.channels)
    grad_levels = _texel_gradients(args, _lookup(args, touch=True), values, saved.levels)
    return mips_backward(grad_levels, args.shapes) if args.pulls_pyramid else grad_levels[0]


def _levels(args: TextureArgs) -> list:
    """Every level read, base first: the given ones, or the pyramid built in float64."""
    if args.levels == 1:
        return [args.tex]
    if args.mip is not None:
        return [args.tex, *args.mip[:args.levels - 1]]
    return [args.tex, *build_mips(args.tex, args.shapes)]


def forward(tex, uv, uv_da=None, mip_level_bias=None, *mip, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None, own_mips=False, ctx=None):
    """Filtered texture lookups in float64, on checked arrays (layouts and arguments:
    :mod:`glraster.diff.texture_args`; ``ctx`` is ignored).

    Returns ``((out,), saved)``: out (B, H, W, C) float64, saved a
    :class:`~glraster.diff.texture_args.TextureSaved` holding every level read.
    A cube-map direction (0, 0, 0) samples nothing (0, zero gradients).
    """
    args = TextureArgs.of(tex, uv, uv_da, mip_level_bias, mip, filter_mode, boundary_mode,
                          max_mip_level, own_mips)
    levels = _levels(args)
    lk = _lookup(args)
    out = np.einsum("nk,nkc->nc", lk.taps.weight, _gathered(lk, levels, args.channels))
    return (out.reshape(args.uv.shape[:3] + (args.channels,)),), TextureSaved(args, levels)


def backward(saved: TextureSaved, grad_out, *, needs=None, deterministic: bool = False,
             accumulate: str | None = None):
    """Gradients of :func:`forward` in float64.

    Args:
        saved: the second value :func:`forward` returned.
        grad_out: (B, H, W, C) dL/d out, or None (zero).
        needs: None (all) or one bool per input (tex, uv, uv_da, mip_level_bias, *mip): the
            gradients to compute; the texel sums are skipped when neither tex nor a mip
            level needs one, the coordinates' when uv, uv_da and the bias need none.
        deterministic, accumulate: the GPU core's options, accepted for the one signature
            (the reference always sums in a fixed order in float64).

    Returns:
        ``(grad_tex, grad_uv, grad_uv_da, grad_mip_level_bias, *grad_mip)``, float64, None
        where not wanted or not given: grad_tex of tex's shape (a built pyramid's or own
        mips' level gradients pulled back into the base through its box filter; summed
        over the batch where tex broadcast); grad_uv_da / grad_mip_level_bias zeros unless
        the mode is linear-mipmap-linear; each of a user's mip levels its own gradient
        (zeros for levels beyond ``max_mip_level``; None without mipmapping, or with
        ``own_mips``).
    """
    args = saved.args
    mips = len(args.mip or ())
    want = wanted(needs, 4 + mips)
    shape = args.uv.shape[:3] + (args.channels,)
    grad_out = (np.zeros(shape) if grad_out is None
                else validate.image("grad_out", grad_out, shape=shape))
    g = grad_out.reshape(-1, args.channels)
    lk = _lookup(args)
    grad_tex, grad_mip = None, [None] * mips
    user = len(args.user_mips) if args.mipmapped else 0
    if want[0] or any(want[4:4 + user]):
        grad_levels = _texel_gradients(args, lk, g, saved.levels)
        if want[0]:
            grad_tex = (mips_backward(grad_levels, args.shapes) if args.pulls_pyramid
                        else grad_levels[0])
        for k in range(user):
            if want[4 + k]:
                grad_mip[k] = (grad_levels[k + 1] if k + 1 < args.levels
                               else np.zeros(args.mip[k].shape))
    grad_coords = (None, None, None)
    if any(want[1:4]):
        gathered = _gathered(lk, saved.levels, args.channels)
        grad_coords = _coordinate_gradients(args, lk, gathered, g, want[1:4])
    return (grad_tex, *grad_coords, *grad_mip)
