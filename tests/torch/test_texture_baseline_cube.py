"""The texture bench's plain-PyTorch cube map (glraster.studies.torch_texture_baseline.
cube_texture, the yardstick of its "cube" cells) computes glraster's linear cube-map
lookup away from the face edges: output and gradients (tex, directions) against the float64
texture reference through glraster.diff.ops.TEXTURE, within 1e-12 of the largest entry.

Pixels whose bilinear taps reach past their face's edge (within one texel of it) are left
out: there glraster reads the neighbouring face and the yardstick clamps to its own (said
in its docstring); their upstream gradient is 0 and their output is not compared. At least
half the pixels remain (asserted), and the edge pixels do differ (so the mask is needed,
and a wrong face table fails).
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from glraster.diff.ops import TEXTURE  # noqa: E402
from glraster.studies import torch_texture_baseline as baseline  # noqa: E402


def _inner(direction: np.ndarray, n: int) -> np.ndarray:
    """(B, H, W) bool: the pixels whose four taps lie on their own face."""
    a = np.abs(direction)
    m = a.max(-1)
    # both face coordinates are the two non-major components over m, in [-1, 1]
    rest = np.sort(a, axis=-1)[..., :2] / m[..., None]
    x = (rest + 1) / 2 * n - 0.5                    # texel positions
    return np.all(x <= n - 1 - 1e-3, axis=-1) & (m > 0)


def test_cube_yardstick_matches_the_float64_reference_off_the_edges():
    tex32, d32 = baseline.cube_inputs(16, channels=3, seed=4)
    tex, d = tex32.double().numpy(), d32.double().numpy()
    n = tex.shape[2]
    assert tex.shape == (1, 6, 8, 8, 3) and d.shape == (1, 16, 16, 3)
    inner = _inner(d, n)
    assert inner.mean() >= 0.5 and not inner.all()
    g = np.random.default_rng(5).normal(size=d.shape[:3] + (3,))
    g[~inner] = 0.0
    params = dict(filter_mode="linear", boundary_mode="cube")
    (out, ), saved = TEXTURE.forward(tex, d, None, None, **params)
    want = TEXTURE.core(np.float64).backward(saved, g)[:2]
    t = torch.from_numpy(tex).requires_grad_()
    u = torch.from_numpy(d).requires_grad_()
    got = baseline.cube_texture(t, u)
    got.backward(torch.from_numpy(g))
    err = np.abs(got.detach().numpy() - out)
    assert err[inner].max() <= 1e-12 * max(1.0, np.abs(out).max())
    assert err[~inner].max() > 1e-3                   # the edges do differ
    for name, w, x in (("grad tex", want[0], t.grad), ("grad direction", want[1], u.grad)):
        x = x.numpy()
        assert x.shape == w.shape, name
        assert np.abs(x - w).max() <= 1e-12 * max(1.0, np.abs(w).max()), name


def test_the_bench_runs_its_short_forms(ctx, capsys):
    """docs/differentiable.md quotes `texture-baseline --sizes 256 512 1024 --repeat 3` and
    `--cores --cpu-time` over the same sizes (minutes); these are their 16² rounds, the cube
    cell included: every row printed, ratios and the clear timing line there."""
    assert baseline.main(["--sizes", "16", "--repeat", "1", "--modes", "nearest", "cube"]) == 0
    assert baseline.main(["--cores", "--cpu-time", "--sizes", "16", "--repeat", "1",
                          "--modes", "linear", "cube"]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = [line.split("|") for line in out if line.startswith("| 16²")]
    assert [row[2].strip() for row in rows] == ["nearest", "cube", "linear", "cube"]
    assert all(len(row) == 8 and "[" in row[5 if i < 2 else 6] for i, row in enumerate(rows))
    assert any(line.startswith("clearing the texel-gradient buffer") for line in out)


def test_the_comparison_counts_cpu_time_when_asked(ctx, capsys):
    """`texture-baseline --cpu-time` without --cores (docs/differentiable.md, "Texture",
    small cells) times both sides by the process's CPU time and says so."""
    assert baseline.main(["--cpu-time", "--sizes", "16", "--repeat", "1",
                          "--modes", "linear"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "CPU time of the process" in out[0]
    rows = [line.split("|") for line in out if line.startswith("| 16²")]
    assert [row[2].strip() for row in rows] == ["linear"] and "[" in rows[0][5]
