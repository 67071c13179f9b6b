"""glraster.studies.registry and `glraster study`: every study is listed once and runs by
name; a module study's --help runs nothing; bad names and options are usage errors that name
what was wrong."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from glraster.cli import build_parser, exit_codes, main
from glraster.errors import ArgumentError
from glraster.studies import registry

REPO = Path(__file__).resolve().parents[2]
MODULE_STUDIES = sorted(n for n, s in registry.STUDIES.items() if s.command is None)
COMMAND_STUDIES = sorted(n for n, s in registry.STUDIES.items() if s.command is not None)
# the module an extra installs, for skipping where the extra is absent
EXTRA_MODULE = {"torch": "torch", "service": "prometheus_client", "mesh": "trimesh",
                "jax": "jax"}


def _needs_extra(name: str) -> None:
    extra = registry.STUDIES[name].extra
    if extra:
        pytest.importorskip(EXTRA_MODULE[extra])


def test_every_study_has_a_runner():
    commands = build_parser()._subparsers._group_actions[0].choices
    assert MODULE_STUDIES and COMMAND_STUDIES
    for name, study in registry.STUDIES.items():
        assert study.name == name and study.summary
        assert study.extra in ("", *EXTRA_MODULE), (name, study.extra)
        if study.command is not None:
            assert study.command in commands, (name, study.command)
        else:
            assert importlib.util.find_spec(study.module) is not None, (name, study.module)


def test_the_list_names_every_study_once(capsys):
    assert main(["study", "--list"]) == exit_codes.OK
    lines = capsys.readouterr().out.splitlines()
    assert sorted(line.split()[0] for line in lines) == sorted(registry.STUDIES)
    assert any("(= glraster serve-bench; needs glraster[service])" in line for line in lines)


def test_no_name_prints_the_list_as_a_usage_error(capsys):
    assert main(["study"]) == exit_codes.USAGE
    assert "texture-baseline" in capsys.readouterr().out


@pytest.mark.parametrize("name", MODULE_STUDIES)
def test_a_module_study_help_runs_nothing(name, capsys):
    _needs_extra(name)
    with pytest.raises(SystemExit) as exit_:
        main(["study", name, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: glraster study {name}"), out[:200]


def test_a_command_study_is_its_command(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["study", "stress", "--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith("usage: glraster stress")


def test_an_unknown_study_is_a_usage_error_naming_the_choices(capsys):
    assert main(["study", "nope"]) == exit_codes.USAGE
    err = capsys.readouterr().err
    assert err.startswith("glraster study: error: NAME 'nope' is not a study; choose from ")
    assert "core-figures" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(ArgumentError) as exc:
        registry.get("nope")
    assert exc.value.argument == "NAME"


def test_a_command_study_does_not_run_outside_the_cli():
    with pytest.raises(ArgumentError, match="'glraster bench'"):
        registry.run("bench", [])


@pytest.mark.parametrize("argv, message", [
    (["area-coverage", "--rounds", "0"], "--rounds must be at least 1, got 0"),
    (["area-coverage", "--size", "4"], "--size must be at least 16, got 4"),
    (["core-figures", "--size", "8"], "--size must be at least 16, got 8"),
    (["backend-probe", "--rounds", "0"], "--rounds must be at least 1, got 0"),
    (["diff-antialias-figures", "--repeat", "0"], "--repeat must be at least 1, got 0"),
    (["diff-rasterize-figures", "--repeat", "0"], "--repeat must be at least 1, got 0"),
    (["multisample-cost", "--base", "/nonexistent"], "--base must be a glraster source tree"),
    (["texture-mip-reuse", "--sizes", "12"], "--sizes must be powers of two >= 2, got 12"),
    (["texture-baseline", "--repeat", "0"], "--repeat must be >= 1, got 0"),
    (["metrics-ab", "--rounds", "0"], "--rounds must be at least 1, got 0"),
    (["jax-overhead", "--size", "0"], "--size must be at least 1, got 0"),
    (["torch-overhead", "--before-commit", "HEAD", "--calls", "0"],
     "--calls must be at least 1, got 0"),
])
def test_bad_options_are_usage_errors_naming_the_option(argv, message, capsys):
    _needs_extra(argv[0])
    with pytest.raises(SystemExit) as exit_:
        main(["study", *argv])
    assert exit_.value.code == exit_codes.USAGE
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("name", ["metrics-ab", "service-parse-ab"])
def test_an_ab_study_refuses_a_revision_git_does_not_know(name, capsys):
    _needs_extra(name)
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    assert main(["study", name, "no-such-revision-0123"]) == exit_codes.USAGE
    err = capsys.readouterr().err
    assert "REV 'no-such-revision-0123': git cannot show glraster/service/" in err


def test_a_module_study_runs_as_a_module_too():
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO),
                                                        os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-m", "glraster.studies.area_coverage", "--help"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("usage: glraster study area-coverage")
