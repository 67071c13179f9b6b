"""glraster.gpu.gl_trace and the diff-floors study (glraster.studies.diff_floors).

A replayed trace must do the op's GL work again, not merely take time: the tests wipe the
op's output buffer after recording and check that the replay writes the core's output
into it again, bit for bit (the same shader on the same inputs: exact). The study itself
runs at tiny sizes; its tables are timings (never checked), but the call counts of a fit
iteration are exact (the cube fit renders twice per iteration: target and fit).
"""

from __future__ import annotations

import json

import moderngl
import numpy as np
import pytest

from glraster.diff.ops import INTERPOLATE, RASTERIZE
from glraster.gpu.gl_trace import Recorder
from glraster.studies import diff_floors


def _scene():
    pos = np.array([[-0.9, -0.8, 0.1, 1.0], [0.8, -0.9, 0.2, 1.3], [0.1, 0.9, 0.3, 0.8],
                    [0.9, 0.9, 0.5, 1.1]], np.float32)
    tri = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    return pos, tri


def test_replay_redoes_the_dispatch_and_readback(ctx):
    pos, tri = _scene()
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=(8, 8), grad_db=False, ctx=ctx)
    attr = np.random.default_rng(0).uniform(0, 1, (4, 3)).astype(np.float32)
    arrays, params = INTERPOLATE.check(attr, rast, tri=tri, ctx=ctx)
    core = INTERPOLATE.core(np.float32)
    with diff_floors.recording() as rec:
        (out, _), _ = core.forward(*arrays, **params)
    assert rec.trace.counts() == {"interpolate.forward": 1}
    written = ctx.scratch_buffer("interpolate.out", out.nbytes)
    with ctx:
        written.write(np.full(out.size, -7.0, np.float32).tobytes())
    seconds = rec.trace.replay(ctx)
    assert set(seconds) == {"interpolate.forward"} and seconds["interpolate.forward"] > 0
    with ctx:
        again = np.frombuffer(written.read(size=out.nbytes), np.float32)
    np.testing.assert_array_equal(again, out.reshape(-1))


def test_replay_of_a_draw_redraws_the_raster(ctx):
    pos, tri = _scene()
    arrays, params = RASTERIZE.check(pos, tri=tri, resolution=(6, 10), grad_db=True, ctx=ctx)
    core = RASTERIZE.core(np.float32)
    with diff_floors.recording() as rec:
        (rast, rast_db), _ = core.forward(*arrays, **params)
    expected = rast.copy(), rast_db.copy()
    rast[...] = -1.0            # the recorded readback fills these arrays again
    rast_db[...] = -1.0
    rec.trace.replay(ctx)
    np.testing.assert_array_equal(rast, expected[0])
    np.testing.assert_array_equal(rast_db, expected[1])


def test_recorder_restores_moderngl_and_refuses_nesting(ctx):
    before = moderngl.Buffer.read, moderngl.ComputeShader.run, moderngl.Uniform.value
    with Recorder():
        assert moderngl.Buffer.read is not before[0]
        with pytest.raises(RuntimeError, match="active already"):
            Recorder().__enter__()
    assert (moderngl.Buffer.read, moderngl.ComputeShader.run,
            moderngl.Uniform.value) == before


def test_calls_outside_a_segment_are_kept_apart(ctx):
    with Recorder() as rec:
        with ctx:
            buffer = ctx.storage_buffer("test.outside", np.zeros(4, np.float32))
            buffer.read()
        with rec.segment("named"):
            with ctx:
                buffer.read()
    assert rec.trace.names() == ["(outside)", "named"]
    assert rec.trace.counts() == {"named": 1}


class _Ticks:
    """perf_counter that advances 1 second per call: the clock's attribution exact."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self):
        self.now += 1.0
        return self.now


def test_phase_clock_charges_each_phase_its_exclusive_time(monkeypatch):
    monkeypatch.setattr(diff_floors, "time", _Ticks())
    clock = diff_floors.PhaseClock()                         # tick 1
    upload = clock.wrap(lambda: None, "upload")
    core = clock.wrap(lambda: upload(), "python")
    core()      # ticks 2 (torch 1), 3 (python 1), 4 (upload 1), 5 (python 1)
    totals = clock.read()                                    # tick 6: torch 1
    assert totals == dict({p: 0.0 for p in diff_floors.PHASES},
                          torch=2.0, python=2.0, upload=1.0)


def test_study_runs_small(gl_backend, tmp_path, capsys):
    pytest.importorskip("torch")
    out = tmp_path / "floors.json"
    assert diff_floors.main(["--op-size", "8", "--fits", "cube4", "--rounds", "1",
                             "--calls", "1", "--iterations", "1",
                             "--profile-iterations", "1", "--backend", gl_backend,
                             "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "## Op floors" in printed and "| cube4 |" in printed
    figures = json.loads(out.read_text())
    ops = figures["ops"]["8"]
    assert set(ops) == {"rasterize", "interpolate", "texture", "antialias"}
    for paths in ops.values():
        assert all(s > 0 for s in paths["floor"])
    cube = figures["fits"]["cube4"]
    # fit_cube's loop: one call of each op per iteration, the targets' calls batched
    from glraster.torch.fitting.cube import TARGET_BATCH

    share = 1 / TARGET_BATCH
    assert cube["calls"] == {"rasterize.forward": 1, "interpolate.forward": 1,
                             "antialias.forward": 1, "rasterize.backward": 1,
                             "interpolate.backward": 1, "antialias.backward": 1,
                             "target rasterize.forward": share,
                             "target interpolate.forward": share,
                             "target antialias.forward": share}
    assert cube["floors"]["target rasterize.forward"] > 0
    assert set(cube["phases"]) == set(diff_floors.PHASES)
    for phase in ("python", "validation", "context", "dispatch", "readback", "torch"):
        assert cube["phases"][phase] > 0, phase


def test_envmap_iteration_runs_small(ctx):
    """One iteration of the environment-map fit: the material enters after the GL calls, so
    the target and the fitted render share them (envmap_loss): rasterize and interpolate
    run once, texture twice (the diffuse and the mirror lookups)."""
    from glraster.torch.context import RasterizeGLContext

    iteration = diff_floors._envmap(RasterizeGLContext(context=ctx), resolution=8, views=1,
                                    mesh=(6, 5), env_size=8)
    with diff_floors.recording() as rec:
        step = iteration()
    assert step > 0
    counts = rec.trace.counts()
    assert (counts["rasterize.forward"], counts["interpolate.forward"],
            counts["texture.forward"]) == (1, 1, 2)


def test_bad_options_are_refused(capsys):
    with pytest.raises(SystemExit):
        diff_floors.main(["--rounds", "0"])
    assert "--rounds must be at least 1" in capsys.readouterr().err
