"""The HTML report as a person sees it: rendered by headless Chromium and screenshotted."""

import shutil
import subprocess

import numpy as np
import OpenImageIO as oiio
import pytest

from glraster.conformance import check
from glraster.conformance.html_report import HtmlReport
from glraster.io.png import EMPTY_RGB

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
SCENES = ["basic_perspective_triangle", "torus", "fan_offcenter", "far_from_origin_4096"]


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory, gl_context):
    ctx = gl_context
    out = tmp_path_factory.mktemp("report")
    rep = HtmlReport(out)
    masks = {}

    def on_scene(res, art):
        if art is not None:
            masks[res.name] = art.gpu.mask.copy()
        rep.add_scene(res, art)

    result = check.run(ctx, SCENES, on_scene=on_scene, mutants=True,
                       mutant_pattern="tri_id_*,half_float_targets")
    rep.finish(result)
    assert ctx.gl_error() == "GL_NO_ERROR"
    return out, result, masks, rep.images


def test_report_files_and_content(report_dir):
    out, result, *_ = report_dir
    html = (out / "index.html").read_text()
    for name in SCENES:
        assert f'id="{name}"' in html
        for kind in ("gpu", "ref", "error", "coverage"):
            assert (out / "img" / f"{name}_{kind}.png").is_file()
    assert "tri_id_off_by_one" in html and "Fault injection" in html
    assert (out / "img" / "summary.png").is_file()
    # The 4096x4096 scene is cropped to its covered corner and reduced to <= 384 px.
    spec = oiio.ImageInput.open(str(out / "img" / "far_from_origin_4096_gpu.png")).spec()
    assert max(spec.width, spec.height) <= 384
    assert "http://" not in html and "https://" not in html      # works offline


def test_report_images_are_upright_pngs_of_the_cropped_size(report_dir):
    out, result, masks, images = report_dir
    for name in SCENES:
        shapes = set()
        for kind in ("gpu", "ref", "error", "coverage"):
            p = out / "img" / f"{name}_{kind}.png"
            inp = oiio.ImageInput.open(str(p))
            assert inp is not None and inp.format_name() == "png", oiio.geterror()
            img = inp.read_image("uint8")
            inp.close()
            assert img.shape[2] == 3
            shapes.add(img.shape[:2])
        assert len(shapes) == 1                       # the four views line up
    # upright and unscaled at 1x: the non-empty pixels of the GPU picture are the covered
    # pixels of the crop, with the rows flipped (file row 0 = top = array row H - 1)
    for name in ("basic_perspective_triangle", "torus"):
        info = images[name]
        assert info["factor"] == 1
        y0, y1, x0, x1 = info["crop"]
        inp = oiio.ImageInput.open(str(out / "img" / info["files"]["gpu"]))
        img = inp.read_image("uint8")
        inp.close()
        drawn = (img != np.array(EMPTY_RGB, np.uint8)).any(axis=2)
        np.testing.assert_array_equal(drawn, masks[name][y0:y1, x0:x1][::-1])
    # the summary figure: decodable, titled, Software = glraster
    from PIL import Image

    text = Image.open(out / "img" / "summary.png").text
    assert text["Title"].startswith("glraster check") and text["Software"].startswith("glraster")
    # atomic writes: no temporary file left in the report
    assert not [p.name for p in out.rglob(".*")]


def screenshot(url, path, tmp_path, size="1280,2000"):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
           f"--window-size={size}", f"--screenshot={path}", url]
    subprocess.run(cmd, check=True, timeout=120, capture_output=True)
    return oiio.ImageInput.open(str(path)).read_image("uint8")


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/install-system-deps.sh)")
def test_report_renders_in_headless_chromium(report_dir, tmp_path):
    out, result, *_ = report_dir
    img = screenshot((out / "index.html").as_uri(), tmp_path / "shot.png", tmp_path)
    assert img.shape[:2] == (2000, 1280)
    rgb = img[..., :3].astype(int)
    # Not blank: many distinct colors and a large share of non-background pixels.
    # (Thresholds are loose on purpose: fonts differ between machines; a blank or
    # broken page has ~1 color and ~0 % foreground.)
    background = np.array([250, 250, 250])
    foreground = (np.abs(rgb - background).sum(axis=2) > 30).mean()
    colors = len(np.unique(rgb.reshape(-1, 3) // 8, axis=0))
    assert foreground > 0.05 and colors > 100
    # The verdict badge is drawn: green (PASS) or red (FAIL) pixels in the title row.
    top = rgb[:80]
    green = ((top[..., 1] > 100) & (top[..., 0] < 80) & (top[..., 2] < 80)).sum()
    red = ((top[..., 0] > 180) & (top[..., 1] < 70) & (top[..., 2] < 70)).sum()
    assert (green > 100) == result.ok and (red > 100) == (not result.ok)
    # The summary figure (an <img>) loaded: its blue/orange/green bars are visible.
    bars = ((rgb[..., 2] > 150) & (rgb[..., 0] < 60)).sum()
    assert bars > 200


def _snapshot(folder):
    """{relative path: bytes} of every file under ``folder``, hidden ones included."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_run_that_fails_leaves_the_report_that_was_there(gl_context, tmp_path):
    """The images of a run go to a folder of their own until finish() writes index.html:
    a run that raises (a full disk, Ctrl-C) between its first image and the index leaves
    the previous report whole (its index and exactly its images) and nothing of its own;
    a run that finishes replaces both, so the images are those the index shows."""
    out = tmp_path / "report"
    with HtmlReport(out) as rep:
        result = check.run(gl_context, ["torus"], on_scene=rep.add_scene)
        rep.finish(result)
    before = _snapshot(out)
    assert "index.html" in before and "img/torus_gpu.png" in before
    assert (out / "img").stat().st_mode & 0o777 == 0o755, "readable by a web server"

    with pytest.raises(KeyboardInterrupt):
        with HtmlReport(out) as rep:
            check.run(gl_context, ["fan_offcenter"], on_scene=rep.add_scene)
            assert (rep.img / "fan_offcenter_gpu.png").is_file()   # written, not published
            raise KeyboardInterrupt
    assert _snapshot(out) == before

    with HtmlReport(out) as rep:
        result = check.run(gl_context, ["fan_offcenter"], on_scene=rep.add_scene)
        rep.finish(result)
    after = _snapshot(out)
    assert 'id="fan_offcenter"' in after["index.html"].decode()
    assert sorted(after) == ["img/fan_offcenter_coverage.png", "img/fan_offcenter_error.png",
                             "img/fan_offcenter_gpu.png", "img/fan_offcenter_ref.png",
                             "img/summary.png", "index.html"]


def test_a_report_folder_made_by_a_run_that_fails_is_removed(tmp_path):
    out = tmp_path / "new" / "report"
    with pytest.raises(RuntimeError):
        with HtmlReport(out):
            raise RuntimeError("the run failed")
    assert not out.exists()
