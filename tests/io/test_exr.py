"""glraster EXR files: exact round trip, layout, orientation, windows, atomic writes."""

import numpy as np
import OpenImageIO as oiio
import pytest

from glraster.io import exr


def sample(h=6, w=5, seed=0):
    rng = np.random.default_rng(seed)
    persp = rng.random((h, w, 3)).astype(np.float32)
    screen = rng.random((h, w, 3)).astype(np.float32)
    depth = rng.random((h, w)).astype(np.float32)
    tri = rng.integers(-1, 100, (h, w)).astype(np.int64)
    return persp, screen, depth, tri


def bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def test_round_trip_is_bit_exact_including_huge_ids(tmp_path):
    persp, screen, depth, tri = sample()
    # ids past 2^24 are not representable in float32: the UINT channel must keep them.
    tri[0, 0], tri[1, 1], tri[2, 2] = 2**24 + 1, 2**31 + 7, 2**32 - 2
    persp[3, 3] = [np.float32(1e-38), -0.0, np.float32(1 - 2**-24)]
    p = exr.write_raster(tmp_path / "a.exr", persp=persp, screen=screen, depth=depth,
                         tri_id=tri, window="full", metadata={"scene": "x"})
    r = exr.read_raster(p)
    # Tolerance: none; the format is lossless and ids are integers.
    assert np.array_equal(bits(r.persp), bits(persp))
    assert np.array_equal(bits(r.screen), bits(screen))
    assert np.array_equal(bits(r.depth), bits(depth))
    assert np.array_equal(r.tri_id, tri)
    assert r.metadata["scene"] == "x" and r.metadata["version"]


def test_channels_formats_compression_and_upright_rows(tmp_path):
    persp, screen, depth, tri = sample(4, 3)
    depth = np.arange(12, dtype=np.float32).reshape(4, 3)   # row 0 (bottom) = 0, 1, 2
    p = exr.write_raster(tmp_path / "b.exr", persp=persp, screen=screen, depth=depth,
                         tri_id=tri, window="full")
    inp = oiio.ImageInput.open(str(p))
    inp.seek_subimage(0, 0)
    s0 = inp.spec()
    assert set(s0.channelnames) == {"persp.b0", "persp.b1", "persp.b2", "screen.b0",
                                    "screen.b1", "screen.b2", "depth.Z"}
    assert all(f == oiio.FLOAT for f in (s0.channelformats or [s0.format]))
    assert s0.get_string_attribute("compression") == "zip"
    assert "upright" in s0.get_string_attribute("glraster:orientation")
    z = inp.read_image(0, 0, 0, s0.nchannels, "float")
    zc = list(s0.channelnames).index("depth.Z")
    # File row 0 is the top: the array's last row.
    assert np.array_equal(z[0, :, zc], depth[-1])
    assert np.array_equal(z[-1, :, zc], depth[0])
    inp.seek_subimage(1, 0)
    s1 = inp.spec()
    assert s1.channelnames == ("tri_id.id",) and s1.format == oiio.UINT
    inp.close()


def test_covered_window_crops_losslessly(tmp_path):
    h, w = 40, 50
    tri = np.full((h, w), -1, np.int64)
    tri[10:20, 30:35] = 7
    persp = np.zeros((h, w, 3), np.float32)
    persp[tri >= 0] = [0.25, 0.25, 0.5]
    depth = np.where(tri >= 0, 0.5, 1.0).astype(np.float32)
    p = exr.write_raster(tmp_path / "c.exr", persp=persp, depth=depth, tri_id=tri)
    r = exr.read_raster(p)
    assert r.window == (10, 20, 30, 35) and r.resolution == (h, w)
    assert r.persp.shape == (10, 5, 3)
    assert np.array_equal(r.full("tri_id"), tri)
    assert np.array_equal(r.full("persp"), persp)
    assert np.array_equal(r.full("depth"), depth)
    assert r.screen is None
    with pytest.raises(ValueError, match="no 'screen'"):
        r.full("screen")


def test_empty_image_gets_a_one_pixel_window(tmp_path):
    tri = np.full((8, 8), -1, np.int64)
    r = exr.read_raster(exr.write_raster(tmp_path / "e.exr", tri_id=tri))
    assert r.window == (0, 1, 0, 1)
    assert np.array_equal(r.full("tri_id"), tri)


def test_write_is_atomic(tmp_path, monkeypatch):
    persp, screen, depth, tri = sample()
    target = tmp_path / "d.exr"
    exr.write_raster(target, persp=persp, tri_id=tri)
    before = target.read_bytes()

    real = oiio.ImageOutput

    class Broken:
        @staticmethod
        def create(name):
            out = real.create(name)

            class Wrapper:
                def open(self, *a):
                    return out.open(*a)

                def write_image(self, data):
                    return False        # simulate a failed write half way

                def close(self):
                    return out.close()

                def geterror(self):
                    return "simulated failure"
            return Wrapper()

    monkeypatch.setattr(exr.oiio, "ImageOutput", Broken)
    with pytest.raises(OSError, match="simulated failure"):
        exr.write_raster(target, persp=persp * 0, tri_id=tri)
    assert target.read_bytes() == before                    # old file untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.exr"]   # no temp left


@pytest.mark.parametrize("kwargs, message", [
    ({}, "at least one"),
    ({"persp": np.zeros((4, 4, 2), np.float32)}, "persp must have shape"),
    ({"depth": np.zeros((4, 4)), "tri_id": np.zeros((4, 5), np.int32)}, "share one"),
    ({"tri_id": np.zeros((4, 4), np.float32)}, "integer dtype"),
    ({"tri_id": np.full((4, 4), -2)}, "tri_id values"),
    ({"depth": np.zeros((4, 4)), "window": (0, 5, 0, 4)}, "window"),
])
def test_write_rejects_bad_input(tmp_path, kwargs, message):
    with pytest.raises(ValueError, match=message):
        exr.write_raster(tmp_path / "x.exr", **kwargs)


def test_read_rejects_foreign_files(tmp_path):
    (tmp_path / "n.exr").write_bytes(b"not an exr")
    with pytest.raises(ValueError, match="cannot open"):
        exr.read_raster(tmp_path / "n.exr")
    spec = oiio.ImageSpec(2, 2, 1, oiio.FLOAT)
    spec.channelnames = ("Y",)
    out = oiio.ImageOutput.create(str(tmp_path / "y.exr"))
    out.open(str(tmp_path / "y.exr"), spec)
    out.write_image(np.zeros((2, 2, 1), np.float32))
    out.close()
    with pytest.raises(ValueError, match="no glraster channels"):
        exr.read_raster(tmp_path / "y.exr")
