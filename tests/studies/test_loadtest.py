"""glraster.studies.loadtest (`glraster serve-bench`) runs end to end (a smoke run with tiny
counts; figures are never judged) and refuses a URL that is not loopback."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

for _module in ("starlette", "uvicorn", "uvloop"):  # the [service] extra
    pytest.importorskip(_module)


def test_serve_bench_quick_run_writes_its_figures(gl_backend, tmp_path):
    out = tmp_path / "bench.json"
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "serve-bench", "--quick",
                          "--backend", gl_backend, "--memory-requests", "200", "--json",
                          str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    figures = json.loads(out.read_text())
    for name in ("256", "1024"):
        rows = figures["scenes"][name]["load"]
        assert [r["concurrency"] for r in rows] == [1, 4, 16]
        assert all(set(r["statuses"]) == {"200"} for r in rows)
    assert figures["overhead_256"]["service_p50_ms"] > 0
    assert set(figures["sustained"]) == {"256", "1024"}
    assert figures["memory"]["samples"][-1]["requests"] == 200


def test_serve_bench_refuses_a_non_loopback_url(tmp_path):
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "serve-bench", "--url",
                          "http://192.0.2.1:8642"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "loopback" in run.stderr
