"""The float64 texture reference (glraster.diff.texture_reference, called through
glraster.diff.ops.TEXTURE as a front end calls it) against central
differences, the level formula against an eigenvalue solver, the pyramid's box filter, the
cube map's seams, and the argument checks (no OpenGL).

Central differences: per entry, 4-point for uv, uv_da and the bias (step 1e-6), 2-point
for tex and the mip levels (step 1: the output is linear in them); relative error
|analytic - numeric| / max(|numeric|, 1e-3 max|numeric|) <= 1e-6. A step moves a texel
position by < 2e-5 texels and a level by < 2e-4, so only pixels whose texel positions are
>= 1e-3 texels from a texel boundary at every level they read, whose level fraction is
>= 1e-3 from 0 and 1 (from 0.5 for linear-mipmap-nearest) and whose level is inside
(0, top) are compared (``safe``; at least 30% of the pixels, asserted); elsewhere the function has kinks. Along one coordinate the bilinear filter is linear
inside a texel cell, so the truncation error is that of the level's log2 (~h^4 / |uv_da|^5)
and of the cube projection; rounding is ~1e-16 / h relative.
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff import texture_args as ta
from glraster.diff import texture_reference as tr
from glraster.diff.ops import TEXTURE
from glraster.errors import ArgumentError

REL = 1e-6
MARGIN = 1e-3
MODES_2D = ["nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear"]
BOUNDARIES_2D = ["wrap", "clamp", "zero"]


# --------------------------------------------------------------------------- the op


def texture_forward(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
                    boundary_mode="wrap", max_mip_level=None, *, own_mips=False,
                    dtype=np.float64, ctx=None):
    """The texture op as a front end runs it: TEXTURE.check, then the core of ``dtype``
    (float64: the reference, float32: the GPU); returns (out, saved)."""
    if isinstance(tex, np.ndarray) and np.issubdtype(tex.dtype, np.floating):
        tex = tex.astype(dtype)
    inputs, params = TEXTURE.check(tex, uv, uv_da, mip_level_bias, *(mip or ()),
                                   filter_mode=filter_mode, boundary_mode=boundary_mode,
                                   max_mip_level=max_mip_level, own_mips=own_mips, ctx=ctx)
    (out,), saved = TEXTURE.core(dtype).forward(*inputs, **params)
    return out, saved


def texture_backward(saved, grad_out, **options):
    """(grad_tex, grad_uv, grad_uv_da, grad_mip_level_bias, grad_mip) from the core that
    made ``saved``; grad_mip a list, None without mip levels."""
    grads = TEXTURE.core(saved.args.tex.dtype).backward(saved, grad_out, **options)
    return (*grads[:4], list(grads[4:]) or None)


# --------------------------------------------------------------------------- inputs


def make_inputs(seed, boundary, *, batch=2, image=(5, 6), tex_size=(9, 12), channels=3,
                tex_batch=1, with_da=True, with_bias=True, level_range=None):
    """tex, uv, uv_da, bias with levels spread over (0.2, top - 0.2) and anisotropic
    footprints (ratio 0.3 .. 0.9: away from the isotropic point where the largest
    eigenvalue is not differentiable)."""
    rng = np.random.default_rng(seed)
    shape = (batch,) + image
    if boundary == "cube":
        n = tex_size[0]
        tex = rng.normal(size=(tex_batch, 6, n, n, channels))
        uv = rng.normal(size=shape + (3,))
        h = w = n
    else:
        h, w = tex_size
        tex = rng.normal(size=(tex_batch, h, w, channels))
        uv = rng.uniform(-0.3, 1.3, size=shape + (2,))
    top = len(ta.level_shapes(h, w)) - 1
    lo, hi = level_range or (0.2, top - 0.2)
    lam = rng.uniform(lo, hi, size=shape)
    theta = rng.uniform(0, 2 * np.pi, size=shape)
    ratio = rng.uniform(0.3, 0.9, size=shape)
    big, small = 2.0 ** lam, 2.0 ** lam * ratio
    c, s = np.cos(theta), np.sin(theta)
    # J = R(theta) diag(big, small) in texels per pixel
    j = np.stack([c * big, -s * small, s * big, c * small], axis=-1)
    if boundary == "cube":
        # derivatives of the direction: the texel-space footprint scaled back to the face
        # (half a face is N/2 texels) along two tangents of the direction
        d = uv / np.linalg.norm(uv, axis=-1, keepdims=True)
        t1 = np.cross(d, rng.normal(size=d.shape))
        t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
        t2 = np.cross(d, t1)
        scale = np.linalg.norm(uv, axis=-1, keepdims=True) * 2.0 / n
        dx = (j[..., 0:1] * t1 + j[..., 2:3] * t2) * scale
        dy = (j[..., 1:2] * t1 + j[..., 3:4] * t2) * scale
        da = np.stack([dx, dy], axis=-1).reshape(shape + (6,))
    else:
        da = j / np.array([w, w, h, h])
    bias = rng.uniform(-0.3, 0.3, size=shape)
    return tex, uv, (da if with_da else None), (bias if with_bias else None)


def _cell_margin(pos):
    return np.abs(pos - np.round(pos))


def safe(args: ta.TextureArgs, margin=MARGIN):
    """Flattened mask of pixels away from every kink of the lookup (module docstring)."""
    geo = tr.lookup_geometry(args)
    s, t, raw, level = geo["s"], geo["t"], geo["raw_level"], geo["level"]
    shapes = np.array(args.shapes)
    top = args.levels - 1
    ok = np.ones(len(s), bool)
    mode = args.filter_mode
    if mode == "nearest":
        used = [np.zeros(len(s), np.int64)]
        offset = 0.0
    else:
        offset = 0.5
        if mode == "linear":
            used = [np.zeros(len(s), np.int64)]
        elif mode == "linear-mipmap-nearest":
            used = [np.minimum(np.floor(level + 0.5).astype(np.int64), top)]
            ok &= np.abs(level - np.floor(level) - 0.5) > margin
        else:
            l0 = np.minimum(np.floor(level).astype(np.int64), top)
            used = [l0, np.minimum(l0 + 1, top)]
            f = level - np.floor(level)
            ok &= (raw > margin) & (raw < top - margin) & (f > margin) & (f < 1 - margin)
    for lv in used:
        h, w = shapes[lv, 0], shapes[lv, 1]
        ok &= _cell_margin(s * w - offset) > margin
        ok &= _cell_margin(t * h - offset) > margin
    if args.cube:
        d = np.abs(args.uv.reshape(len(s), 3))
        top2 = np.sort(d, axis=1)
        ok &= top2[:, 1] < (1 - margin) * top2[:, 2]
    return ok


# --------------------------------------------------------------------------- differences


def _loss_pixels(out, g):
    return (out * g).sum(axis=-1).reshape(-1)


def check_gradients(tex, uv, da, bias, mode, boundary, mip=None, max_mip_level=None, seed=0):
    """Every derivative against central differences; returns {name: (max rel error, n)}."""
    rng = np.random.default_rng(seed + 100)
    run = lambda *a, mip_=mip: texture_forward(*a, mip_, mode, boundary, max_mip_level)[0]
    out, saved = texture_forward(tex, uv, da, bias, mip, mode, boundary, max_mip_level)
    g = rng.normal(size=out.shape)
    grad_tex, grad_uv, grad_da, grad_bias, grad_mip = texture_backward(saved, g)
    mask = safe(saved.args)
    assert mask.sum() >= 0.3 * mask.size, f"only {mask.sum()} of {mask.size} pixels are safe"
    report = {}

    def compare(name, analytic, numeric):
        analytic, numeric = np.asarray(analytic), np.asarray(numeric)
        scale = max(np.abs(numeric).max(), 1e-300)
        err = np.abs(analytic - numeric) / np.maximum(np.abs(numeric), 1e-3 * scale)
        report[name] = (float(err.max()), int(err.size))
        assert np.abs(numeric).max() > 0, f"{name}: the gradient is all zero"
        assert err.max() <= REL, f"{name}: relative error {err.max():.2e} > {REL}"

    # per-pixel inputs: every pixel's output depends on its own entries only, so one pair
    # of forwards per channel gives every pixel's partial derivative
    for name, value, grad, h in (("uv", uv, grad_uv, 1e-6), ("uv_da", da, grad_da, 1e-6),
                                 ("mip_level_bias", bias, grad_bias, 1e-6)):
        if value is None:
            continue
        value = np.asarray(value, np.float64)
        flat_grad = grad.reshape(mask.size, -1)
        channels = 1 if value.ndim == 3 else value.shape[-1]
        num = np.zeros((mask.size, channels))
        for c in range(channels):
            step = np.zeros_like(value)
            if value.ndim == 3:
                step[...] = h
            else:
                step[..., c] = h
            args = {"uv": uv, "uv_da": da, "mip_level_bias": bias}

            def at(k):
                moved = dict(args, **{name: value + k * step})
                return _loss_pixels(run(tex, moved["uv"], moved["uv_da"],
                                        moved["mip_level_bias"]), g)

            # 4-point central difference (truncation ~h^4)
            num[:, c] = (8 * (at(1) - at(-1)) - (at(2) - at(-2))) / (12 * h)
        if mode in ("nearest",) or (name != "uv" and mode != "linear-mipmap-linear"):
            assert np.all(flat_grad == 0), f"{name}: expected zero gradients in {mode}"
            assert np.abs(num[mask]).max() < 1e-6
            report[name] = (0.0, int(mask.sum()))
            continue
        compare(name, flat_grad[mask], num[mask])
    # tex (and the user's mip levels): the output is linear in them
    targets = [("tex", np.asarray(tex, np.float64), grad_tex)]
    if mip is not None:
        targets += [(f"mip[{k}]", np.asarray(m, np.float64), grad_mip[k])
                    for k, m in enumerate(mip)]
    for name, value, grad in targets:
        num = np.zeros(value.size)
        for k in range(value.size):
            e = np.zeros(value.size)
            e[k] = 1.0
            e = e.reshape(value.shape)
            if name == "tex":
                lp, lm = run(value + e, uv, da, bias), run(value - e, uv, da, bias)
            else:
                idx = int(name[4:-1])
                mp = [m if i != idx else m + e for i, m in enumerate(mip)]
                mm = [m if i != idx else m - e for i, m in enumerate(mip)]
                lp, lm = run(tex, uv, da, bias, mip_=mp), run(tex, uv, da, bias, mip_=mm)
            num[k] = ((lp - lm) * g).sum() / 2.0
        if name.startswith("mip") and max_mip_level is not None and \
                int(name[4:-1]) >= max_mip_level:
            assert np.all(grad == 0) and np.all(num == 0)
            continue
        compare(name, grad.reshape(-1), num)
    return report


@pytest.mark.parametrize("boundary", BOUNDARIES_2D)
@pytest.mark.parametrize("mode", MODES_2D)
def test_2d_gradients_match_central_differences(mode, boundary):
    tex, uv, da, bias = make_inputs(1, boundary, tex_size=(6, 8), channels=2)
    check_gradients(tex, uv, da, bias, mode, boundary)


@pytest.mark.parametrize("mode", MODES_2D)
def test_cube_gradients_match_central_differences(mode):
    tex, uv, da, bias = make_inputs(2, "cube", tex_size=(4, 4), channels=2)
    check_gradients(tex, uv, da, bias, mode, "cube")


def test_gradients_with_a_batched_odd_sized_texture():
    # Bt = B = 2, odd extents (7 x 5 -> 3 x 2 -> 1 x 1): the 3-tap box filter and its transpose
    tex, uv, da, bias = make_inputs(3, "wrap", tex_size=(7, 5), channels=2, tex_batch=2)
    check_gradients(tex, uv, da, bias, "linear-mipmap-linear", "wrap")


def test_gradients_from_the_bias_alone_and_from_uv_da_alone():
    tex, uv, _, bias = make_inputs(4, "clamp", tex_size=(6, 8), channels=2)
    check_gradients(tex, uv, None, bias + 1.0, "linear-mipmap-linear", "clamp")
    tex, uv, da, _ = make_inputs(5, "clamp", tex_size=(6, 8), channels=2)
    check_gradients(tex, uv, da, None, "linear-mipmap-linear", "clamp")


def test_gradients_to_a_user_mip_stack_and_max_mip_level():
    tex, uv, da, bias = make_inputs(6, "zero", tex_size=(6, 8), channels=2,
                                    level_range=(0.2, 1.8))
    rng = np.random.default_rng(7)
    mip = [rng.normal(size=(1, 3, 4, 2)), rng.normal(size=(1, 1, 2, 2)),
           rng.normal(size=(1, 1, 1, 2))]
    check_gradients(tex, uv, da, bias, "linear-mipmap-linear", "zero", mip=mip)
    tex, uv, da, bias = make_inputs(8, "zero", tex_size=(6, 8), channels=2,
                                    level_range=(0.1, 0.9))
    check_gradients(tex, uv, da, bias, "linear-mipmap-linear", "zero", mip=mip,
                    max_mip_level=1)


def test_cube_gradients_through_the_level_and_a_batched_cube():
    tex, uv, da, bias = make_inputs(9, "cube", tex_size=(5, 5), channels=1, tex_batch=2)
    check_gradients(tex, uv, da, None, "linear-mipmap-linear", "cube")


# --------------------------------------------------------------------------- level formula


def test_level_is_half_log2_of_the_largest_eigenvalue_of_jtj():
    tex, uv, da, bias = make_inputs(10, "wrap", tex_size=(64, 32), batch=1, image=(8, 8))
    args = ta.check(tex, uv, da, None, filter_mode="linear-mipmap-linear")
    geo = tr.lookup_geometry(args)
    j = da.reshape(-1, 2, 2) * np.array([[32.0], [64.0]])     # rows (s W, t H), cols (X, Y)
    eig = np.linalg.eigvalsh(np.transpose(j, (0, 2, 1)) @ j)[:, -1]
    np.testing.assert_allclose(geo["raw_level"], 0.5 * np.log2(eig), rtol=0, atol=1e-12)
    # bias adds; clamping to [0, levels - 1]
    args_b = ta.check(tex, uv, da, bias, filter_mode="linear-mipmap-linear")
    geo_b = tr.lookup_geometry(args_b)
    np.testing.assert_allclose(geo_b["raw_level"], geo["raw_level"] + bias.reshape(-1),
                               atol=1e-12)
    assert geo_b["level"].min() >= 0 and geo_b["level"].max() <= args_b.levels - 1


def test_level_without_uv_da_is_the_bias_and_auto_mode():
    tex = np.arange(16.0).reshape(1, 4, 4, 1)
    uv = np.full((1, 1, 3, 2), 0.5)
    bias = np.array([[[-1.0, 0.25, 7.0]]])
    args = ta.check(tex, uv, None, bias)
    assert args.filter_mode == "linear-mipmap-linear"
    np.testing.assert_array_equal(tr.lookup_geometry(args)["level"], [0.0, 0.25, 2.0])
    assert ta.check(tex, uv).filter_mode == "linear"


# --------------------------------------------------------------------------- values


def test_texel_centres_and_boundary_modes():
    tex = np.arange(12.0).reshape(1, 3, 4, 1)   # texel (i, j) = 4 j + i
    centres = np.array([[[[(i + 0.5) / 4, (j + 0.5) / 3] for i in range(4)] for j in range(3)]])
    for mode in ("nearest", "linear"):
        for boundary in BOUNDARIES_2D:
            out, _ = texture_forward(tex, centres, filter_mode=mode, boundary_mode=boundary)
            np.testing.assert_allclose(out[0, ..., 0], tex[0, ..., 0], atol=1e-12)
    # half a texel beyond the left edge: wrap blends with the last column, clamp repeats the
    # first, zero blends with 0
    uv = np.array([[[[0.0, 0.5 / 3]]]])
    wrap = texture_forward(tex, uv, boundary_mode="wrap")[0].item()
    clamp = texture_forward(tex, uv, boundary_mode="clamp")[0].item()
    zero = texture_forward(tex, uv, boundary_mode="zero")[0].item()
    assert (wrap, clamp, zero) == (1.5, 0.0, 0.0)
    uv = np.array([[[[1.0 - 0.125 / 4, 0.5 / 3]]]])  # 3/8 texel right of the last centre
    assert texture_forward(tex, uv, boundary_mode="zero")[0].item() == pytest.approx(3 * 0.625)


def test_pyramid_is_the_footprint_mean_and_its_transpose_is_the_adjoint():
    rng = np.random.default_rng(11)
    for h, w in [(8, 8), (7, 5), (1, 6), (9, 2), (3, 3)]:
        tex = rng.normal(size=(2, h, w, 3))
        shapes = ta.level_shapes(h, w)
        assert shapes[-1] == (1, 1)
        levels = tr.build_mips(tex, shapes)
        for lv, (hl, wl) in zip(levels, shapes[1:]):
            assert lv.shape == (2, hl, wl, 3)
            # each level keeps the mean (every finer texel weighs the same in total)
            np.testing.assert_allclose(lv.mean(axis=(1, 2)), tex.mean(axis=(1, 2)), atol=1e-12)
        if h % 2 == 0 and w % 2 == 0:
            box = tex.reshape(2, h // 2, 2, w // 2, 2, 3).mean(axis=(2, 4))
            np.testing.assert_allclose(levels[0], box, atol=1e-12)
        # <P x, y> = <x, P^T y> through the whole pyramid
        grads = [rng.normal(size=(2,) + s + (3,)) for s in shapes]
        pulled = tr.mips_backward(grads, shapes)
        lhs = sum((lv * g).sum() for lv, g in zip([tex, *levels], grads))
        assert (pulled * tex).sum() == pytest.approx(lhs, rel=1e-12)
    # odd extent 5 -> 2: weights (2, 2, 1)/5 and (1, 2, 2)/5
    row = np.arange(5.0).reshape(1, 1, 5, 1)
    level = tr.build_mips(row, ta.level_shapes(1, 5))[0]
    np.testing.assert_allclose(level[0, 0, :, 0], [(0 * 2 + 1 * 2 + 2) / 5, (2 + 3 * 2 + 4 * 2) / 5])


def test_max_mip_level_limits_the_pyramid():
    assert ta.level_shapes(16, 4) == [(16, 4), (8, 2), (4, 1), (2, 1), (1, 1)]
    assert ta.level_shapes(16, 4, 2) == [(16, 4), (8, 2), (4, 1)]
    assert ta.level_shapes(16, 4, 0) == [(16, 4)]


def test_cube_lookups_are_continuous_across_edges_and_corners():
    rng = np.random.default_rng(12)
    tex = rng.normal(size=(1, 6, 5, 5, 2))
    t = np.linspace(0, 1, 4001)[:, None]
    paths = [((1, 0.3, -1.2), (1, 0.3, 1.2)),       # +x -> +z ... across face edges
             ((1, -1.3, 0.2), (1, 1.3, 0.2)),
             ((1.0, 0.9, -1.3), (-1, 0.9, -1.3)),
             ((1, 1, 1.3), (1, 1, 0.7)),            # through the corner (1, 1, 1)
             ((1, 1.3, 1), (1, 0.7, 1))]
    for start, end in paths:
        d = (1 - t) * np.array(start) + t * np.array(end)
        out, _ = texture_forward(tex, d[None, None], boundary_mode="cube")
        steps = np.abs(np.diff(out[0, 0], axis=0)).max()
        # a bilinear filter moving 1/4000 of the path (< 0.01 texel per step)
        assert steps < 0.02, f"jump {steps} along {start} -> {end}"


def test_cube_face_selection_and_face_coordinates_follow_gl():
    tex = np.zeros((1, 6, 2, 2, 1))
    for f in range(6):
        tex[0, f, :, :, 0] = np.array([[0, 1], [2, 3]]) + 10 * f
    # GL table 8.19: (direction, face, s, t)
    cases = [((1, -0.5, 0.5), 0, 0.25, 0.75), ((-1, -0.5, 0.5), 1, 0.75, 0.75),
             ((0.5, 1, 0.5), 2, 0.75, 0.75), ((0.5, -1, 0.5), 3, 0.75, 0.25),
             ((0.5, -0.5, 1), 4, 0.75, 0.75), ((0.5, -0.5, -1), 5, 0.25, 0.75)]
    for d, face, s, t in cases:
        out = texture_forward(tex, np.array(d, float).reshape(1, 1, 1, 3), filter_mode="nearest",
                         boundary_mode="cube")[0].item()
        assert out == 10 * face + 2 * int(t * 2) + int(s * 2), (d, face)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("kwargs, message", [
    ({"tex": np.zeros((4, 4, 3))}, "tex must have shape (B, Ht, Wt, C)"),
    ({"tex": np.zeros((1, 6, 4, 4, 3))}, "pass boundary_mode='cube'"),
    ({"tex": np.zeros((1, 6, 4, 3, 3)), "boundary_mode": "cube"}, "tex must have shape (B, 6, N, N, C)"),
    ({"tex": np.zeros((3, 4, 4, 3))}, "tex has a batch of 3, uv of 2"),
    ({"tex": np.full((1, 4, 4, 3), np.nan)}, "tex must be finite"),
    ({"uv": np.zeros((2, 3, 3, 3))}, "uv must have shape (B, H, W, 2)"),
    ({"uv": np.zeros((2, 3, 3, 2)), "boundary_mode": "cube",
      "tex": np.zeros((1, 6, 4, 4, 3))}, "uv must have shape (B, H, W, 3)"),
    ({"uv_da": np.zeros((2, 3, 3, 2))}, "uv_da must have shape (2, 3, 3, 4)"),
    ({"mip_level_bias": np.zeros((2, 3, 3, 1))}, "mip_level_bias must have shape (2, 3, 3)"),
    ({"mip_level_bias": np.full((2, 3, 3), np.inf)}, "mip_level_bias must be finite"),
    ({"filter_mode": "cubic"}, "filter_mode must be one of"),
    ({"boundary_mode": "mirror"}, "boundary_mode must be one of"),
    ({"max_mip_level": -1}, "max_mip_level must be None or an integer >= 0"),
    ({"max_mip_level": 1.5}, "max_mip_level must be None or an integer >= 0"),
    ({"mip": [[["a"]]], "filter_mode": "linear-mipmap-linear"}, "mip[0] must hold real numbers"),
    ({"mip": [np.full((1, 2, 2, 3), np.nan)], "filter_mode": "linear-mipmap-linear"},
     "mip[0] must be finite"),
    ({"own_mips": 1}, "own_mips must be True or False"),
    ({"mip": [np.zeros((1, 2, 3, 3))], "filter_mode": "linear-mipmap-linear"},
     "mip[0] (mip level 1) must have shape (1, 2, 2, 3)"),
    ({"mip": [np.zeros((1, 2, 2, 3))] * 3, "filter_mode": "linear-mipmap-linear"},
     "mip has 3 levels, more than the 2"),
    ({"uv": [["a"]]}, "uv must hold real numbers"),
])
def test_bad_input_raises_value_error_naming_the_argument(kwargs, message):
    args = {"tex": np.zeros((1, 4, 4, 3)), "uv": np.zeros((2, 3, 3, 2))}
    args.update(kwargs)
    with pytest.raises(ValueError) as info:
        texture_forward(**args)
    assert message in str(info.value)


def test_bad_grad_out_raises():
    _, saved = texture_forward(np.zeros((1, 4, 4, 3)), np.zeros((2, 3, 3, 2)))
    with pytest.raises(ValueError, match=r"grad_out must have shape \(2, 3, 3, 3\)"):
        texture_backward(saved, np.zeros((2, 3, 3, 2)))


@pytest.mark.parametrize("kwargs, argument", [
    ({"filter_mode": "cubic"}, "filter_mode"),
    ({"boundary_mode": "mirror"}, "boundary_mode"),
    ({"max_mip_level": -1}, "max_mip_level"),
    ({"own_mips": "yes"}, "own_mips"),
    ({"tex": np.zeros((4, 4, 3))}, "tex"),
    ({"tex": np.zeros((3, 4, 4, 3))}, "tex"),
    ({"uv": np.zeros((2, 3, 3, 3))}, "uv"),
    ({"uv_da": np.zeros((2, 3, 3, 2))}, "uv_da"),
    ({"mip_level_bias": np.zeros((2, 3, 3, 1))}, "mip_level_bias"),
    ({"mip": [np.zeros((1, 2, 3, 3))], "filter_mode": "linear-mipmap-linear"}, "mip"),
])
def test_bad_input_error_carries_the_argument_name(kwargs, argument):
    args = {"tex": np.zeros((1, 4, 4, 3)), "uv": np.zeros((2, 3, 3, 2))}
    args.update(kwargs)
    with pytest.raises(ArgumentError) as info:
        texture_forward(**args)
    assert info.value.argument == argument
