"""CLI one-line errors name the option at fault from the error's ``.argument``."""

from __future__ import annotations

import argparse

import pytest

from glraster.cli import build_parser, exit_codes, main
from glraster.cli.errors import describe, options_of
from glraster.errors import ArgumentError


def _args(*argv):
    return build_parser().parse_args(list(argv))


def test_options_are_spelled_as_typed():
    args = _args("render", "torus", "-o", "x.exr")
    assert args.cli_options["output"] == "-o/--output"
    assert args.cli_options["token_file"] == "--token-file"
    assert args.cli_options["scene"] == "SCENE_OR_FILE"
    nested = _args("fit", "cube", "--out", "o")    # a subcommand of a subcommand
    assert nested.cli_options["resolutions"] == "--resolutions"


@pytest.mark.parametrize("exc, expected", [
    (ArgumentError("outputs", "outputs has unknown names ['x']"),
     "argument --outputs: outputs has unknown names ['x']"),
    (ArgumentError("output", "output must end in .exr, got 'x.png'"),
     "argument -o/--output: output must end in .exr, got 'x.png'"),
    # the message already starts with the option: unchanged
    (ArgumentError("--server", "--server needs the service's URL"),
     "--server needs the service's URL"),
    # an argument the command line does not have (a scene's pos): the message alone
    (ArgumentError("pos", "pos must have shape (V, 4), got (3, 3)"),
     "pos must have shape (V, 4), got (3, 3)"),
    # a plain ValueError carries no argument: its wording is not read
    (ValueError("outputs has unknown names"), "outputs has unknown names"),
])
def test_describe_names_the_option_from_the_argument(exc, expected):
    assert describe(exc, _args("render", "torus", "-o", "x.exr")) == expected


def test_describe_without_a_command_line():
    assert describe(ArgumentError("outputs", "outputs is bad")) == "outputs is bad"
    parser = argparse.ArgumentParser()
    parser.add_argument("--max-body", type=int)
    assert options_of(parser) == {"max_body": "--max-body"}


def test_render_with_an_unknown_output_names_the_option(capsys, tmp_path):
    code = main(["render", "torus", "-o", str(tmp_path / "x.exr"), "--outputs", "persp,normal"])
    err = capsys.readouterr().err.strip()
    assert code == exit_codes.USAGE
    assert err.splitlines() == [
        "glraster render: argument --outputs: outputs has unknown names ['normal']; choose "
        "from ('persp', 'screen', 'depth', 'tri_id')"]
    assert not (tmp_path / "x.exr").exists()


def test_an_option_check_of_the_cli_is_one_line_naming_the_option(capsys, tmp_path):
    code = main(["antialias-study", "--out", str(tmp_path / "o"), "--size", "8"])
    assert code == exit_codes.USAGE
    assert capsys.readouterr().err.strip() == (
        "glraster antialias-study: error: --size must be at least 16 pixels, got 8")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, line", [
    (["distortion", "--width", "0"], "glraster distortion: error: --width must be >= 1, got 0"),
    (["distortion", "--supersample", "0"],
     "glraster distortion: error: --supersample must be >= 1, got 0"),
    (["distortion", "--height", "100000"],
     "glraster distortion: error: --height 100000 x --supersample 3 = 300000 pixels exceeds "
     "the driver's maximum of {limit}"),
    (["serve", "--queue", "-1"],
     "glraster serve: error: argument --queue: queue_size must be an integer >= 0, got -1"),
    # crosscheck named "resolution[1]", which its command line does not have
    (["crosscheck", "pyrender", "--width", "0"],
     "glraster crosscheck: error: --width must be >= 1, got 0"),
    (["crosscheck", "pyrender", "--margin", "-1"],
     "glraster crosscheck: error: --margin must be >= 0, got -1"),
])
def test_size_and_service_options_are_named_in_their_errors(argv, line, capsys, tmp_path,
                                                            gl_context, monkeypatch):
    """The panels of `distortion` are --width x --height each, rendered at --supersample
    times that: an error names those options, not the internal aspect or resolution."""
    monkeypatch.setenv("GLRASTER_BACKEND", gl_context.backend)
    assert main([*argv, *(["--out", str(tmp_path / "d")] if argv[0] == "distortion" else [])]) \
        == exit_codes.USAGE
    assert capsys.readouterr().err.strip() == line.format(limit=gl_context.max_texture_size)
    assert not (tmp_path / "d").exists()


LIST_METAVARS = {"LIST", "PATTERN", "A,B", "M1,M2"}


def _list_options():
    """(command words, option) of every option of every command whose help says it takes a
    comma-separated list, with its argparse action."""
    found = []

    def walk(parser, words):
        for action in parser._actions:   # argparse offers no public list of them
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, words + [name])
            elif action.option_strings and ("comma-separated" in (action.help or "")
                                            or action.metavar in LIST_METAVARS):
                found.append((words, action))

    walk(build_parser(), [])
    return found


def test_every_comma_separated_option_refuses_an_empty_list():
    """An option given an empty list ('', ',') used to read as the option left out (--scenes
    "$UNSET" ran the whole catalog); every such option is now a comma_list, and so is
    every one a new command adds."""
    from glraster.cli.commands import comma_list

    options = _list_options()
    assert len(options) >= 9
    assert [f"{' '.join(w)} {a.option_strings[-1]}" for w, a in options
            if a.type is not comma_list] == []


@pytest.mark.parametrize("words, option, value", [
    (["check"], "--scenes", ""), (["check", "--ray"], "--drivers", ","),
    (["check", "--ray"], "--methods", " "), (["check"], "--mutants", ""),
    (["render", "torus", "-o", "x.npz"], "--outputs", ","), (["bench"], "--methods", ""),
    (["stress"], "--sweeps", ""), (["stress"], "--methods", ", ,"),
    (["batch", "in", "out"], "--outputs", ""),
])
def test_an_empty_list_is_a_usage_error_naming_the_option(capsys, tmp_path, monkeypatch,
                                                          words, option, value):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main([*words, option, value])
    assert exit_.value.code == exit_codes.USAGE
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        f"error: argument {option}: lists nothing (got {value!r}): name at least one")
    assert list(tmp_path.iterdir()) == []


def _float_options():
    """(command words, option) of every option of every command that takes a number with
    a fraction (its argparse type parses a float)."""
    from glraster.cli.commands import non_negative_float, positive_float

    found = []

    def walk(parser, words):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, words + [name])
            elif action.type in (float, positive_float, non_negative_float):
                found.append((words, action))

    walk(build_parser(), [])
    return found


def test_every_float_option_is_checked_as_it_is_parsed():
    """A bare ``type=float`` takes nan, inf and negative values: serve started with a
    --drain-timeout of -2, and crosscheck judged a median against nan. Every float option
    is positive_float or non_negative_float, so each new one is too."""
    from glraster.cli.commands import non_negative_float, positive_float

    options = _float_options()
    assert len(options) >= 10
    assert [f"{' '.join(w)} {a.option_strings[-1]}" for w, a in options
            if a.type not in (positive_float, non_negative_float)] == []


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "x"])
def test_a_float_option_refuses_what_is_not_a_finite_number_in_range(value, capsys):
    for words, action in _float_options():
        option = action.option_strings[-1]
        with pytest.raises(SystemExit) as exit_:
            build_parser().parse_args([*words, option, value])
        assert exit_.value.code == exit_codes.USAGE
        assert capsys.readouterr().err.splitlines()[-1].endswith(
            f"error: argument {option}: must be a finite number "
            f"{'>' if action.type.__name__ == 'positive_float' else '>='} 0, got {value!r}")
    # 0 is the boundary: refused where the option must be > 0, taken where >= 0
    assert build_parser().parse_args(["serve", "--drain-timeout", "0"]).drain_timeout == 0.0
    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve", "--deadline", "0"])
