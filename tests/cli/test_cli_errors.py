"""Every CLI error is one line on stderr and an exit code of glraster.cli.exit_codes:
bind failures of `glraster serve`, a closed stdout pipe, Ctrl-C while files are written."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from glraster.cli import exit_codes

REPO = Path(__file__).resolve().parents[2]


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO),
                                                         os.environ.get("PYTHONPATH", "")])}


def _glraster(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "glraster.cli", *args], capture_output=True,
                          text=True, env=_env(), cwd=cwd, timeout=timeout)


def _one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    return lines[0]


@pytest.fixture
def busy_port():
    """A port that a socket of this process holds (listening)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(1)
    yield sock.getsockname()[1]
    sock.close()


def test_serve_on_a_busy_port_is_one_line_and_exit_2(busy_port):
    pytest.importorskip("uvicorn")
    result = _glraster("serve", "--port", str(busy_port), "--workers", "1")
    assert result.returncode == exit_codes.USAGE, result.stderr
    line = _one_line(result.stderr)
    assert line == (f"glraster serve: cannot listen on 127.0.0.1:{busy_port}: the port is in "
                    "use by another process; pick another --port (--port 0: any free one)")
    assert result.stdout == "", "nothing announced: the service never started"


def test_serve_on_a_host_that_does_not_resolve_is_one_line_and_exit_2():
    pytest.importorskip("uvicorn")
    # .invalid never resolves (RFC 2606)
    result = _glraster("serve", "--host", "no-such-host.invalid", "--port", "0",
                       "--workers", "1")
    assert result.returncode == exit_codes.USAGE, result.stderr
    line = _one_line(result.stderr)
    assert line.startswith("glraster serve: cannot listen on no-such-host.invalid:0: --host "
                           "'no-such-host.invalid' does not resolve")
    assert "without --token-file" not in line, "no warning for a service that never listens"


def test_a_closed_stdout_pipe_ends_quietly():
    """`glraster check --list | head -1`: the reader is gone before glraster writes."""
    proc = subprocess.Popen([sys.executable, "-m", "glraster.cli", "check", "--list"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env())
    proc.stdout.close()
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == exit_codes.BROKEN_PIPE
    assert stderr == "", stderr


def test_head_reading_one_line_of_the_list_leaves_no_traceback():
    result = subprocess.run(["bash", "-o", "pipefail", "-c",
                             f"{sys.executable} -m glraster.cli check --list | head -1"],
                            capture_output=True, text=True, env=_env(), timeout=120)
    assert result.stderr == "", result.stderr
    assert len(result.stdout.splitlines()) == 1
    assert result.returncode in (exit_codes.OK, exit_codes.BROKEN_PIPE)


def test_an_unwritable_output_is_one_line_naming_the_file(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a folder")
    out = blocker / "x.exr"
    result = _glraster("render", "basic_triangle", "--reference", "-o", str(out))
    assert result.returncode == exit_codes.USAGE
    assert _one_line(result.stderr) == (f"glraster render: error: argument -o/--output: "
                                        f"cannot write {out} ({blocker} is a file, not a "
                                        f"folder)")


# SIGINT at the worst moment: the EXR is fully written to its temporary file, which is
# about to be renamed over the target (atomic_write's chmod comes just before the rename).
INTERRUPT_MID_WRITE = """
import os, signal, sys
real_chmod = os.chmod
def chmod_then_ctrl_c(path, mode, *args, **kwargs):
    real_chmod(path, mode, *args, **kwargs)
    os.kill(os.getpid(), signal.SIGINT)
os.chmod = chmod_then_ctrl_c
from glraster.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_while_writing_leaves_no_file_and_exits_130(tmp_path):
    result = subprocess.run([sys.executable, "-c", INTERRUPT_MID_WRITE, "render",
                             "basic_triangle", "--reference", "-o", "x.exr", "--png", "x.png"],
                            capture_output=True, text=True, env=_env(), cwd=tmp_path,
                            timeout=120)
    assert result.returncode == exit_codes.INTERRUPTED, result.stderr
    assert _one_line(result.stderr) == "glraster: interrupted"
    assert sorted(os.listdir(tmp_path)) == [], "no x.exr, no temporary file"


@pytest.mark.parametrize("signum, code, said", [
    (signal.SIGINT, exit_codes.INTERRUPTED, "glraster: interrupted"),
    (signal.SIGTERM, exit_codes.TERMINATED, "glraster: terminated")])
def test_a_signal_from_outside_during_a_write_leaves_no_file(tmp_path, signum, code, said):
    """A real Ctrl-C, or the SIGTERM of a CI job cancelled or timed out (it killed the
    process at once and left the temporary file), from another process, sent as soon as
    the EXR's temporary file appears (1024x1024, eight float channels: the write takes a
    while)."""
    pos = np.array([[-1, -1, 0, 1], [3, -1, 0, 1], [-1, 3, 0, 1]], np.float32)
    np.savez(tmp_path / "scene.npz", pos=pos, tri=np.array([[0, 1, 2]]),
             resolution=np.array([1024, 1024]))
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "glraster.cli", "render",
                             str(tmp_path / "scene.npz"), "--reference", "-o", "big.exr"],
                            cwd=out, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env())
    deadline = time.monotonic() + 300
    while not os.listdir(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    assert proc.poll() is None, "the render ended before its write was seen"
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, stderr
    assert _one_line(stderr.decode()) == said
    assert os.listdir(out) == [], "the interrupted write left nothing behind"


def test_render_writes_the_exr_and_its_preview_or_neither(tmp_path):
    """A preview that cannot be written (its folder is a file) fails the render (exit 2)
    without leaving the EXR behind; a preview whose name is not .png is refused before
    anything is rendered."""
    (tmp_path / "taken").write_text("a file, not a folder")
    result = _glraster("render", "basic_triangle", "--reference", "-o", "x.exr",
                       "--png", "taken/x.png", cwd=tmp_path)
    assert result.returncode == exit_codes.USAGE, result.stderr
    assert "taken is a file, not a folder" in _one_line(result.stderr)
    assert sorted(os.listdir(tmp_path)) == ["taken"], "no x.exr, no temporary file"

    result = _glraster("render", "basic_triangle", "--reference", "-o", "x.exr",
                       "--png", "x.jpg", cwd=tmp_path)
    assert result.returncode == exit_codes.USAGE, result.stderr
    assert _one_line(result.stderr) == ("glraster render: argument --png: png must end in "
                                        ".png, got 'x.jpg'")
    assert sorted(os.listdir(tmp_path)) == ["taken"]

    result = _glraster("render", "basic_triangle", "--reference", "-o", "x.exr",
                       "--png", "x.png", cwd=tmp_path)
    assert result.returncode == exit_codes.OK, result.stderr
    assert sorted(os.listdir(tmp_path)) == ["taken", "x.exr", "x.png"]


@pytest.mark.parametrize("args, option", [
    (("fit", "cube", "--json", "taken/fit.json"), "--json"),
    (("fit", "cube", "--out", "taken"), "--out"),
    (("check", "--junit", "taken/junit.xml"), "--junit"),
    (("check", "--html", "taken/report"), "--html"),
    (("bench", "--quick", "--plot", "taken/pareto.png"), "--plot"),
    (("stress", "--json", "taken/stress.json"), "--json"),
    (("batch", "scenes", "taken"), "OUT"),
    (("study", "speed-goals", "--json", "taken/goals.json"), "--json"),
])
def test_an_output_that_cannot_be_written_stops_the_command_before_it_runs(tmp_path, args,
                                                                           option):
    """A long run (a fit, the conformance suite, a benchmark) whose output file or folder
    cannot be made is refused when its command line is parsed (exit 2), not after the
    run, at its last write."""
    (tmp_path / "taken").write_text("a file, not a folder")
    result = _glraster(*args, cwd=tmp_path)
    assert result.returncode == exit_codes.USAGE, result.stderr
    assert result.stdout == "", "nothing ran"
    line = _one_line(result.stderr)
    assert f"error: argument {option}: cannot write taken" in line, line
    assert line.endswith("(taken is a file, not a folder)"), line
    assert sorted(os.listdir(tmp_path)) == ["taken"]


@pytest.mark.parametrize("args, target", [
    (("fit", "cube"), "out/fit/cube"),
    (("distortion",), "out/distortion"),
    (("antialias-study",), "out/antialias"),
    (("demo",), "out"),
])
def test_an_output_left_at_its_default_is_judged_before_the_run_too(tmp_path, args, target):
    """argparse runs no action for an option left at its default: such an --out was not
    judged, and the command ran until its first write (demo: after its comparison)."""
    (tmp_path / "out").write_text("a file, not a folder")
    result = _glraster(*args, cwd=tmp_path)
    assert result.returncode == exit_codes.USAGE, result.stderr
    assert result.stdout == "", "nothing ran"
    line = _one_line(result.stderr)
    assert f"error: argument --out: cannot write {target} (out is a file, not a folder)" \
        in line, line
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_demo_quick_writes_nothing_so_its_default_out_is_not_judged(tmp_path, gl_backend):
    (tmp_path / "out").write_text("a file, not a folder")
    env = {k: v for k, v in _env().items() if k != "GLRASTER_BACKEND"}
    result = subprocess.run([sys.executable, "-m", "glraster.cli", "demo", "--quick",
                             "--backend", gl_backend], capture_output=True, text=True,
                            env=env, cwd=tmp_path, timeout=300)
    assert result.returncode == exit_codes.OK, result.stderr
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_every_option_that_names_an_output_is_checked_before_the_run():
    """Every --json/--plot/--junit/--html/--png/--out/-o FILE of every command is an
    OutputFile or OutputFolder action (refused at parse time when it cannot be made), so
    that a new command's output option cannot skip the check."""
    import argparse

    from glraster.cli import build_parser
    from glraster.io.destinations import OutputFile

    outputs = {"json", "plot", "junit", "html", "png", "out", "output"}
    unchecked, checked = [], 0

    def walk(parser, prog):
        nonlocal checked
        for action in parser._actions:   # argparse offers no public list of them
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{prog} {name}")
            elif action.dest in outputs and action.nargs != 0:
                if isinstance(action, OutputFile):
                    checked += 1
                else:
                    unchecked.append(f"{prog} {'/'.join(action.option_strings) or action.dest}")

    walk(build_parser(), "glraster")
    assert not unchecked, unchecked
    assert checked >= 20
