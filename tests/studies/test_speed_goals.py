"""The speed-goals study (glraster/studies/speed_goals.py) in its short form: every part
runs at tiny sizes, and each goal's met / missed follows from its figure. The figures are
timings and never checked."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from glraster.studies import speed_goals

REPO = Path(__file__).resolve().parents[2]
SHORT = ["--rounds", "1", "--fits", "cube4", "--fit-iterations", "1",
         "--profile-iterations", "1", "--before", str(REPO), "--ab-cases", "cube 4x4",
         "envmap", "--ab-iterations", "2", "--ab-size", "8", "--envmap-resolution", "8",
         "--envmap-mesh", "6", "4", "--envmap-env-size", "4", "--bench-resolutions", "16",
         "--bench-counts", "20", "--bench-repeats", "1", "--texture-sizes", "8",
         "--texture-repeat", "1", "--texture-modes", "linear", "linear-mipmap-linear"]


def test_the_short_form_prints_and_writes_every_goal(gl_backend, tmp_path, capsys):
    out = tmp_path / "goals.json"
    assert speed_goals.main([*SHORT, "--backend", gl_backend, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    goals = json.loads(out.read_text())["goals"]
    assert [g["figure"] for g in goals] == [
        "cube4: iteration / (floors + step)",
        "cube 4x4: iterations/s after / before", "envmap 8²: iterations/s after / before",
        "16², 18 triangles: rasterize det. backward / forward",
        "16², 18 triangles: rasterize atomic backward / forward",
        "16², 18 triangles: rasterize det. / atomic backward",
        "16², 18 triangles: interpolate det. / atomic backward",
        "8² linear: glraster / PyTorch", "8² linear: det. / atomic backward",
        "8² linear-mipmap-linear: glraster / PyTorch",
        "8² linear-mipmap-linear: det. / atomic backward"]
    for g in goals:
        op, target = g["goal"].split()
        value, target = g["value"], float(target)
        assert g["met"] == {"<=": value <= target, ">=": value >= target,
                            "<": value < target}[op], g
    assert f"{sum(g['met'] for g in goals)} of {len(goals)} met" in printed
    for title in ("floors", "fit-iterations-ab", "bench-diff", "texture-baseline"):
        assert title in printed


def test_a_goal_is_met_only_on_its_side():
    assert speed_goals._goal("x", "f", 2.0, ("<=", 2.0))["met"]
    assert not speed_goals._goal("x", "f", 2.01, ("<=", 2.0))["met"]
    assert not speed_goals._goal("x", "f", 1.0, ("<", 1.0))["met"]
    assert speed_goals._goal("x", "f", 4.0, (">=", 4.0))["met"]
    assert not speed_goals._goal("x", "f", 3.99, (">=", 4.0))["met"]


@pytest.mark.parametrize("argv, message", [
    (["--rounds", "0"], "--rounds must be at least 1"),
    (["--texture-sizes", "12"], "--texture-sizes must be powers of two"),
    (["--before", "x", "--before-commit", "y"], "at most one of --before"),
])
def test_bad_options_are_refused(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        speed_goals.main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err
