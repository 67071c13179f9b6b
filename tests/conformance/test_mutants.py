"""Fault injection: every mutant is caught by some scene; the real shaders raise no alarm."""

import re
from pathlib import Path

import pytest

from glraster.conformance import check, golden, mutants
from glraster.conformance.scenes import list_scenes, load_scene
from glraster.gpu.methods import error_model as gr_error_model_of
from glraster.gpu.shaders import shader_dir


def gr_error_model(ctx):
    """The hw error model of the check run (llvmpipe's documented deviations waived)."""
    return gr_error_model_of("hw", ctx)

# Cheap scenes that between them exercise every mutated feature (perspective, shared
# edges, ids, depth overlap); the full catalog would only add run time.
SCENES = ("tiny_viewport", "basic_triangle", "basic_perspective_triangle",
          "quad_shared_diagonal", "pixel_center_edges", "grid_pixel_centers",
          "depth_interpenetrating", "ortho_box", "fan_pixel_center",
          # multisampling: per-sample values, centroid points, per-sample coverage
          "ms_perspective_sample", "ms_perspective_centroid", "ms_depth_interpenetrating")


@pytest.fixture(scope="module")
def references():
    return {n: golden.reference_for(load_scene(n)) for n in SCENES}


def test_at_least_eight_mutants_with_distinct_faults():
    assert len(mutants.MUTANTS) >= 8
    assert len({m.name for m in mutants.MUTANTS}) == len(mutants.MUTANTS)
    assert len({(m.patches, m.target_dtype, m.depth_test, m.multisample, m.depth_clear,
                 m.depth_func) for m in mutants.MUTANTS}) == len(mutants.MUTANTS)


@pytest.mark.parametrize("m", mutants.MUTANTS, ids=lambda m: m.name)
def test_each_patch_applies_exactly_once_to_the_current_shaders(m):
    d = shader_dir()
    for file in mutants.REAL_SHADERS:
        text = (d / file).read_text()
        for p in (p for p in m.patches if p.file == file):
            assert text.count(p.old) == 1, (m.name, file, p.old)
            text = text.replace(p.old, p.new)
        assert m.source(file) == text


@pytest.mark.parametrize("m", mutants.MUTANTS, ids=lambda m: m.name)
def test_mutated_source_differs_from_the_real_one_only_where_patched(m):
    d = shader_dir()
    for file in mutants.REAL_SHADERS:
        real, mutated = (d / file).read_text(), m.source(file)
        patches = [p for p in m.patches if p.file == file]
        if not patches:
            assert file not in m.patched_files and mutated == real
            continue
        assert mutated != real and mutated.startswith("#version 450 core")
        # Same lines, so that a compile error's line number is the real file's.
        real_lines, mutated_lines = real.splitlines(), mutated.splitlines()
        assert len(mutated_lines) == len(real_lines)
        changed = [i for i, (a, b) in enumerate(zip(real_lines, mutated_lines)) if a != b]
        # Every changed line is one that a patch's old text covers.
        covered = set()
        for p in patches:
            start = real[:real.index(p.old)].count("\n") if p.old in real else None
            if start is not None:
                covered |= set(range(start, start + p.old.count("\n") + 1))
        assert changed and set(changed) <= covered, (file, changed, covered)
        # Undoing the replacements (in reverse order) gives back the real text exactly.
        undone = mutated
        for p in reversed(patches):
            assert undone.count(p.new) == 1
            undone = undone.replace(p.new, p.old)
        assert undone == real


@pytest.mark.parametrize("m", [m for m in mutants.MUTANTS if m.patches], ids=lambda m: m.name)
def test_generated_shader_files_keep_the_real_line_numbers(m):
    d = shader_dir()
    files = dict(zip(mutants.REAL_SHADERS, m.shader_files()))
    for file, path in files.items():
        if file not in m.patched_files:
            assert path == str(d / file)
            continue
        text = Path(path).read_text()
        assert m.name in path and Path(path).name == Path(file).name
        body = m.source(file)
        assert text.startswith(body)
        assert f"MUTANT {m.name}" in text[len(body):]
    assert m.shader_files() == tuple(files.values())  # stable paths: one cached program


def test_patches_matching_zero_or_two_times_raise_naming_the_mutant():
    frag = mutants.FRAG
    missing = mutants.Mutant("stale_patch", "x", patches=(
        mutants.Patch(frag, "out_tri_id = gl_PrimitiveID;", "out_tri_id = 0;"),))
    with pytest.raises(ValueError, match=r"'stale_patch'.*'out_tri_id = gl_PrimitiveID;' "
                                         r"does not occur in raster/raster.frag"):
        missing.source(frag)
    with pytest.raises(ValueError, match="stale_patch"):
        missing.shader_files()
    twice = mutants.Mutant("ambiguous_patch", "x", patches=(
        mutants.Patch(frag, "#ifdef OUT_PERSP", "#ifdef OUT_SCREEN"),))
    with pytest.raises(ValueError, match=r"'ambiguous_patch'.*'#ifdef OUT_PERSP' occurs 2 "
                                         r"times in raster/raster.frag"):
        twice.source(frag)
    # A later patch is matched against the text the earlier ones left.
    text = "a b"
    assert mutants.apply_patches("m", "f", text, [mutants.Patch(frag, "a", "b")]) == "b b"
    with pytest.raises(ValueError, match="'b' occurs 2 times in f"):
        mutants.apply_patches("m", "f", text, [mutants.Patch(frag, "a", "b"),
                                               mutants.Patch(frag, "b", "c")])


def test_patches_that_add_lines_or_name_other_files_are_refused():
    with pytest.raises(ValueError, match="'adds_a_line'.*as many lines"):
        mutants.Mutant("adds_a_line", "x", patches=(
            mutants.Patch(mutants.VERT, "void main() {", "uniform float u;\nvoid main() {"),))
    with pytest.raises(ValueError, match="'other_file'.*can only patch"):
        mutants.Mutant("other_file", "x", patches=(
            mutants.Patch("methods/divw.frag", "a", "b"),))
    with pytest.raises(ValueError, match="'no_op'.*differ"):
        mutants.Mutant("no_op", "x", patches=(mutants.Patch(mutants.VERT, "a", "a"),))


def test_no_full_shader_copies_left():
    d = shader_dir()
    assert not (d / "mutants").exists() or not [
        f for f in (d / "mutants").iterdir() if f.suffix in (".vert", ".frag")]


MULTISAMPLE_MUTANTS = {"wrong_sample_position", "centroid_as_center", "sample_mask_ignored"}


def test_every_mutant_is_caught_and_the_control_passes(ctx, references):
    scenes = [load_scene(n) for n in SCENES]
    chosen = list(mutants.MUTANTS)
    if 4 not in ctx.sample_counts:              # no multisample scene can run here
        scenes = [s for s in scenes if s.samples == 1]
        chosen = [m for m in chosen if m.name not in MULTISAMPLE_MUTANTS]
    results, control_failures = check.run_mutants(ctx, scenes, references, chosen,
                                                  model=gr_error_model(ctx))
    # No false alarm: the real shaders through the mutant renderer pass every scene.
    assert control_failures == []
    escaped = [m.name for m in results if not m.caught]
    assert not escaped, f"mutants not caught on {ctx.backend}: {escaped}"
    assert {m.name for m in results} == {m.name for m in chosen}
    caught_by = {m.name: m.caught_by for m in results}
    for name in MULTISAMPLE_MUTANTS & set(caught_by):
        assert caught_by[name].startswith("ms_"), (name, caught_by[name])


def test_fill_rule_mutant_changes_only_tie_pixels(ctx, references):
    # The rotated rendering keeps values within tolerance; only pixel centers lying exactly
    # on an edge change owner. That is what makes it a pure fill-rule fault.
    s = load_scene("quad_shared_diagonal")
    gpu = mutants.render(mutants.get("fill_rule_top_right"), s.pos, s.tri, s.resolution, ctx=ctx)
    rep = check.evaluate(gpu, references[s.name], ctx).report
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
