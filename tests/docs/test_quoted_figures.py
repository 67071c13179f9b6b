"""The figures and messages the docs quote are what glraster prints today.

Each test first asserts that the doc still quotes the figure (so a reworded page fails here
and points at the figure to re-check), then produces it: an error message raised by the
code, or a figure printed by a cheap command (seconds). A figure written in the docs with
n significant digits must equal the command's value rounded to n significant digits.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

import glraster as gr
from glraster import camera as cam
from glraster.conformance import mutants
from glraster.conformance.scenes import load_scene_file
from glraster import validate
from tests.docs import markdown_blocks as mb


def doc(name: str) -> str:
    return (mb.REPO / name).read_text()


def assert_quoted(name: str, text: str) -> None:
    # Line breaks and indentation in the Markdown do not count.
    flat = re.sub(r"\s+", " ", doc(name))
    assert re.sub(r"\s+", " ", text) in flat, f"{name} no longer quotes {text!r}"


def assert_same_figure(written: str, value: float, where: str) -> None:
    """``written`` ("7.8e-8", "0.14", "51") is ``value`` rounded to its significant digits."""
    digits = len(Decimal(written).as_tuple().digits)
    rounded = float(f"{value:.{digits}g}")
    assert np.isclose(rounded, float(written), rtol=1e-12, atol=0), (
        f"{where} says {written}, the command prints {value:.6g} (rounded: {rounded:g})")


def glraster_command(*args: str, cwd: Path) -> str:
    env = dict(os.environ, PYTHONPATH=str(mb.REPO), MPLBACKEND="Agg")
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    done = subprocess.run(["glraster", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, f"glraster {' '.join(args)} exited {done.returncode}:\n" \
                                 f"{done.stdout[-3000:]}{done.stderr[-3000:]}"
    return done.stdout


def raised(call) -> str:
    with pytest.raises(ValueError) as info:
        call()
    return str(info.value)


# -- error messages (no GL) -----------------------------------------------------------

def test_quoted_validation_messages_are_the_ones_raised(tmp_path, monkeypatch):
    tri = np.array([[0, 1, 2]])
    three = np.zeros((3, 4))
    cases = [
        ("README.md", "pos must have shape (V, 4), got (5, 3)",
         lambda: gr.reference.rasterize(np.zeros((5, 3)), tri, (8, 8))),
        ("docs/service.md", "tri index 7 is out of range for pos with 3 vertices",
         lambda: gr.reference.rasterize(three, [[0, 1, 7]], (8, 8))),
        ("docs/cameras.md", "K must have shape (3, 3), got (2, 3)",
         lambda: cam.from_intrinsics([[1, 0, 0], [0, 1, 0]], 64, 48, near=0.1, far=10)),
        ("docs/differentiable.md", "pos must have shape (V, 4) or (B, V, 4), got (5, 3)",
         lambda: validate.batched_positions(np.zeros((5, 3)))),
        ("docs/differentiable.md",
         "ranges row 0 = [1, 3] reaches triangle 3, beyond tri's 3 triangles",
         lambda: validate.ranges(np.array([[1, 3]]), 3, 2)),
        ("docs/differentiable.md", "grad_rast must have shape (1, 24, 32, 4), got",
         lambda: validate.image("grad_rast", np.zeros((1, 24, 32, 3)), (1, 24, 32, 4))),
    ]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.json").write_text(json.dumps(
        {"pos": [[0, 0, 0, 1], [1, 0, 0, 1], [0, 1, 0, 1]], "tri": [[0, 1, 3]],
         "resolution": [8, 8]}))
    cases.append(("docs/conformance.md",
                  "scene.json: tri index 3 is out of range for pos with 3 vertices",
                  lambda: load_scene_file("scene.json")))
    for name, quoted, call in cases:
        assert_quoted(name, quoted)
        assert quoted in raised(call), f"{name} quotes {quoted!r}; the code says otherwise"


def test_catalog_and_mutant_counts_match_the_readme(tmp_path):
    scenes = glraster_command("check", "--list", cwd=tmp_path).strip().splitlines()
    assert_quoted("README.md", f"`glraster check` renders {len(scenes)} catalog scenes")
    assert_quoted("README.md", f"{len(scenes)}/{len(scenes)} scenes pass via EGL and OSMesa")
    assert_quoted("README.md", f"all {len(mutants.MUTANTS)} fault-injection mutants")


# -- figures printed by commands (GL) -------------------------------------------------

@pytest.mark.gl
def test_probe_count_quoted_for_the_drivers_is_what_check_prints(tmp_path):
    out = glraster_command("check", "--scenes", "tiny_viewport", "--no-golden", cwd=tmp_path)
    printed = re.search(r"probes \((\d+/\d+ ok)\)", out)
    assert printed, out
    assert_quoted("docs/drivers.md", f'"probes ({printed.group(1)})", nine PASS and '
                                     "`noperspective_clip`, `sample_perspective` and "
                                     "`centroid` KNOWN")
    statuses = dict(re.findall(r"^  (\w+) +(PASS|KNOWN|FAIL|SKIPPED) ", out, re.MULTILINE))
    for known in ("noperspective_clip", "sample_perspective", "centroid"):
        assert statuses.pop(known) == "KNOWN", out
    assert list(statuses.values()) == ["PASS"] * 9, statuses


@pytest.mark.gl
def test_crosscheck_figures_are_what_the_command_prints(tmp_path):
    out = glraster_command("crosscheck", "pyrender", cwd=tmp_path)
    median, p99, largest, steps = map(float, re.search(
        r"relative depth difference: median (\S+), p99 (\S+), max (\S+) at .*?\((\S+) steps",
        out).groups())
    reference_max, bound_fraction = map(float, re.search(
        r"pyrender against the float64 reference: median \S+, max (\S+) = (\S+) of the", out)
        .groups())
    center = float(re.search(r"median by glraster sample position: center: (\S+),", out)
                   .group(1))
    readme = ("README.md", "the median relative difference is 7.8e-8 and the max 3.3e-7 "
              "(5.4 steps of pyrender's 24-bit depth); pyrender against the float64 "
              "reference: max 3.5e-7, 0.14 of the error-model bound")
    assert_quoted(*readme)
    for written, value in [("7.8e-8", median), ("3.3e-7", largest), ("5.4", steps),
                           ("3.5e-7", reference_max), ("0.14", bound_fraction),
                           ("5e-4", center)]:
        assert_same_figure(written, value, "README.md (crosscheck)")
    table = ("docs/cameras.md", "| glraster at MSAA sample 0 (chosen) | **7.8e-8** | 2.2e-7 | "
             "**3.3e-7** (5.4 steps of 24-bit depth) |")
    assert_quoted(*table)
    assert_same_figure("2.2e-7", p99, "docs/cameras.md (crosscheck p99)")
    assert_quoted("docs/cameras.md", "| pyrender against the float64 reference | 5.8e-8 | | "
                                     "3.5e-7 = 0.14 of the error bound |")
    assert_quoted("docs/cameras.md", "| glraster at pixel centers | 5.0e-4 | | |")
    assert_same_figure("5.0e-4", center, "docs/cameras.md (pixel centers)")


@pytest.mark.gl
def test_distortion_figures_are_what_the_command_prints(tmp_path):
    glraster_command("distortion", "--out", "fig", cwd=tmp_path)
    summary = json.loads((tmp_path / "fig" / "summary.json").read_text())
    plane, cube = summary["scenes"]["plane"], summary["scenes"]["cube"]
    assert_quoted("README.md", "the affine uv is off by up to 4.35 checker squares on the "
                               "plane (51 % of pixels change color), 1.33 on the cube")
    assert_same_figure("4.35", plane["max_uv_error"], "README.md (plane)")
    assert_same_figure("51", 100 * plane["pixels_changed"], "README.md (plane)")
    assert_same_figure("1.33", cube["max_uv_error"], "README.md (cube)")
    assert_quoted("docs/distortion.md", "| plane | 4.35 checker squares | 2.44 | 51 % |")
    assert_quoted("docs/distortion.md", "| cube | 1.33 checker squares | 0.53 | 38 % |")
    for written, value in [("2.44", plane["mean_uv_error"]), ("0.53", cube["mean_uv_error"]),
                           ("38", 100 * cube["pixels_changed"])]:
        assert_same_figure(written, value, "docs/distortion.md")
    gpu = summary["segment_example"]["gpu"]
    assert_quoted("README.md", "(GPU: 4.5000000 against 4.0000000)")
    assert f"{gpu['affine_depth']:.7f} against {gpu['correct_depth']:.7f}" \
        == "4.5000000 against 4.0000000"
    assert f"{gpu['screen_weight_B']:.7f}" == "0.8333333"


def test_files_the_docs_name_exist():
    named = re.compile(r"(?<![\w/.$-])(?:tests|glraster|shaders|scripts|benchmarks|deploy|golden)/"
                       r"[A-Za-z0-9_/.-]*[A-Za-z0-9_]")
    missing = [f"{mb.relative(path)}: {name}" for path in mb.documented_files()
               for name in sorted(set(named.findall(path.read_text())))
               if not (mb.REPO / name).exists()]
    assert not missing, "the docs name files that do not exist:\n" + "\n".join(missing)


def test_golden_size_and_exit_codes_match_the_readme():
    from glraster.cli import exit_codes

    size = sum(p.stat().st_size for p in (mb.REPO / "golden").rglob("*.exr")) / 2**20
    assert_quoted("README.md", "the goldens take 13.9 MiB")
    assert_same_figure("13.9", size, "README.md (golden size, MiB)")
    assert_quoted("docs/conformance.md", "in 13.9 MiB (budget: 20 MiB)")
    assert size <= 20
    codes = (exit_codes.OK, exit_codes.FAIL, exit_codes.USAGE, exit_codes.NO_BACKEND)
    assert_quoted("README.md", "Exit codes: {} pass, {} fail, {} bad input, {} no GL "
                               "backend".format(*codes))
