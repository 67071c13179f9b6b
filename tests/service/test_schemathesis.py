"""schemathesis, every check, against a real ``glraster serve`` on loopback (with a token,
and without one): the schema says what the server accepts, so schemathesis finds nothing.

What schemathesis checks (``--checks all``): no 5xx; every status, content type, header
and response body as the schema declares; schema-valid requests accepted
(positive_data_acceptance) and schema-invalid ones refused (negative_data_rejection);
missing or ignored authentication refused where the schema declares it; unsupported
methods answered 405 with Allow. The few rules the schema cannot state are kept by
tests/service/schemathesis_hooks.py for valid cases only.

The server's limits are small (64x64, 32 vertices and triangles) so that every valid
request renders in milliseconds; the examples are bounded (a fixed seed) so that a run
takes about 15 s (30 s on a busy machine).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("schemathesis")

from tests.service.conftest import Server  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "schemathesis-test-token-0123456789"
LIMITS = ("--workers", "1", "--queue", "8", "--max-resolution", "64", "--max-vertices", "32",
          "--max-triangles", "32", "--deadline", "30")


def _schemathesis(server: Server, examples: int, token: str | None, tmp_path,
                  phases: str = "coverage,fuzzing") -> str:
    """Run the schemathesis CLI against ``server``; its output (the test fails on any
    failure, with the output)."""
    with server.client() as c:   # warm the worker: the first compare compiles the reference
        import numpy as np

        c.rasterize(np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [0, 1, 0, 1]], np.float32),
                    np.array([[0, 1, 2]]), (8, 8), result="json", compare=True)
    cli = Path(sys.executable).with_name("schemathesis")
    cmd = [str(cli) if cli.exists() else shutil.which("schemathesis") or "schemathesis", "run",
           f"{server.url}/openapi.json", "--checks", "all", "--max-examples", str(examples),
           "--workers", "1", "--seed", "20", "--generation-database", "none", "--no-color",
           "--request-timeout", "120", "--phases", phases]
    if token:
        cmd += ["--header", f"Authorization: Bearer {token}"]
    counts = server.info()["driver"]["sample_counts"]
    env = {**os.environ, "SCHEMATHESIS_HOOKS": "tests.service.schemathesis_hooks",
           "GLRASTER_TEST_SAMPLE_COUNTS": json.dumps(counts),
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=env,
                         timeout=600)
    out = run.stdout + run.stderr
    assert run.returncode == 0 and "No issues found" in out, out[-8000:]
    info = server.info()
    assert all(w["restarts"] == 0 for w in info["workers"]), info["workers"]
    return out


def test_schemathesis_all_checks_with_a_token_finds_nothing(gl_backend, tmp_path):
    token_file = tmp_path / "tokens"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    server = Server(gl_backend, *LIMITS, "--token-file", str(token_file), token=TOKEN,
                    log=tmp_path / "server.log")
    try:
        with server.client() as c:
            import json

            doc = json.loads(c.request("GET", "/openapi.json")[2])
        assert doc["security"] == [{"bearer": []}]
        assert doc["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
        out = _schemathesis(server, 30, TOKEN, tmp_path)
    finally:
        server.stop()
    assert "passed" in out


def test_schemathesis_all_checks_without_a_token_finds_nothing(gl_backend, tmp_path):
    """No token file: the schema declares no authentication, and nothing asks for it."""
    server = Server(gl_backend, *LIMITS, log=tmp_path / "server.log")
    try:
        with server.client() as c:
            import json

            doc = json.loads(c.request("GET", "/openapi.json")[2])
        assert "security" not in doc and "securitySchemes" not in doc["components"]
        # the coverage phase's boundary cases do not depend on auth: the token run has them
        _schemathesis(server, 30, None, tmp_path, phases="fuzzing")
    finally:
        server.stop()
