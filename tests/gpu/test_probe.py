"""The backend probe: crashes and hangs become errors, verdicts are cached as documented.

These tests replace the probe's child program or its runner, so they open no GL context
(not marked gl).
"""

from __future__ import annotations

import os

import pytest

from glraster.errors import BackendCrashed, BackendUnavailable, DriverTooOld
from glraster.gpu.backends import environment, probe


@pytest.fixture(autouse=True)
def isolated(monkeypatch, tmp_path):
    """An empty verdict cache in memory and on disk."""
    monkeypatch.setattr(probe, "_verdicts", {})
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def test_a_child_killed_by_a_signal_is_backend_crashed(monkeypatch):
    monkeypatch.setattr(probe, "CHILD", "import os, signal, sys; "
                        "sys.stderr.write('MESA: about to fall over\\n'); sys.stderr.flush(); "
                        "os.kill(os.getpid(), signal.SIGSEGV)")
    found = probe.run_probe("osmesa")
    assert found["ok"] is False and found["signal"] == "SIGSEGV"
    error = probe.error_from("osmesa", found)
    assert isinstance(error, BackendCrashed) and error.signal == "SIGSEGV"
    assert str(error) == ("libOSMesa crashed (SIGSEGV) creating a context (in a probe "
                          "process; this one is unharmed); Mesa said: MESA: about to fall over")


def test_a_child_that_hangs_is_stopped_at_the_timeout(monkeypatch):
    monkeypatch.setattr(probe, "CHILD", "import time; time.sleep(60)")
    monkeypatch.setattr(probe, "PROBE_TIMEOUT_S", 0.5)
    found = probe.run_probe("egl")
    assert found == {"ok": False, "error": "BackendUnavailable",
                     "message": "egl: creating a context did not finish in 0.5 s (a driver "
                                "waiting for a device?)"}
    assert type(probe.error_from("egl", found)) is BackendUnavailable


def test_a_child_that_exits_without_a_verdict_says_so(monkeypatch):
    monkeypatch.setattr(probe, "CHILD", "import sys; sys.exit(5)")
    found = probe.run_probe("egl")
    assert "ended with exit status 5 and no verdict" in found["message"]


def test_driver_too_old_keeps_its_versions():
    found = {"ok": False, "error": "DriverTooOld", "message": "old", "offered": "2.1",
             "needed": "3.3", "mesa": []}
    error = probe.error_from("egl", found)
    assert isinstance(error, DriverTooOld) and (error.offered, error.needed) == ("2.1", "3.3")


def _counting(monkeypatch, verdict):
    calls = []

    def run(backend):
        calls.append(backend)
        return dict(verdict)
    monkeypatch.setattr(probe, "run_probe", run)
    return calls


def test_a_verdict_is_probed_once_per_process_and_environment(monkeypatch):
    calls = _counting(monkeypatch, {"ok": False, "error": "BackendUnavailable",
                                    "message": "no"})
    for _ in range(3):
        assert probe.verdict("egl")["ok"] is False
    assert calls == ["egl"]
    monkeypatch.setenv("GALLIUM_DRIVER", "softpipe")  # another environment: probed again
    probe.verdict("egl")
    assert calls == ["egl", "egl"]


def test_only_working_verdicts_are_kept_on_disk(monkeypatch, tmp_path):
    library = tmp_path / "libfake.so"
    library.write_bytes(b"1234")
    stat = library.stat()
    ok = {"ok": True, "renderer": "r", "gl_version": "4.5",
          "libraries": [[str(library), stat.st_size, stat.st_mtime_ns]]}
    calls = _counting(monkeypatch, ok)
    probe.verdict("egl")
    monkeypatch.setattr(probe, "_verdicts", {})  # a new process
    assert probe.verdict("egl")["renderer"] == "r"
    assert calls == ["egl"], "the second process read the verdict from disk"
    assert len(list(probe.cache_folder().iterdir())) == 1

    library.write_bytes(b"12345")  # the driver library changed: probed again
    monkeypatch.setattr(probe, "_verdicts", {})
    probe.verdict("egl")
    assert calls == ["egl", "egl"]

    failed = _counting(monkeypatch, {"ok": False, "error": "BackendUnavailable",
                                     "message": "no"})
    monkeypatch.setattr(probe, "_verdicts", {})
    probe.verdict("osmesa")
    monkeypatch.setattr(probe, "_verdicts", {})
    probe.verdict("osmesa")
    assert failed == ["osmesa", "osmesa"], "a failure is never read back from disk"


def test_an_unwritable_cache_folder_falls_back_to_memory(monkeypatch, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    calls = _counting(monkeypatch, {"ok": True, "libraries": []})
    assert probe.verdict("egl")["ok"] and probe.verdict("egl")["ok"]
    assert calls == ["egl"]


def test_the_cache_key_covers_driver_variables_and_not_others():
    base = {"HOME": "/h", "PATH": "/bin"}
    assert environment.environment_key(base) == ()
    key = environment.environment_key({**base, "GALLIUM_DRIVER": "softpipe",
                                       "LP_NUM_THREADS": "2", "LD_LIBRARY_PATH": "/x"})
    assert key == (("GALLIUM_DRIVER", "softpipe"), ("LD_LIBRARY_PATH", "/x"),
                   ("LP_NUM_THREADS", "2"))


@pytest.mark.parametrize("variables, words", [
    ({"GALLIUM_DRIVER": "llvmpip"}, ["did you mean 'llvmpipe'?", "unset it"]),
    ({"GALLIUM_DRIVER": "softpipe"}, ["unset it to let Mesa choose"]),
    ({"GALLIUM_DRIVER": "iris"}, ["'iris' needs its GPU or host"]),
    ({"MESA_GL_VERSION_OVERRIDE": "3.1"}, ["below the OpenGL 3.3 glraster needs"]),
    ({"MESA_GL_VERSION_OVERRIDE": "4.6"}, ["unset it to get the driver's own version"]),
    ({"GLCONTEXT_DEVICE_INDEX": "3"}, ["pick a device EGL lists"]),
    ({}, ["no variable that picks the driver is set", "EGL_LOG_LEVEL=debug"]),
])
def test_advice_names_each_variable_and_what_to_do(variables, words):
    text = environment.advice({"HOME": "/h", **variables})
    for name, value in variables.items():
        assert f"{name}={value!r}" in text
    for word in words:
        assert word in text, text


def test_the_probe_child_skips_the_package_init():
    """The child registers glraster as a bare package (no NumPy import: half its time)."""
    import subprocess
    import sys

    code = probe.CHILD.replace("from glraster.gpu.backends.probe import main; sys.exit(main())",
                               "import glraster.gpu.backends.probe; print('numpy' in sys.modules)")
    package = os.path.dirname(os.path.dirname(os.path.dirname(probe.__file__)))
    out = subprocess.run([sys.executable, "-c", code, package], capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.strip() == "False", out.stderr


def test_an_embedded_interpreter_is_not_probed(monkeypatch):
    """Python inside another program: sys.executable would start that program, not a
    probe; the context is then made in-process (the behaviour before probes)."""
    monkeypatch.setattr(probe.sys, "executable", "/usr/bin/blender")
    found = probe.verdict("osmesa")
    assert found["ok"] and "not a Python interpreter" in found["unprobed"]
    assert not probe.cache_folder().exists(), "an unprobed verdict is not stored"


def test_the_disk_keeps_only_the_newest_verdicts(monkeypatch):
    monkeypatch.setattr(probe, "DISK_VERDICTS", 3)
    _counting(monkeypatch, {"ok": True, "libraries": []})
    for k in range(5):
        monkeypatch.setenv("MESA_DEBUG", str(k))   # five environments, five verdicts
        probe.verdict("egl")
    assert len(list(probe.cache_folder().glob("*.json"))) == 3
