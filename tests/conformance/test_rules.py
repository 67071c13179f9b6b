"""Rule detection (glraster.conformance.rules): synthetic drivers played by the parameterized
reference, an inconsistent driver, and the real llvmpipe."""

import numpy as np
import pytest

from glraster import reference
from glraster.conformance import mutants, rules
from glraster.geometry.fill_rule import LLVMPIPE, FillRule, candidates
from glraster.geometry.window import window_float32


def synthetic(rule):
    """A 'driver' whose coverage is the reference's under ``rule``."""
    def render(pos, tri, resolution):
        return reference.rasterize(pos, tri, resolution, outputs=("tri_id",),
                                   fill_rule=rule).tri_id
    return render


def test_probe_scene_is_exact_in_float32_and_its_triangles_never_share_a_pixel():
    # probe_scene raises if a window position is not exactly the intended one or if two
    # cells could reach the same pixel; check the exactness here again, independently.
    s = rules.probe_scene()
    assert len(s.tri) == len(s.labels) > 300
    got = window_float32(s.pos, s.resolution).reshape(-1, 3, 2)
    np.testing.assert_array_equal(got, s.window)       # exact: no tolerance
    assert {label.split(":")[0] for label in s.labels} == {"snap x", "snap y", "tie"}


def test_every_candidate_rule_predicts_a_different_probe_image():
    # The guarantee behind "the unique candidate that predicts every probe pixel": no two
    # of the 360 rules (12 bits x 6 ties x 5 snappings) give the same ids anywhere.
    images = {}
    for rule in candidates():
        images.setdefault(rules.predict(rule).tobytes(), []).append(rule.name)
    same = [names for names in images.values() if len(names) > 1]
    assert not same, same[:5]
    assert len(images) == len(candidates()) == 360


@pytest.mark.parametrize("rule", [
    LLVMPIPE,
    FillRule(4, "top-left", "truncate"),
    FillRule(12, "bottom-right", "round-half-up"),
    FillRule(6, "all", "round-half-away"),
    FillRule(3, "none", "floor"),
    FillRule(8, "top-right", "round-half-even"),
], ids=str)
def test_synthetic_driver_rules_are_detected_exactly(rule):
    d = rules.detect(synthetic(rule))
    assert d.status == "identified" and d.rule == rule and d.matching == [rule]
    assert d.rule.name in d.summary() and "coverage judged exactly" in d.summary()


def test_a_driver_without_snapping_is_unidentified_and_the_closest_rule_is_named():
    # fill_rule=None: float64 point-in-triangle at the centers, no snapping (like a float
    # rasterizer): every fixed-point candidate mispredicts some of the finest offsets.
    d = rules.detect(synthetic(None))
    assert d.status == "unidentified" and d.rule is None and not d.matching
    assert d.closest and d.closest[0][1] > 0 and d.mismatched_probes
    assert "edge band" in d.summary() and "closest" in d.summary()


def test_a_driver_that_snaps_x_and_y_differently_is_unidentified():
    s = rules.probe_scene()
    x_rule, y_rule = FillRule(8, "bottom-left", "round-half-even"), FillRule(4, "bottom-left",
                                                                            "floor")
    from_y = np.array([label.startswith("snap y") for label in s.labels])

    def render(pos, tri, resolution):
        a, b = rules.predict(x_rule), rules.predict(y_rule)
        return np.where(np.isin(a, np.flatnonzero(from_y)) | np.isin(b, np.flatnonzero(from_y)),
                        b, a)
    d = rules.detect(render)
    assert d.status == "unidentified"
    assert any(label.startswith("snap") for label in d.mismatched_probes)


def test_a_driver_that_cannot_draw_the_probes_is_unidentified_not_a_crash():
    def render(pos, tri, resolution):
        raise RuntimeError("no")
    d = rules.detect(render)
    assert d.status == "error" and d.rule is None and "RuntimeError: no" in d.message


def test_fill_rule_arguments_are_validated():
    with pytest.raises(ValueError, match="subpixel_bits must be"):
        FillRule(0)
    with pytest.raises(ValueError, match="tie must be one of"):
        FillRule(8, "top-left-ish")
    with pytest.raises(ValueError, match="snap must be one of"):
        FillRule(8, "top-left", "round")
    with pytest.raises(ValueError, match="fill_rule must be 'llvmpipe' or None"):
        reference.rasterize(np.zeros((3, 4), np.float32) + [0, 0, 0, 1], [[0, 1, 2]], (4, 4),
                            fill_rule="softpipe")


def test_llvmpipe_rules_are_detected_on_the_gpu(ctx):
    d = rules.detect_on(ctx)
    if not ctx.is_llvmpipe:
        pytest.skip(f"the detected rule is only known for llvmpipe, not {ctx.renderer}")
    assert d.status == "identified"
    assert (d.rule.subpixel_bits, d.rule.tie, d.rule.snap) == (8, "bottom-left",
                                                              "round-half-even")
    assert d.reported_subpixel_bits == ctx.subpixel_bits == 8


def test_the_top_right_mutant_is_detected_as_a_top_right_rule(ctx):
    # The mutant renders the image rotated by 180 degrees: left edges become right ones,
    # bottom ones top ones; round-half-even is symmetric, so the rule is llvmpipe's mirrored.
    if not ctx.is_llvmpipe:
        pytest.skip("the mirrored rule is known for llvmpipe only")
    m = mutants.get("fill_rule_top_right")
    d = rules.detect_on(ctx, render=lambda *a, **k: mutants.render(m, *a, **k))
    assert d.rule == FillRule(8, "top-right", "round-half-even")
