"""glraster.client without a server: light imports, URL checks, unreachable services."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from glraster.client import Client, ServiceUnavailable, decode_raster, encode_scene


def test_client_imports_neither_moderngl_nor_the_service():
    code = ("import sys, glraster.client; "
            "print(sorted(m for m in ('moderngl', 'glcontext', 'glraster.gpu', 'starlette', "
            "'uvicorn', 'glraster.service') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"


@pytest.mark.parametrize("url", ["127.0.0.1:8642", "ftp://x", "http://"])
def test_bad_url_is_a_value_error(url):
    with pytest.raises(ValueError, match="url"):
        Client(url)


def test_unreachable_service_is_service_unavailable():
    with Client("http://127.0.0.1:9", timeout=5) as c, pytest.raises(ServiceUnavailable):
        c.info()


def test_scene_encoding_keeps_float32_bits():
    pos = np.random.default_rng(0).normal(size=(7, 4)).astype(np.float32)
    body = encode_scene(pos, np.array([[0, 1, 2]]), (3, 5))
    with np.load(__import__("io").BytesIO(body)) as z:
        assert z["pos"].tobytes() == pos.tobytes() and z["tri"].dtype == np.int32
        assert z["resolution"].tolist() == [3, 5]
    from glraster.service.protocol import encode_npz
    from glraster.types import Raster

    r = Raster((2, 2), np.ones((2, 2), bool), depth=np.full((2, 2), 0.25, np.float32))
    back = decode_raster(encode_npz(r, ("depth",), {"comparison": {"ok": True}}))
    assert back.depth.tobytes() == r.depth.tobytes() and back.info["comparison"] == {"ok": True}
