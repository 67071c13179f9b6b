"""Fault injection: every mutant is caught by some scene; the real shaders raise no alarm."""

import re

import pytest

from glraster.conformance import check, golden, mutants
from glraster.conformance.scenes import list_scenes, load_scene
from glraster.gpu.shaders import shader_dir

# Cheap scenes that between them exercise every mutated feature (perspective, shared
# edges, ids, depth overlap); the full catalog would only add run time.
SCENES = ("tiny_viewport", "basic_triangle", "basic_perspective_triangle",
          "quad_shared_diagonal", "pixel_center_edges", "grid_pixel_centers",
          "depth_interpenetrating", "ortho_box", "fan_pixel_center")


@pytest.fixture(scope="module")
def references():
    return {n: golden.reference_for(load_scene(n)) for n in SCENES}


def test_at_least_eight_mutants_with_distinct_faults():
    assert len(mutants.MUTANTS) >= 8
    assert len({m.name for m in mutants.MUTANTS}) == len(mutants.MUTANTS)
    assert len({(m.vert, m.frag, m.target_dtype, m.depth_test) for m in mutants.MUTANTS}) \
        == len(mutants.MUTANTS)


@pytest.mark.parametrize("m", mutants.MUTANTS, ids=lambda m: m.name)
def test_mutant_files_are_marked_copies_of_the_real_shaders(m):
    d = shader_dir()
    for changed, real in ((m.vert, "raster/raster.vert"), (m.frag, "raster/raster.frag")):
        text = (d / changed).read_text()
        assert text.startswith("#version 450 core")
        if changed != real:
            assert "MUTANT" in text
            real_text = (d / real).read_text()
            assert text != real_text
            # Derived from the current real shader: the fault replaces a few lines, the
            # rest (interface, defines, uniforms) is unchanged.
            kept = set(text.splitlines())
            lost = [ln for ln in real_text.splitlines() if ln not in kept]
            assert len(lost) <= 2, f"{changed} is stale against {real}: {lost}"
            interface = [ln for ln in lost if ln.lstrip().startswith(
                ("layout", "uniform", "#", "readonly", "buffer"))]
            assert not interface, f"{changed} lost interface lines of {real}: {interface}"


def test_every_mutant_is_caught_and_the_control_passes(ctx, references):
    scenes = [load_scene(n) for n in SCENES]
    results, control_failures = check.run_mutants(ctx, scenes, references)
    # No false alarm: the real shaders through the mutant renderer pass every scene.
    assert control_failures == []
    escaped = [m.name for m in results if not m.caught]
    assert not escaped, f"mutants not caught on {ctx.backend}: {escaped}"
    assert {m.name for m in results} == {m.name for m in mutants.MUTANTS}


def test_fill_rule_mutant_changes_only_tie_pixels(ctx, references):
    # The rotated rendering keeps values within tolerance; only pixel centers lying exactly
    # on an edge change owner. That is what makes it a pure fill-rule fault.
    s = load_scene("quad_shared_diagonal")
    gpu = mutants.render(mutants.get("fill_rule_top_right"), s.pos, s.tri, s.resolution, ctx=ctx)
    rep, failures, _, _ = check.evaluate(gpu, references[s.name], ctx)
    assert rep.tri_id_mismatch > 0 or rep.coverage_mismatch > 0
    assert all(v.over_tolerance == 0 for v in rep.values.values())


def test_mutant_selection_and_unknown_names():
    assert [m.name for m in mutants.select("tri_id_*")] == ["tri_id_off_by_one"]
    assert len(mutants.select(None)) == len(mutants.MUTANTS)
    with pytest.raises(ValueError, match="no mutant matches"):
        mutants.select("nothing")
    with pytest.raises(ValueError, match="unknown mutant"):
        mutants.get("nothing")


def test_mutant_catalog_scenes_exist():
    assert set(SCENES) <= set(list_scenes())
    for m in mutants.MUTANTS:
        assert re.fullmatch(r"[a-z0-9_]+", m.name) and m.fault
