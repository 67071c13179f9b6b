"""glraster.studies.diff_bench and its yardstick glraster.studies.torch_interpolate_baseline:
a tiny grid gives every field, and the plain-PyTorch interpolate computes the same thing as glraster's (out
and out_da bit for bit, gradients within float32 summation order). No timing is judged
here (timings are benchmark figures, docs/differentiable.md "Speed")."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import glraster.torch as dr  # noqa: E402
from glraster.diff.ids import MAX_ID, encode_ids  # noqa: E402
from glraster.studies import diff_bench  # noqa: E402
from glraster.studies.bench import make_bench_scene  # noqa: E402
from glraster.studies import torch_interpolate_baseline as baseline  # noqa: E402

# Gradients: float32 sums over the pixels of a vertex (atomics in any order against
# index_add_'s order) and, for dL/du, sum_k g_k (a0 - a2)_k against autograd's
# sum_k g_k a0_k - g_k a2_k; a few float32 roundings of the largest entry.
GRAD_TOL = 1e-5


def test_a_tiny_run_reports_every_field(gl_backend):
    steps = []
    result = diff_bench.run("quick", backend=gl_backend, resolutions=(40,), counts=(1, 300),
                            repeats=2, profile=[(40, 300)],
                            progress=lambda i, n, label: steps.append((i, n)))
    assert steps[-1][0] == steps[-1][1] == 3
    assert result["machine"]["accumulation"] in ("atomic_float", "cas")
    assert [c["triangles"] for c in result["cells"]] == [1, len(make_bench_scene("terrain", 300).faces)]
    for cell in result["cells"]:
        assert cell["resolution"] == [40, 40] and 0 < cell["covered_fraction"] <= 1
        assert set(cell["times"]) == {f"rasterize_{k}" for k in diff_bench.RASTER_CALLS} | \
            {f"interpolate_{k}" for k in diff_bench.INTERP_CALLS}
        for t in cell["times"].values():
            assert 0 < t["min_ms"] <= t["median_ms"] <= t["max_ms"] and t["cpu_median_ms"] >= 0
        for name in ("glraster", "baseline"):
            t = cell["times"][f"interpolate_{name}"]
            assert t["forward_median_ms"] > 0 and t["backward_median_ms"] > 0
        for r in cell["ratios"].values():
            assert 0 < r["min"] <= r["median"] <= r["max"] and r["pairs"] == 2
        # the interpolate goal applies from 512² up only
        assert set(cell["goals"]) == set(diff_bench.GOALS) - {"glraster_over_baseline"}
        assert all(isinstance(g["met"], bool) for g in cell["goals"].values())
        same = cell["same_math"]
        assert same["out_equal"] and same["out_da_equal"], same
        for name in ("grad_attr", "grad_rast", "grad_rast_db"):
            assert same[f"{name}_rel_diff"] <= GRAD_TOL, (name, same)
    assert result["goals"]["db_over_nodb"]["cells"] == 2
    assert len(result["profile"]) == 1 and result["settings"]["profile"] == [[40, 300]]
    profile = result["profile"][0]["ms_per_call"]
    assert set(profile) == set(result["cells"][0]["times"])
    for phases in profile.values():
        assert phases["total"] > 0
        assert sum(v for k, v in phases.items() if k != "total") == pytest.approx(
            phases["total"], rel=1e-6)
    assert "host reduction (ids; fixed-point decode)" in \
        profile["rasterize_backward_deterministic"]
    json.dumps(result, default=float)
    table = diff_bench.table(result)
    assert table.count("\n") == 1 + len(result["cells"]) and "| 40² | 1 |" in table


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


def _grads(fn, attr, rast, rast_db, tri, diff_attrs, seed=1):
    leaves = [t.detach().clone().requires_grad_() for t in (attr, rast, rast_db)]
    out, out_da = fn(leaves[0], leaves[1], tri, leaves[2], diff_attrs)
    rng = np.random.default_rng(seed)
    upstream = [torch.from_numpy(rng.standard_normal(t.shape).astype(np.float32))
                for t in (out, out_da)]
    torch.autograd.backward([t for t in (out, out_da) if t.numel()],
                            [g for g in upstream if g.numel()])
    return out.detach(), out_da.detach(), [leaf.grad for leaf in leaves]


@pytest.mark.parametrize("case", ["plain", "instanced_batched_attr", "broadcast_attr",
                                  "repeated_diff_attrs", "no_diff_attrs"])
def test_baseline_is_the_same_math_as_glraster(glctx, case):
    scene = make_bench_scene("terrain", 400)
    pos, tri = torch.from_numpy(scene.pos), torch.from_numpy(scene.faces)
    rng = np.random.default_rng(0)
    vertices, num_attr = len(scene.pos), 3
    diff_attrs = "all"
    attr_shape = (vertices, num_attr)
    if case == "instanced_batched_attr":
        shift = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.05, -0.03, 0.0, 0.1]])
        pos = pos[None] + shift[:, None]
        attr_shape = (2, vertices, num_attr)
    elif case == "broadcast_attr":
        pos = torch.stack([pos, pos * 1.02])
        attr_shape = (1, vertices, num_attr)
    elif case == "repeated_diff_attrs":
        diff_attrs = [2, 0, 2]
    elif case == "no_diff_attrs":
        diff_attrs = None
    rast, rast_db = dr.rasterize(glctx, pos, tri, (64, 48))
    assert (rast[..., 3] > 0).float().mean() > 0.3
    attr = torch.from_numpy(rng.standard_normal(attr_shape).astype(np.float32))
    gl = lambda *a: dr.interpolate(*a, glctx=glctx)  # noqa: E731
    out_g, da_g, grads_g = _grads(gl, attr, rast, rast_db, tri, diff_attrs)
    out_b, da_b, grads_b = _grads(baseline.interpolate, attr, rast, rast_db, tri, diff_attrs)
    assert torch.equal(out_g, out_b)
    assert da_g.shape == da_b.shape and torch.equal(da_g, da_b)
    for name, g, b in zip(("attr", "rast", "rast_db"), grads_g, grads_b):
        if diff_attrs is None and name == "rast_db":
            assert b is None and (g is None or not g.any())
            continue
        scale = b.abs().max().item()
        assert scale > 0 and (g - b).abs().max().item() <= GRAD_TOL * scale, name


def test_baseline_decodes_ids_as_layout():
    index = np.array([-1, 0, 1, 2**24 - 2, 2**24 - 1, 2**24, 2**24 + 1, 123456789,
                      MAX_ID - 1])
    encoded = encode_ids(index)
    got = baseline.decode_ids(torch.from_numpy(encoded)).numpy()
    np.testing.assert_array_equal(got, index + 1)


def test_unknown_settings_are_rejected():
    with pytest.raises(ValueError, match="preset must be"):
        diff_bench.run("huge")
    with pytest.raises(ValueError, match="unknown settings"):
        diff_bench.run("quick", methods=("hw",))
