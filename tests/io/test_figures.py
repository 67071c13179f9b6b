"""glraster.io.figures, the one matplotlib setup, and the figures drawn with it: files
written, decodable, of the right size, with metadata; nothing (no partial or temporary
file) after a failure while drawing or saving; no global matplotlib state touched."""

import math

import matplotlib
import numpy as np
import OpenImageIO as oiio
import pytest
from matplotlib.figure import Figure
from PIL import Image

from glraster.io import figures
from glraster.studies import bench, stress


def png_size(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        assert inp.format_name() == "png"
        img = inp.read_image("uint8")
        return img.shape[1], img.shape[0], img
    finally:
        inp.close()


def test_figure_is_saved_with_size_and_metadata(tmp_path):
    backend = matplotlib.get_backend()
    p = tmp_path / "sub" / "f.png"
    with figures.figure(p, figsize=(4, 3), dpi=50, title="a title", description="words") as fig:
        ax = fig.subplots()
        ax.plot([1, 2, 3], [1e-16, 1e-8, 1])
        ax.set_yscale("log")
    w, h, img = png_size(p)
    assert (w, h) == (200, 150)
    assert len(np.unique(img.reshape(-1, img.shape[2]), axis=0)) > 4     # something drawn
    text = Image.open(p).text
    assert text["Title"] == "a title" and text["Description"] == "words"
    assert text["Software"].startswith("glraster ")
    assert matplotlib.get_backend() == backend            # no global backend switch
    assert sorted(x.name for x in p.parent.iterdir()) == ["f.png"]


def test_svg_and_pdf_take_their_formats_metadata(tmp_path):
    for name in ("f.svg", "f.pdf"):
        with figures.figure(tmp_path / name, figsize=(2, 2), title="t", description="d") as fig:
            fig.subplots().plot([0, 1])
    assert (tmp_path / "f.svg").read_text().lstrip().startswith("<?xml")
    assert (tmp_path / "f.pdf").read_bytes().startswith(b"%PDF")


def test_an_error_while_drawing_writes_nothing(tmp_path):
    with pytest.raises(ZeroDivisionError):
        with figures.figure(tmp_path / "f.png") as fig:
            fig.subplots().plot([0, 1])
            1 / 0
    assert list(tmp_path.iterdir()) == []


def test_a_failed_save_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    p = tmp_path / "f.png"
    with figures.figure(p, figsize=(2, 2), dpi=40) as fig:
        fig.subplots().plot([0, 1])
    before = p.read_bytes()

    def broken_savefig(self, fname, **kwargs):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG partial")
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        with figures.figure(p, figsize=(5, 5)) as fig:
            fig.subplots().plot([1, 0])
    with pytest.raises(OSError, match="disk full"):
        with figures.figure(tmp_path / "new.png") as fig:
            fig.subplots()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["f.png"]
    assert p.read_bytes() == before


def test_colors_and_colormap_lut():
    c = figures.colors(["a", "b"])
    assert c == {"a": figures.PALETTE[0], "b": figures.PALETTE[1]}
    lut = figures.colormap_lut("viridis", 256)
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    assert lut[0].tolist() == [68, 1, 84] and lut[-1].tolist() == [253, 231, 37]


def _bench_result(methods=("hw", "divw", "homogeneous", "homogeneous64", "solve4"),
                  scenes=("terrain", "shards"), sizes=(256, 1024, 4096),
                  counts=(1, 1000, 20000, 1000000)):
    """A benchmark result shaped like bench.run's, with homogeneous64 at the float64
    rounding level (1e-16), one exact 0 and one NaN."""
    base = {"hw": 3e-4, "divw": 4e-4, "homogeneous": 1.3e-7, "homogeneous64": 1.1e-16,
            "solve4": 5e-5}
    cost = {"hw": 1.0, "divw": 1.3, "homogeneous": 3.0, "homogeneous64": 4.0, "solve4": 5.0}
    cases = []
    for scene in scenes:
        for s in sizes:
            for n in counts:
                for m in methods:
                    tris = n if scene == "shards" or n == 1 else int(n * 0.97)
                    err = base[m] * (1 + math.log10(n) / 3)
                    cases.append({"method": m, "scene": scene, "resolution": [s, s],
                                  "triangles": tris, "warm_ms": cost[m] * (s / 256) ** 2
                                  * (1 + n / 1e4),
                                  "error": {"persp": {"max": err}}})
    cases[-1]["error"]["persp"]["max"] = 0.0
    cases[0]["error"]["persp"]["max"] = float("nan")
    cases.append({"method": "hw", "scene": scenes[0], "resolution": [sizes[0]] * 2,
                  "triangles": 1, "warm_ms": 1.0, "error": {}})     # no persp: left out
    return {"settings": {"methods": list(methods), "scenes": list(scenes),
                         "resolutions": list(sizes), "counts": list(counts)},
            "cases": cases}


@pytest.mark.parametrize("kw, panels", [({}, (3, 2)),
                                        ({"scenes": ("terrain",), "sizes": (48,),
                                          "counts": (1, 50), "methods": ("hw",)}, (1, 1))])
def test_pareto_plot_has_a_panel_per_scene_and_resolution(tmp_path, kw, panels):
    p = tmp_path / "pareto.png"
    bench.pareto_plot(_bench_result(**kw), str(p))
    w, h, _ = png_size(p)
    ncols, nrows = panels
    # 120 dpi, 4 in per column (+ a legend column when narrow), 3.3 in per row
    assert abs(w - 120 * (0.8 + 4.0 * ncols + (0 if ncols >= 3 else 3.6))) <= 2
    assert abs(h - 120 * (1.6 + 3.3 * nrows)) <= 2
    assert Image.open(p).text["Title"].startswith("glraster methods")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["pareto.png"]


def test_pareto_plot_error_axis_reaches_the_float64_level(tmp_path, monkeypatch):
    """The error axis of every panel spans down past 1e-16 when homogeneous64 is there,
    and every panel shares it."""
    seen = []
    real_save = figures.save

    def spy(fig, path, **kw):
        seen.extend(ax.get_ylim() for ax in fig.axes if ax.get_visible())
        return real_save(fig, path, **kw)

    monkeypatch.setattr(figures, "save", spy)
    bench.pareto_plot(_bench_result(), str(tmp_path / "p.png"))
    assert len(seen) == 6 and len(set(seen)) == 1
    lo, hi = seen[0]
    assert lo < 1e-16 and hi > 1e-3


def test_a_failing_figure_leaves_no_file(tmp_path, monkeypatch):
    monkeypatch.setattr(Figure, "savefig",
                        lambda self, fname, **kw: (open(fname, "wb").write(b"x"),
                                                   (_ for _ in ()).throw(OSError("full"))))
    with pytest.raises(OSError, match="full"):
        bench.pareto_plot(_bench_result(), str(tmp_path / "p.png"))
    with pytest.raises(OSError, match="full"):
        stress.plot(_stress_result(), str(tmp_path / "s.png"))
    assert list(tmp_path.iterdir()) == []


def _stress_result(sweeps=("origin", "w_ratio", "size", "near", "extent", "scale", "aspect")):
    out = {}
    for sweep in sweeps:
        values = [0.0, 1024.0, 8192.0] if sweep.startswith("origin") else [1e-3, 1.0, 1e3]
        out[sweep] = {"values": values, "methods": {}}
        for m, e in (("hw", 3e-6), ("homogeneous", 1e-7), ("homogeneous64", 2e-16)):
            pts = [{"pixels": 10, "nonfinite": 0,
                    "persp": {"max": e * (1 + i), "ratio_max": e / 6e-8 * (1 + i)}}
                   for i in range(len(values))]
            pts[0] = {"pixels": 0, "nonfinite": 0}                        # nothing judged
            if m == "hw":
                pts[-1]["nonfinite"] = 3
            out[sweep]["methods"][m] = pts
    return out


def test_stress_plot_wraps_sweeps_into_rows(tmp_path):
    p = tmp_path / "stress.png"
    stress.plot(_stress_result(), str(p), columns=4)
    w, h, _ = png_size(p)
    # 7 sweeps at 4 per row: 2 rows of (error, normalized error) panel pairs
    assert abs(w - 110 * (3.2 * 4 + 0.6)) <= 2 and abs(h - 110 * (5.2 * 2 + 0.9)) <= 2
    assert "stress" in Image.open(p).text["Title"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["stress.png"]
