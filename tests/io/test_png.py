"""glraster.io.png: the one PNG writer (upright, decodable, metadata, atomic) and the
barycentric picture."""

import numpy as np
import OpenImageIO as oiio
import pytest
from PIL import Image

from glraster.io import png


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        assert inp.format_name() == "png"
        return inp.read_image("uint8"), inp.spec()
    finally:
        inp.close()


def test_written_png_is_upright_right_size_and_exact(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (7, 11, 3), dtype=np.uint8)   # row 0 at the bottom
    p = png.write_png(tmp_path / "a.png", rgb)
    img, spec = read(p)
    assert (spec.width, spec.height, spec.nchannels) == (11, 7, 3)
    np.testing.assert_array_equal(img, rgb[::-1])               # file row 0 is the top
    # Pillow (what matplotlib and browsers-like readers use) agrees
    np.testing.assert_array_equal(np.asarray(Image.open(p)), rgb[::-1])
    q = png.write_png(tmp_path / "b.png", rgb, bottom_up=False)
    np.testing.assert_array_equal(read(q)[0], rgb)


def test_rgba_float_input_metadata_and_parent_folder(tmp_path):
    rgba = np.zeros((3, 4, 4))
    rgba[..., 0] = [[0.0, 0.5, 1.0, 2.0]] * 3            # clipped to 1
    rgba[..., 1] = np.nan                                # NaN becomes 0
    rgba[..., 3] = 1.0
    p = png.write_png(tmp_path / "deep" / "er" / "x.png", rgba,
                      metadata={"Title": "t", "Description": png.ORIENTATION})
    img, spec = read(p)
    assert spec.nchannels == 4
    assert img[0, :, 0].tolist() == [0, 128, 255, 255] and (img[..., 1] == 0).all()
    assert (img[..., 3] == 255).all()
    text = Image.open(p).text
    assert text["Title"] == "t" and text["Description"].startswith("upright")


@pytest.mark.parametrize("bad", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 2), np.uint8),
                                 np.zeros((0, 4, 3), np.uint8), np.zeros((2, 2, 3), np.int32),
                                 np.zeros((2, 2, 3), bool)])
def test_bad_images_are_rejected_and_nothing_is_written(tmp_path, bad):
    with pytest.raises(ValueError, match="images? must"):
        png.write_png(tmp_path / "x.png", bad)
    assert list(tmp_path.iterdir()) == []


class _FailingOutput:
    """Stands in for OpenImageIO's PNG writer: writes some bytes, then fails."""

    def open(self, name, spec):
        with open(name, "wb") as fh:
            fh.write(b"\x89PNG partial")
        return True

    def write_image(self, img):
        return False

    def geterror(self):
        return "disk full (simulated)"

    def close(self):
        return True


def test_a_failed_write_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    old = np.full((2, 3, 3), 7, np.uint8)
    target = png.write_png(tmp_path / "keep.png", old)
    monkeypatch.setattr(oiio.ImageOutput, "create", staticmethod(lambda *a: _FailingOutput()))
    with pytest.raises(OSError, match="disk full"):
        png.write_png(tmp_path / "keep.png", np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(OSError, match="disk full"):
        png.write_png(tmp_path / "new.png", np.zeros((5, 5, 3), np.uint8))
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]
    np.testing.assert_array_equal(read(target)[0], old[::-1])


def test_bary_rgb_colors_covered_empty_and_nonfinite_pixels():
    bary = np.array([[[1.0, 0.0, 0.0], [0.25, 0.25, 0.5]],
                     [[np.nan, 0.5, 0.5], [2.0, -1.0, 0.0]]])
    mask = np.array([[True, True], [True, False]])
    rgb = png.bary_rgb(bary, mask)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 2, 3)
    assert rgb[0, 0].tolist() == [255, 0, 0]
    assert rgb[0, 1].tolist() == [64, 64, 128]
    assert tuple(rgb[1, 0]) == png.NONFINITE_RGB
    assert tuple(rgb[1, 1]) == png.EMPTY_RGB                  # not covered
    assert (png.bary_rgb(None, mask) == png.EMPTY_RGB).all()
