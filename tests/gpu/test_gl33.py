"""The GL 3.3 path of method "hw" (shaders/raster33/, vertex attributes, no storage buffers).

On llvmpipe it is forced with ``Context(max_gl=33)`` (or ``GLRASTER_MAX_GL=3.3``) and must
give the 4.5 path's images bit for bit. Mesa's softpipe (GL 3.3 core) runs it for real:
those tests start a subprocess with ``GALLIUM_DRIVER=softpipe``, which must be set before
Mesa loads. Methods that need GL 4.5 raise a ValueError naming the versions.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import glraster as gr
from glraster.cli import main
from glraster.conformance import check, golden, mutants
from glraster.conformance.scenes import list_scenes, load_scene
from glraster.errors import GLVersionError
from glraster.geometry import synthetic
from glraster.gpu import methods, pipeline
from glraster.gpu.backends import osmesa
from glraster.gpu.shaders import shader_dir

OUTPUTS = ("persp", "screen", "depth", "tri_id")
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ctx33(gl_context):
    """A context of the same backend that uses no GL above 3.3."""
    ctx = gr.Context(gl_context.backend, max_gl=33)
    yield ctx
    assert ctx.gl_error() == "GL_NO_ERROR"
    ctx.release()


def bits(array):
    return array.view(np.uint32) if array.dtype == np.float32 else array


def separated_triangles(cell=5, size=512, seed=0):
    """(pos, tri, resolution): one right triangle per cell x cell square, edges 0.25 px or
    more from every pixel center (so any fill rule and any subpixel precision of 4 bits
    or more covers the same pixels), w in [0.5, 2] per vertex; over 10,000 triangles, so
    that a draw crosses the driver's internal vertex splits."""
    rng = np.random.default_rng(seed)
    x0, y0 = np.meshgrid(np.arange(0, size - cell + 1, cell), np.arange(0, size - cell + 1, cell))
    x0, y0 = x0.ravel().astype(np.float64), y0.ravel().astype(np.float64)
    leg = cell - 1.0
    window = np.stack([np.stack([x0 + 0.25, y0 + 0.25], 1),
                       np.stack([x0 + 0.25 + leg, y0 + 0.25], 1),
                       np.stack([x0 + 0.25, y0 + 0.25 + leg], 1)], 1).reshape(-1, 2)
    w = rng.uniform(0.5, 2.0, len(window))
    ndc = window / size * 2 - 1
    z = rng.uniform(-0.9, 0.9, len(window))
    pos = np.stack([ndc[:, 0] * w, ndc[:, 1] * w, z * w, w], 1).astype(np.float32)
    tri = np.arange(len(window)).reshape(-1, 3)
    return pos, tri, (size, size)


# -- llvmpipe, 3.3 path forced -----------------------------------------------------------
def test_capped_context_reports_both_versions(ctx33, ctx):
    assert ctx33.gl_version_number == 33 and ctx33.max_gl == 33
    assert ctx33.driver_gl_version_number == ctx.driver_gl_version_number
    assert ctx.gl_version_number == ctx.driver_gl_version_number >= 33
    assert ctx33.max_storage_block_size == 0
    assert methods.for_context("hw", ctx33) is methods.HW_GL33
    if ctx.gl_version_number >= 45:
        assert methods.for_context("hw", ctx) is methods.METHODS["hw"]


@pytest.mark.parametrize("name", list_scenes())
def test_gl33_path_gives_the_45_images_bit_for_bit(ctx33, ctx, name):
    if ctx.gl_version_number < 45:
        pytest.skip("the driver has no GL 4.5 path to compare with")
    scene = load_scene(name)
    a = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx, outputs=OUTPUTS)
    b = gr.rasterize(scene.pos, scene.tri, scene.resolution, ctx=ctx33, outputs=OUTPUTS)
    assert not a.info["vertex_input"] and b.info["vertex_input"]
    for output in OUTPUTS:
        assert np.array_equal(bits(getattr(a, output)), bits(getattr(b, output))), output
    assert np.array_equal(a.mask, b.mask)


@pytest.mark.parametrize("outputs", [("depth",), ("tri_id",), ("persp",), ("screen", "depth")])
def test_gl33_output_subsets_and_affine_path(ctx33, ctx, outputs):
    # depth alone: the shaders use no vertex number (a_vertex is optimized out)
    pos, tri = synthetic.random_soup(300, seed=3)
    for p in (pos, np.concatenate([pos[:, :3], np.ones((len(pos), 1), np.float32)], 1)):
        a = gr.rasterize(p, tri, (64, 80), ctx=ctx, outputs=outputs)
        b = gr.rasterize(p, tri, (64, 80), ctx=ctx33, outputs=outputs)
        assert a.info["affine"] == b.info["affine"]
        for output in outputs:
            assert np.array_equal(bits(getattr(a, output)), bits(getattr(b, output)))


def test_gl33_batches_keep_ids_global_and_values_equal(ctx33, monkeypatch):
    pos, tri = synthetic.random_soup(50, seed=4)
    whole = gr.rasterize(pos, tri, (64, 64), ctx=ctx33)
    monkeypatch.setattr(pipeline, "VERTEX_BATCH_TRIANGLES", 7)  # 8 draws
    batched = gr.rasterize(pos, tri, (64, 64), ctx=ctx33)
    for output in OUTPUTS:
        assert np.array_equal(bits(getattr(whole, output)), bits(getattr(batched, output)))


def test_gl33_ids_beyond_2_24_are_exact(gl_context):
    # The vertex numbers k (attribute a_vertex) are what the ids come from: offsetting them
    # by 3 * 2^24 + 3 must give ids 2^24 + 1 + the triangle index, exactly.
    ctx = gr.Context(gl_context.backend, max_gl=33)
    try:
        pos, tri, resolution = separated_triangles(cell=16, size=128)
        ref = gr.reference.rasterize(pos, tri, resolution)
        first = gr.rasterize(pos, tri, resolution, ctx=ctx)
        assert np.array_equal(first.tri_id, ref.tri_id)
        numbers = ctx._buffers["vertex_numbers"]
        offset = 3 * (2**24 + 1)
        with ctx:
            numbers.write(np.arange(numbers.size // 4, dtype=np.int32) + offset)
        shifted = gr.rasterize(pos, tri, resolution, ctx=ctx)
        covered = ref.tri_id >= 0
        assert np.array_equal(shifted.tri_id[covered], ref.tri_id[covered] + 2**24 + 1)
        assert (shifted.tri_id[covered] > 2**24).all()
        assert ctx.gl_error() == "GL_NO_ERROR"
    finally:
        ctx.release()


def test_gl33_caches_do_not_grow(ctx33):
    pos, tri = synthetic.random_soup(3, seed=1)
    variants = [("persp",), ("depth", "tri_id"), OUTPUTS]
    for outputs in variants:
        gr.rasterize(pos, tri, (16, 16), ctx=ctx33, outputs=outputs)
    objects = ctx33.cached_object_count()
    for k in range(300):
        gr.rasterize(pos, tri, (16, 16), ctx=ctx33, outputs=variants[k % 3])
    assert ctx33.cached_object_count() == objects


@pytest.mark.parametrize("method", ["divw", "homogeneous", "homogeneous64", "solve4"])
def test_methods_needing_gl45_name_the_versions(ctx33, method):
    pos, tri = synthetic.random_soup(3, seed=1)
    with pytest.raises(GLVersionError, match=rf"method '{method}' needs OpenGL 4\.5 \(shader "
                                             r"storage buffers.*capped at OpenGL 3\.3") as info:
        gr.rasterize(pos, tri, (8, 8), ctx=ctx33, method=method)
    assert isinstance(info.value, ValueError)
    assert (info.value.offered, info.value.needed) == (33, 45)
    assert methods.available(ctx33)[method] is None


def test_compute_shaders_need_gl45(ctx33):
    with pytest.raises(GLVersionError, match=r"compute shader interpolate\.comp needs OpenGL 4\.5"):
        ctx33.compute_program(shader_dir() / "diff" / "interpolate.comp", {})


def test_vertex_input_refuses_per_triangle_buffers(ctx33):
    spec = pipeline.Draw(*ctx33.program(shader_dir() / "raster33/raster.vert",
                                        shader_dir() / "raster33/raster.frag",
                                        pipeline.output_defines({"tri_id": (1, "i4")})),
                         {"tri_id": (1, "i4")}, per_triangle={3: np.zeros(1, np.int32)},
                         vertex_input=True)
    pos, tri = synthetic.random_soup(1, seed=1)
    with pytest.raises(ValueError, match="per-triangle storage buffers need"):
        pipeline.draw(ctx33, spec, pos, tri.astype(np.int32), (8, 8))


def test_environment_variable_caps_the_context(gl_backend, monkeypatch):
    monkeypatch.setenv("GLRASTER_MAX_GL", "3.3")
    ctx = gr.Context(gl_backend)
    try:
        assert ctx.gl_version_number == 33
        pos, tri = synthetic.random_soup(3, seed=1)
        assert gr.rasterize(pos, tri, (8, 8), ctx=ctx).info["vertex_input"]
    finally:
        ctx.release()


def test_bad_max_gl_is_a_value_error_before_any_context():
    for bad in ("2.1", "four", 12, True):
        with pytest.raises(ValueError, match="max_gl must be"):
            gr.Context("egl", max_gl=bad)


# -- mutants on the 3.3 shaders ----------------------------------------------------------
@pytest.mark.parametrize("m", mutants.MUTANTS, ids=lambda m: m.name)
def test_each_patch_applies_once_to_the_gl33_shaders_keeping_lines(m, ctx33):
    real = dict(zip(mutants.REAL_SHADERS, mutants.real_shaders(ctx33)))
    assert real == {mutants.VERT: "raster33/raster.vert", mutants.FRAG: "raster33/raster.frag"}
    for role, file in real.items():
        text = (shader_dir() / file).read_text()
        for p in (p for p in m.patches if p.file == role):
            assert text.count(p.old) == 1, (m.name, file, p.old)
            text = text.replace(p.old, p.new)
        assert m.source(role, ctx33) == text
        assert len(text.splitlines()) == len((shader_dir() / file).read_text().splitlines())
    for role, path in zip(mutants.REAL_SHADERS, m.shader_files(ctx33)):
        if role in m.patched_files:
            assert f"{m.name}/raster33/" in path and Path(path).read_text().startswith(
                m.source(role, ctx33))
        else:
            assert path == str(shader_dir() / real[role])


def test_every_mutant_is_caught_on_the_gl33_path(ctx33):
    names = ("tiny_viewport", "basic_triangle", "quad_shared_diagonal", "pixel_center_edges",
             "depth_interpenetrating")
    if 4 in ctx33.sample_counts:     # the multisampling mutants need a multisample scene
        names += ("ms_perspective_sample", "ms_perspective_centroid")
    scenes = [load_scene(n) for n in names]
    refs = {n: golden.reference_for(s) for n, s in zip(names, scenes)}
    results, control_failures = check.run_mutants(ctx33, scenes, refs)
    assert control_failures == []
    assert [m.name for m in results if not m.caught] == []


# -- softpipe (GL 3.3 core), in a subprocess ---------------------------------------------
SOFTPIPE_SCRIPT = r"""
import json, sys
import numpy as np
import glraster as gr
sys.path.insert(0, sys.argv[2])
from tests.gpu.test_gl33 import separated_triangles
ctx = gr.Context(sys.argv[1])
out = {"renderer": ctx.renderer, "gl": ctx.gl_version_number}
if ctx.renderer == "softpipe":
    pos, tri, resolution = separated_triangles()
    r = gr.rasterize(pos, tri, resolution, ctx=ctx)
    ref = gr.reference.rasterize(pos, tri, resolution)
    out.update(vertex_input=r.info["vertex_input"], triangles=len(tri),
               covered=int(r.mask.sum()), mask_equal=bool(np.array_equal(r.mask, ref.mask)),
               ids_equal=bool(np.array_equal(r.tri_id, ref.tri_id)),
               persp_max=float(np.abs(r.persp - ref.persp)[ref.mask].max()),
               depth_max=float(np.abs(r.depth - ref.depth)[ref.mask].max()))
    try:
        gr.rasterize(pos, tri, resolution, ctx=ctx, method="homogeneous")
    except ValueError as exc:
        out["homogeneous"] = str(exc)
print(json.dumps(out))
"""


def run_softpipe(args, **env):
    environment = dict(os.environ, GALLIUM_DRIVER="softpipe", **env)
    environment.pop("GLRASTER_MAX_GL", None)
    return subprocess.run(args, check=False, capture_output=True, text=True, env=environment,
                          cwd=REPO, timeout=600)


def test_softpipe_rasterizes_with_exact_ids(gl_backend):
    proc = run_softpipe([sys.executable, "-c", SOFTPIPE_SCRIPT, gl_backend, str(REPO)])
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    if out["renderer"] != "softpipe":
        pytest.skip(f"GALLIUM_DRIVER=softpipe gave {out['renderer']!r} (not Mesa's gallium)")
    assert out["gl"] == 33 and out["vertex_input"]
    assert out["triangles"] > 10_000 and out["covered"] > 100_000
    assert out["mask_equal"] and out["ids_equal"]
    assert out["persp_max"] < 1e-3 and out["depth_max"] < 1e-4
    assert "method 'homogeneous' needs OpenGL 4.5" in out["homogeneous"]
    assert "the driver (softpipe) offers OpenGL 3.3" in out["homogeneous"]


def test_softpipe_check_runs_every_scene_and_the_mutants(gl_backend):
    scenes = "tiny_viewport,basic_triangle,quad_shared_diagonal,near_plane_crossing"
    proc = run_softpipe([sys.executable, "-m", "glraster.cli", "check", "--backend",
                         gl_backend, "--no-golden", "--scenes", scenes, "--mutants"])
    # softpipe ships in the same Debian package as llvmpipe (libgl1-mesa-dri)
    assert "| softpipe | GL 3.3" in proc.stdout, proc.stdout[-2000:]
    # every scene passes: tie-rule differences are judged by the edge band (softpipe's rule
    # is not a fixed-point one), Mesa's clipper defect, which the noperspective_clip probe
    # finds on softpipe too, is waived and counted as on llvmpipe
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr
    lines = proc.stdout.splitlines()
    for name in scenes.split(","):
        assert any(line.startswith(name) and " PASS" in line for line in lines), name
    assert any(line.startswith("near_plane_crossing") and "waived" in line for line in lines)
    assert "control (real shaders via the mutant path): no false alarm" in proc.stdout
    assert "Traceback" not in proc.stderr


def test_info_on_softpipe_names_the_missing_version(gl_backend):
    proc = run_softpipe([sys.executable, "-m", "glraster.cli", "info", "--backend", gl_backend])
    if "softpipe" not in proc.stdout:
        pytest.skip("GALLIUM_DRIVER=softpipe did not give softpipe")
    assert proc.returncode == 0, proc.stderr
    assert "vertex attributes (GL 3.3, shaders/raster33)" in proc.stdout
    assert "divw, homogeneous, solve4: driver offers GL 3.3; glraster needs 4.5 for shader " \
           "storage buffers" in proc.stdout


# -- glraster info -----------------------------------------------------------------------
def test_info_on_a_capped_context(gl_backend, capsys, monkeypatch):
    monkeypatch.setenv("GLRASTER_MAX_GL", "33")
    assert main(["info", "--backend", gl_backend, "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    assert facts["gl_version_number"] == 33 and facts["methods"] == ["hw"]
    assert facts["draw_path"].startswith("vertex attributes")
    assert set(facts["unavailable_methods"]) == {"divw", "homogeneous", "homogeneous64", "solve4"}
    assert main(["info", "--backend", gl_backend]) == 0
    text = capsys.readouterr().out
    assert "the context is capped at GL 3.3" in text and "glraster needs 4.5 for" in text


def test_info_on_a_full_context_lists_every_method(gl_backend, capsys, monkeypatch):
    monkeypatch.delenv("GLRASTER_MAX_GL", raising=False)
    assert main(["info", "--backend", gl_backend, "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    if facts["gl_version_number"] >= 45:
        assert facts["methods"] == list(methods.METHODS) and facts["unavailable_methods"] == {}
        assert facts["draw_path"].startswith("storage buffers")


def test_info_without_the_library_gives_the_install_hint(monkeypatch, capsys):
    monkeypatch.setattr(osmesa, "LIBRARY_NAMES", ("libOSMesa-missing.so",))
    monkeypatch.setattr(osmesa.ctypes.util, "find_library", lambda name: None)
    assert main(["info", "--backend", "osmesa"]) == 3
    err = capsys.readouterr().err
    assert "no OpenGL library" in err and "libOSMesa not found" in err
    assert "apt-get install" in err and "driver offers" not in err


def test_too_old_driver_names_the_versions_without_install_hint(gl_backend):
    # Mesa only: MESA_GL_VERSION_OVERRIDE=3.1 makes the driver offer no 3.3 core context.
    env = dict(os.environ, MESA_GL_VERSION_OVERRIDE="3.1")
    env.pop("GLRASTER_MAX_GL", None)
    proc = subprocess.run([sys.executable, "-m", "glraster.cli", "info", "--backend", gl_backend],
                          check=False, capture_output=True, text=True, env=env, cwd=REPO,
                          timeout=300)
    if proc.returncode == 0:
        pytest.skip("MESA_GL_VERSION_OVERRIDE has no effect on this driver")
    assert proc.returncode == 3
    assert "driver offers GL 3.1; glraster needs 3.3 core" in proc.stderr
    assert "apt-get" not in proc.stderr
    script = ("import glraster as gr, sys\n"
              "try:\n    gr.Context(sys.argv[1])\n"
              "except gr.errors.DriverTooOld as e:\n    print(e.offered, e.needed)\n")
    proc = subprocess.run([sys.executable, "-c", script, gl_backend], check=False,
                          capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    assert proc.stdout.split() == ["3.1", "3.3"], proc.stderr


def test_osmesa_refuses_zink_instead_of_crashing(monkeypatch):
    # Mesa 22.3's OSMesaCreateContextAttribs segfaults with GALLIUM_DRIVER=zink.
    monkeypatch.setenv("GALLIUM_DRIVER", "zink")
    with pytest.raises(gr.BackendUnavailable, match="OSMesa cannot run zink"):
        gr.Context("osmesa")
