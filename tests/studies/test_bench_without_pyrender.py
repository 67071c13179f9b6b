"""`glraster bench` without its pyrender peer: --no-pyrender skips it everywhere (the
headline figures included), and a missing pyrender is a usage error said at once."""

from __future__ import annotations

import pytest

from glraster.cli import exit_codes, main
from glraster.studies import bench


def test_the_headline_without_pyrender_has_no_peer(ctx):
    head = bench.headline(backend=ctx.backend, repeats=2, resolution=(48, 64), count=50,
                          with_pyrender=False)
    assert head["pyrender"] is None
    assert head["hw_ms"] > 0 and head["hw_over_fill"]["pairs"] == 2


def test_a_missing_pyrender_is_a_usage_error_before_any_work(monkeypatch, capsys):
    monkeypatch.setattr(bench, "pyrender_installed", lambda: False)
    monkeypatch.setattr(bench, "run", lambda *a, **k: pytest.fail("bench ran"))
    assert main(["bench", "--quick"]) == exit_codes.USAGE
    err = capsys.readouterr().err
    assert "pip install 'glraster[mesh]'" in err and "--no-pyrender" in err
    assert "Traceback" not in err


def test_no_pyrender_is_passed_on_to_every_part(monkeypatch):
    seen = {}

    def fake_run(preset, *, with_pyrender, **_):
        seen["with_pyrender"] = with_pyrender
        raise ValueError("stop here")   # the CLI turns it into a usage error

    monkeypatch.setattr(bench, "pyrender_installed", lambda: False)
    monkeypatch.setattr(bench, "run", fake_run)
    assert main(["bench", "--quick", "--no-pyrender"]) == exit_codes.USAGE
    assert seen == {"with_pyrender": False}


def test_pyrender_installed_looks_for_both_packages(monkeypatch):
    import importlib.util

    found = {"pyrender": object(), "trimesh": None}
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: found.get(name))
    assert not bench.pyrender_installed()
    found["trimesh"] = object()
    assert bench.pyrender_installed()


def test_run_hands_with_pyrender_to_the_headline(gl_backend, monkeypatch):
    seen = {}
    monkeypatch.setattr(bench, "headline", lambda **kw: seen.update(kw) or {})
    monkeypatch.setattr(bench, "skips", lambda **kw: {})
    bench.run("quick", backend=gl_backend, with_pyrender=False, methods=("hw",),
              resolutions=(16,), counts=(4,), repeats=1)
    assert seen["with_pyrender"] is False
