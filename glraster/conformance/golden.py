"""Golden EXR images of the scene catalog, produced by the reference rasterizer.

Each catalog scene has ``golden/<name>.exr`` (see :mod:`glraster.io.exr` for the layout): the
float64 reference (:func:`glraster.reference.rasterize`, llvmpipe fill rule) rounded once to
float32, cropped to the bounding box of covered pixels (lossless: everything outside is
empty). Goldens do not depend on any driver, so ``check`` can run anywhere: it recomputes
the reference and demands every stored bit back (float32 bit patterns, ids exactly), and
that the scene's geometry hash still matches the one recorded in the file.

Multisample scenes (S samples, the standard sample positions of
:mod:`glraster.geometry.samples`) keep the same EXR layout with the sample axis folded
into the width: an image W S wide whose column S x + s holds sample s of pixel x (the
layout of the GPU's resolve pass). Per-pixel barycentrics ("center", "centroid") are
repeated on the S columns of their pixel. The metadata records ``samples``,
``interpolation``, ``sample_positions`` and ``layout``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glraster.io import exr
from glraster import reference as _reference
from glraster.conformance.golden_folder import golden_dir
from glraster.conformance.scenes import Scene, list_scenes, load_scene
from glraster.geometry.samples import standard_positions

PRODUCER = "glraster.reference.rasterize (float64, fill rule llvmpipe), rounded to float32"
FILL_RULE = "llvmpipe"


def golden_available(directory=None) -> bool:
    """Whether there is a golden folder to check against (source tree or wheel)."""
    return golden_dir(directory).is_dir()


def golden_path(name: str, directory=None) -> Path:
    return golden_dir(directory) / f"{name}.exr"


LAYOUT = "sample axis folded into the width: column S x + s is sample s of pixel x"


def reference_for(scene: Scene, fill_rule=FILL_RULE, sample_positions=None):
    """The float64 reference raster of a scene (all of the scene's outputs, plus tri_id,
    which the tolerance model needs). ``fill_rule``: llvmpipe's for the goldens; a driver's
    detected FillRule (or None, the edge band) when judging that driver's coverage.
    Multisample scenes: ``sample_positions`` (S, 2), the driver's (None: the standard
    pattern, as the goldens)."""
    outputs = tuple(dict.fromkeys(scene.outputs + ("tri_id",)))
    if scene.samples == 1:
        return _reference.rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs,
                                    fill_rule=fill_rule)
    return _reference.rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs,
                                fill_rule=fill_rule, samples=scene.samples,
                                sample_positions=sample_positions,
                                interpolation=scene.interpolation)


def folded(raster, names) -> dict:
    """Output name -> (H, W S[, 3]) array of a multisampled raster, sample axis folded
    into the width (per-pixel barycentrics repeated on their pixel's S columns)."""
    samples = raster.samples
    out = {}
    for name in names:
        a = getattr(raster, name)
        if a is None:
            continue
        if name in ("persp", "screen") and raster.interpolation != "sample":
            a = np.repeat(a[:, :, None, :], samples, axis=2)
        h, w = a.shape[:2]
        out[name] = a.reshape((h, w * samples) + a.shape[3:])
    return out


def write_golden(scene: Scene, ref=None, directory=None) -> Path:
    """Write ``golden/<scene>.exr`` from the reference (computed unless given)."""
    ref = ref if ref is not None else reference_for(scene)
    kept = {n: getattr(ref, n) for n in scene.outputs}
    metadata = {"scene": scene.name, "scene_hash": scene.hash, "producer": PRODUCER,
                "fill_rule": FILL_RULE}
    if scene.samples > 1:
        kept = folded(ref, scene.outputs)
        metadata.update(samples=str(scene.samples), interpolation=scene.interpolation,
                        sample_positions=str(standard_positions(scene.samples).tolist()),
                        layout=LAYOUT)
    return exr.write_raster(golden_path(scene.name, directory), **kept, metadata=metadata)


def update(names=None, directory=None, progress=None, force=False) -> list[Path]:
    """Regenerate the goldens of ``names`` (default: every catalog scene). Without
    ``force``, a golden the reference still reproduces bit for bit is left untouched (no
    churn in version control). Returns the paths written."""
    paths = []
    for name in names or list_scenes():
        if progress:
            progress(name)
        scene = load_scene(name)
        ref = reference_for(scene)
        if not force and check_scene(scene, ref=ref, directory=directory).ok:
            continue
        paths.append(write_golden(scene, ref=ref, directory=directory))
    return paths


@dataclass
class GoldenResult:
    """Outcome of checking one golden file against the reference.

    mismatches: output name -> number of pixels whose stored bits differ
    """

    name: str
    ok: bool
    message: str
    mismatches: dict = field(default_factory=dict)
    raster: object = field(default=None, repr=False)  # the ExrRaster read, when readable


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)


def check_scene(scene: Scene, ref=None, directory=None) -> GoldenResult:
    """Compare the golden of ``scene`` bit for bit with the reference (computed unless
    given; a given reference must hold the scene's outputs)."""
    path = golden_path(scene.name, directory)
    if not path.is_file():
        return GoldenResult(scene.name, False,
                            f"no golden file {path} (run: glraster golden update {scene.name})")
    try:
        gold = exr.read_raster(path)
    except ValueError as exc:
        return GoldenResult(scene.name, False, f"unreadable golden: {exc}")
    stored_hash = gold.metadata.get("scene_hash")
    if stored_hash != scene.hash:
        return GoldenResult(scene.name, False,
                            f"scene geometry hash {scene.hash} differs from the golden's "
                            f"{stored_hash}: the scene changed (or its float64 generation "
                            f"rounds differently on this platform); regenerate the golden")
    height, width = scene.resolution
    if gold.resolution != (height, width * scene.samples):
        return GoldenResult(scene.name, False, f"golden resolution {gold.resolution} != "
                                               f"scene resolution {scene.resolution}"
                            + (f" x {scene.samples} samples" if scene.samples > 1 else ""))
    if str(gold.metadata.get("samples", "1")) != str(scene.samples) \
            or gold.metadata.get("interpolation", "center") != scene.interpolation:
        return GoldenResult(scene.name, False, "golden samples / interpolation differ from "
                                               "the scene's; regenerate the golden")
    missing = [n for n in scene.outputs if getattr(gold, n) is None]
    if missing:
        return GoldenResult(scene.name, False, f"golden lacks outputs {missing}")
    ref = ref if ref is not None else reference_for(scene)
    if scene.samples > 1 and not np.array_equal(ref.sample_positions,
                                                standard_positions(scene.samples)):
        ref = reference_for(scene)                # the goldens use the standard pattern
    arrays = folded(ref, scene.outputs + ("tri_id",)) if scene.samples > 1 else \
        {n: getattr(ref, n) for n in scene.outputs + ("tri_id",)}
    mask = arrays["tri_id"] >= 0
    # Outside the data window the golden is empty by construction: the reference must be
    # too. Inside it, compare stored bits (float32 patterns, ids exactly).
    y0, y1, x0, x1 = gold.window
    outside = int(mask.sum()) - int(mask[y0:y1, x0:x1].sum())
    mismatches = {}
    for name in scene.outputs:
        g = getattr(gold, name)
        r = arrays[name][y0:y1, x0:x1]
        if name == "tri_id":
            diff = g != r
        else:
            diff = _bits(g) != _bits(r)
            if diff.ndim == 3:
                diff = diff.any(axis=2)
        mismatches[name] = int(diff.sum()) + outside
    bad = {k: v for k, v in mismatches.items() if v}
    if bad:
        detail = ", ".join(f"{k}: {v} px" for k, v in bad.items())
        return GoldenResult(scene.name, False, f"reference differs from golden ({detail})",
                            mismatches, gold)
    return GoldenResult(scene.name, True, "bit-exact", mismatches, gold)


def check(names=None, directory=None, progress=None) -> list[GoldenResult]:
    """Check the goldens of ``names`` (default: every catalog scene)."""
    results = []
    for name in names or list_scenes():
        if progress:
            progress(name)
        results.append(check_scene(load_scene(name), directory=directory))
    return results


def folder_size(directory=None) -> int:
    """Total bytes of the .exr files in the golden folder."""
    return sum(p.stat().st_size for p in golden_dir(directory).glob("*.exr"))
