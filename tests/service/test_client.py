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


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then closed)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_service_message_names_the_url_and_the_cause():
    """Not "0: cannot reach": the URL, and why (refused, unresolvable host)."""
    url = f"http://127.0.0.1:{_closed_port()}"
    with Client(url, timeout=5) as c, pytest.raises(ServiceUnavailable) as err:
        c.info()
    assert err.value.status == 0
    assert str(err.value).startswith(f"cannot reach the service at {url}: connection refused")
    assert "glraster serve" in str(err.value)
    with Client("http://no-such-host.invalid:8642", timeout=5) as c, \
            pytest.raises(ServiceUnavailable) as err:
        c.info()
    assert str(err.value).startswith("cannot reach the service at "
                                     "http://no-such-host.invalid:8642: the host name "
                                     "'no-such-host.invalid' does not resolve")


def _render(*args, tmp_path):
    return subprocess.run([sys.executable, "-m", "glraster.cli", "render", "tiny_viewport",
                           "-o", str(tmp_path / "out.exr"), *args],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.mark.parametrize("server", ["", "  "])
def test_render_with_an_empty_server_is_a_usage_error(server, tmp_path):
    """`--server ''` used to render locally without a word: now exit 2 naming --server,
    nothing written."""
    run = _render("--server", server, tmp_path=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines() == [
        "glraster render: --server needs the service's URL (http://HOST:PORT), got an empty "
        "string"]
    assert not (tmp_path / "out.exr").exists()


def test_render_with_an_unreachable_server_names_it_and_exits_3(tmp_path):
    url = f"http://127.0.0.1:{_closed_port()}"
    run = _render("--server", url, tmp_path=tmp_path)
    assert run.returncode == 3, run.stderr
    assert run.stderr.strip().splitlines() == [
        f"glraster render: cannot reach the service at {url}: connection refused: nothing "
        f"listens on 127.0.0.1:{url.rsplit(':', 1)[1]} (is glraster serve running there?)"]
    assert not (tmp_path / "out.exr").exists()
