"""The antialiasing study (glraster.studies.antialias) on a small frame: every method is
run, measured against the exact area coverage, and the files are written atomically."""

from __future__ import annotations

import json

import numpy as np
import pytest

from glraster.cli import main
from glraster.reference.area import area_coverage
from glraster.studies import antialias as study

SIZE = (40, 40)     # small enough to run in seconds; still dozens of edge pixels per scene


@pytest.fixture(scope="module")
def result(gl_context):
    # one run per backend, shared by the tests below (the run is what takes the time)
    assert gl_context.gl_error() == "GL_NO_ERROR"
    out = study.run_study(SIZE, repeats=1, ctx=gl_context)
    assert gl_context.gl_error() == "GL_NO_ERROR", "the study left a GL error set"
    return out


def test_every_method_the_driver_offers_is_measured(result, ctx):
    names = [r["name"] for r in result["methods"]]
    expected = {"1 sample", "SSAA 2x2", "SSAA 4x4", "SSAA 8x8", "analytic AA"}
    expected |= {f"MSAA {s}" for s in ctx.sample_counts if s > 1}
    expected |= {"SSAA {}x{}".format(*study.ssaa_grid(s)) for s in ctx.sample_counts if s > 1}
    assert set(names) == expected
    assert set(result["scenes"]) == {"fan", "thin", "floor", "checker"}
    for r in result["methods"]:
        for name, s in r["scenes"].items():
            assert s["time_s"] > 0, (r["name"], name)
    mean = [r["mean_rmse"] for r in result["methods"]]
    assert mean == sorted(mean)                              # ordered by error


def test_sampling_methods_are_exact_off_the_edges_and_converge_on_them(result):
    # Pixels wholly inside or outside (area exactly 0 or 1) have every sample inside or
    # outside: no sampling method may be wrong there (tolerance 1e-12: the exact area of a
    # pixel split between two triangles sums to 1 within a few float64 ulps). On edge pixels the
    # box-filtered coverage of k x k samples converges to the area: the error must shrink
    # with every step 1 -> 2x2 -> 4x4 -> 8x8 on every scene.
    rows = {r["name"]: r for r in result["methods"]}
    for name, r in rows.items():
        if name != "analytic AA":
            for scene, s in r["scenes"].items():
                assert s["max_off_edge"] <= 1e-12, (name, scene)
    for scene in result["scenes"]:
        chain = [rows[n]["scenes"][scene]["rmse"]
                 for n in ("1 sample", "SSAA 2x2", "SSAA 4x4", "SSAA 8x8")]
        assert chain == sorted(chain, reverse=True) and chain[-1] < chain[0] / 4, (scene, chain)
        for n, r in rows.items():
            if n.startswith("MSAA"):
                assert r["scenes"][scene]["rmse"] < rows["1 sample"]["scenes"][scene]["rmse"]


def test_one_sample_and_ssaa_images_are_what_their_definitions_say(result, ctx):
    # The study's 1-sample image is the pixel-centre mask; the exact area is the reference's
    # area_coverage; SSAA 2x2 is the mean of the 2x2 blocks of a 2x-resolution render.
    from glraster.gpu.rasterize import rasterize

    scene = study.builtin_scenes(SIZE)[0]
    images = result["_images"][scene.name]
    # the fan's values are all 1: its exact image is the area coverage (to 1 ulp: the
    # coverage is clamped to 1, the resolved sum is not)
    np.testing.assert_allclose(images["truth"], area_coverage(scene.pos, scene.tri, SIZE),
                               rtol=0, atol=1e-15)
    single = rasterize(scene.pos, scene.tri, SIZE, ctx=ctx, outputs=("tri_id",)).mask
    np.testing.assert_array_equal(images["1 sample"], single)
    big = rasterize(scene.pos, scene.tri, (80, 80), ctx=ctx, outputs=("tri_id",)).mask
    np.testing.assert_array_equal(images["SSAA 2x2"],
                                  big.reshape(40, 2, 40, 2).mean(axis=(1, 3)))


def test_msaa_is_compared_with_ssaa_at_the_same_sample_count(result, ctx):
    pairs = {c["samples"]: c for c in result["msaa_vs_ssaa"]}
    assert sorted(pairs) == [s for s in ctx.sample_counts if s > 1]
    for s, c in pairs.items():
        kx, ky = study.ssaa_grid(s)
        assert c["ssaa"] == f"SSAA {kx}x{ky}" and kx * ky == s and c["time_ratio"] > 0


def test_ssaa_grids_have_the_sample_count_asked_for():
    assert [study.ssaa_grid(s) for s in (1, 2, 4, 8, 16, 32)] == [
        (1, 1), (2, 1), (2, 2), (4, 2), (4, 4), (8, 4)]
    with pytest.raises(ValueError, match="samples must be a power of two, got 6"):
        study.ssaa_grid(6)


def test_cli_writes_the_json_and_both_figures(gl_backend, tmp_path, capsys):
    out = tmp_path / "aa"
    code = main(["antialias-study", "--out", str(out), "--size", "32", "--repeats", "1",
                 "--backend", gl_backend])
    assert code == 0
    printed = capsys.readouterr().out
    assert "SSAA 8x8" in printed and "exact image (visible areas) in" in printed
    files = sorted(p.name for p in out.iterdir())
    assert files == ["antialias.json", "antialias_error_time.png", "antialias_zoom.png"]
    data = json.loads((out / "antialias.json").read_text())
    assert data["resolution"] == [32, 32] and "_images" not in data
    assert all(set(r["scenes"]) == {"fan", "thin", "floor", "checker"} for r in data["methods"])


def test_cli_rejects_a_tiny_frame(tmp_path, capsys):
    assert main(["antialias-study", "--out", str(tmp_path), "--size", "4"]) != 0
    assert "--size must be at least 16" in capsys.readouterr().err


def test_edge_pixels_are_where_more_than_one_value_shows():
    # a square of two triangles split by its diagonal: with equal values only the square's
    # outline is an edge (the diagonal joins one value to itself); with two values the
    # diagonal's pixels are edges too, and the exact image there is the area-weighted mean
    from glraster.geometry.window import window_to_clip

    res = (8, 8)
    pos = np.float32(window_to_clip(np.array([[1.5, 1.5], [6.5, 1.5], [6.5, 6.5],
                                              [1.5, 6.5]]), res))
    tri = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    same = study.AntialiasScene("same", "same", pos, tri, np.array([1.0, 1.0]))
    image, edge = study.exact_image(same, res)
    outline = np.zeros(res, bool)
    outline[1, 1:7] = outline[6, 1:7] = outline[1:7, 1] = outline[1:7, 6] = True
    np.testing.assert_array_equal(edge, outline)
    two = study.AntialiasScene("two", "two", pos, tri, np.array([1.0, 0.5]))
    image, edge = study.exact_image(two, res)
    diagonal = np.eye(8, dtype=bool)
    np.testing.assert_array_equal(edge, outline | (diagonal & ~np.isin(np.arange(8), [0, 7])))
    assert image[3, 3] == pytest.approx(0.75, abs=1e-15)      # half 1, half 0.5
    assert image[2, 4] == pytest.approx(1.0, abs=1e-15)       # below the diagonal: value 1


def test_cli_without_a_backend_exits_3_and_writes_nothing(tmp_path):
    # EGL with no vendor library finds no device: the backend is unavailable (exit code 3)
    import os
    import subprocess
    import sys

    env = {**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent"}
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "antialias-study", "--out",
                          str(tmp_path / "aa"), "--backend", "egl"], capture_output=True,
                         text=True, env=env, timeout=300)
    assert run.returncode == 3, run.stderr
    assert not list(tmp_path.iterdir())


def _doc_table(path, header_start):
    """{method: [cells]} of the Markdown table whose header row starts with header_start."""
    from pathlib import Path

    lines = (Path(__file__).resolve().parents[2] / path).read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    rows = {}
    for line in lines[first + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def _assert_as_written(written: str, value: float, where) -> None:
    """``written`` ("0.0931") is ``value`` rounded to as many decimals as it shows."""
    decimals = len(written.split(".")[1]) if "." in written else 0
    assert round(float(value), decimals) == pytest.approx(float(written), abs=1e-12), (
        where, written, value)


def test_the_errors_quoted_in_the_docs_are_what_the_study_computes(ctx):
    # docs/antialiasing.md's table (256x256, llvmpipe): every RMSE / max cell and the mean
    # RMSE, to the digits written there, and README's mean RMSE column. The errors do not depend on timing, so one run of
    # each method suffices; they depend on the driver's sample positions and fill rule.
    if "llvmpipe" not in ctx.renderer:
        pytest.skip(f"the quoted figures are llvmpipe's, this is {ctx.renderer}")
    table = _doc_table("docs/antialiasing.md", "| method (by error) | samples | fan |")
    readme = _doc_table("README.md", "| method (by error) | mean edge RMSE |")
    res = (256, 256)
    scenes = study.builtin_scenes(res)
    names = [s.name for s in scenes]
    assert names == ["fan", "thin", "floor", "checker"]
    exact = {s.name: study.exact_image(s, res) for s in scenes}
    for m in study.methods(ctx):
        assert m.name in table, f"docs/antialiasing.md has no row for {m.name}"
        cells = table[m.name]
        rmses = []
        for scene, cell in zip(scenes, cells[1:5]):
            image = m.prepare(scene, res, ctx)()
            truth, edge = exact[scene.name]
            err = np.abs(image - truth)[edge]
            rmse, worst = np.sqrt(np.mean(err ** 2)), err.max()
            rmses.append(rmse)
            quoted_rmse, quoted_max = cell.split(" / ")
            _assert_as_written(quoted_rmse, rmse, (m.name, scene.name, "rmse"))
            _assert_as_written(quoted_max, worst, (m.name, scene.name, "max"))
        _assert_as_written(cells[5], np.mean(rmses), (m.name, "mean rmse"))
        _assert_as_written(readme[m.name][0], np.mean(rmses), ("README", m.name))
