"""`glraster check --shard I/N` splits the catalog across CI runners; `glraster junit-merge`
joins their JUnit files into one (and refuses an incomplete or overlapping set)."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from glraster.conformance import junit
from glraster.conformance.check import CheckResult, SceneResult, _cost, shard_scenes
from glraster.conformance.scenes import list_scenes, load_scene


@pytest.mark.parametrize("count", [1, 2, 3, 4, 7, 40])
def test_shards_cover_every_scene_exactly_once(count):
    names = list_scenes()
    shards = [shard_scenes(names, i, count) for i in range(1, count + 1)]
    flat = [n for s in shards for n in s]
    assert sorted(flat) == sorted(names) and len(flat) == len(names)
    for s in shards:                              # each in catalog order
        assert s == [n for n in names if n in s]
    assert shards == [shard_scenes(names, i, count) for i in range(1, count + 1)]  # stable


def test_shards_are_balanced_by_cost():
    """Longest first onto the least loaded shard: no shard carries more than the largest
    scene plus the mean load."""
    names = list_scenes()
    costs = {n: _cost(load_scene(n)) for n in names}
    for count in (2, 3, 4):
        loads = [sum(costs[n] for n in shard_scenes(names, i, count)) for i in range(1, count + 1)]
        assert max(loads) <= max(costs.values()) + sum(costs.values()) / count


@pytest.mark.parametrize("bad", [(0, 2), (3, 2), (1, 0)])
def test_bad_shard_is_a_value_error(bad):
    with pytest.raises(ValueError, match="shard"):
        shard_scenes(list_scenes(), *bad)


def _fake_run(names, shard, backend="egl", failing=()):
    result = CheckResult(backend, "llvmpipe (fake)", "4.5", "hw", shard=shard)
    for n in names:
        s = SceneResult(n, "", (4, 4), 1, status="fail" if n in failing else "pass")
        s.timings["gpu"] = 0.5
        if n in failing:
            s.failures.append("1 coverage mismatches outside the edge band")
        result.scenes.append(s)
    return junit.to_xml(result)


def test_merge_rebuilds_one_suite_per_driver():
    names = list_scenes()
    trees = [_fake_run(shard_scenes(names, i, 3), (i, 3), backend)
             for backend in ("egl", "osmesa") for i in (1, 2, 3)]
    root = junit.merge(trees).getroot()
    suites = root.findall("testsuite")
    assert len(suites) == 2
    for suite, backend in zip(suites, ("egl", "osmesa")):
        cases = [c.get("name") for c in suite.iter("testcase")]
        assert sorted(cases) == sorted(names)
        assert suite.get("tests") == str(len(names)) and suite.get("failures") == "0"
        props = {p.get("name"): p.get("value") for p in suite.iter("property")}
        assert props["backend"] == backend and props["shards"] == "3" and "shard" not in props
    assert root.get("tests") == str(2 * len(names))


def test_merge_refuses_missing_duplicate_and_overlapping_shards():
    names = list_scenes()
    one, two = (_fake_run(shard_scenes(names, i, 2), (i, 2)) for i in (1, 2))
    with pytest.raises(junit.MergeError, match=r"shards \[2\] of 2 missing"):
        junit.merge([one])
    with pytest.raises(junit.MergeError, match="given twice"):
        junit.merge([one, two, one])
    with pytest.raises(junit.MergeError, match="appears twice"):
        junit.merge([_fake_run(names[:3], (1, 2)), _fake_run(names[2:], (2, 2))])


def test_merge_command_fails_on_failed_cases_and_writes_the_file(tmp_path):
    names = list_scenes()
    files = []
    for i in (1, 2):
        path = tmp_path / f"junit-{i}.xml"
        tree = _fake_run(shard_scenes(names, i, 2), (i, 2), failing=("torus",))
        junit.write_tree(tree, path)
        files.append(str(path))
    out = tmp_path / "merged.xml"
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "junit-merge", *files, "-o",
                          str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1, run.stderr
    assert ET.parse(out).getroot().get("failures") == "1"
    run = subprocess.run([sys.executable, "-m", "glraster.cli", "junit-merge", files[0], "-o",
                          str(tmp_path / "partial.xml")], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 1 and "missing" in run.stderr
    assert not (tmp_path / "partial.xml").exists()


def test_merge_refuses_a_file_that_is_not_junit_naming_it(tmp_path, capsys):
    """Another XML file among the inputs (or no XML at all) is bad input naming the file
    (exit 2), not an empty merge that a CI job would read as passing."""
    from glraster.cli import main

    (tmp_path / "coverage.xml").write_text("<coverage/>")
    (tmp_path / "empty.xml").write_text("")
    for name, words in (("coverage.xml", "not a JUnit file (its root element is <coverage>"),
                        ("empty.xml", "not well-formed XML (no element found")):
        assert main(["junit-merge", str(tmp_path / name), "-o",
                     str(tmp_path / "merged.xml")]) == 2
        err = capsys.readouterr().err
        assert f"argument JUNIT.xml: {tmp_path / name}: {words}" in err, err
    assert not (tmp_path / "merged.xml").exists()


def test_sharded_check_runs_merge_into_the_unsharded_run(gl_backend, tmp_path):
    """Three shards of a real check (with the mutant pass in shard 1) merge into the cases
    of one unsharded run."""
    pattern = "basic_*,fan_*,quad_shared_diagonal,pixel_center_edges,tiny_viewport"
    files = []
    for i in (1, 2, 3):
        path = tmp_path / f"j{i}.xml"
        run = subprocess.run([sys.executable, "-m", "glraster.cli", "check", "--backend",
                              gl_backend, "--scenes", pattern, "--shard", f"{i}/3", "--junit",
                              str(path), "--mutants", "no_half_pixel*"],
                             capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
        files.append(str(path))
    root = junit.merge(files).getroot()
    cases = sorted(c.get("name") for s in root.findall("testsuite")
                   if s.get("name") == "glraster.conformance.check" for c in s.iter("testcase"))
    assert cases == sorted(list_scenes(pattern))
    mutant_suites = [s for s in root.findall("testsuite")
                     if s.get("name") == "glraster.conformance.mutants"]
    assert len(mutant_suites) == 1 and mutant_suites[0].get("failures") == "0"
    assert root.get("failures") == "0" and root.get("errors") == "0"
