"""Golden EXR images of the scene catalog, produced by the reference rasterizer.

Each catalog scene has ``golden/<name>.exr`` (see :mod:`glraster.io.exr` for the layout): the
float64 reference (:func:`glraster.reference.rasterize`, llvmpipe fill rule) rounded once to
float32, cropped to the bounding box of covered pixels (lossless: everything outside is
empty). Goldens do not depend on any driver, so ``check`` can run anywhere: it recomputes
the reference and demands every stored bit back (float32 bit patterns, ids exactly), and
that the scene's geometry hash still matches the one recorded in the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glraster.io import exr
from glraster import reference as _reference
from glraster.conformance.golden_folder import golden_dir
from glraster.conformance.scenes import Scene, list_scenes, load_scene

PRODUCER = "glraster.reference.rasterize (float64, fill rule llvmpipe), rounded to float32"
FILL_RULE = "llvmpipe"


def golden_available(directory=None) -> bool:
    """Whether there is a golden folder to check against (source tree or wheel)."""
    return golden_dir(directory).is_dir()


def golden_path(name: str, directory=None) -> Path:
    return golden_dir(directory) / f"{name}.exr"


def reference_for(scene: Scene, fill_rule=FILL_RULE):
    """The float64 reference raster of a scene (all of the scene's outputs, plus tri_id,
    which the tolerance model needs). ``fill_rule``: llvmpipe's for the goldens; a driver's
    detected FillRule (or None, the edge band) when judging that driver's coverage."""
    outputs = tuple(dict.fromkeys(scene.outputs + ("tri_id",)))
    return _reference.rasterize(scene.pos, scene.tri, scene.resolution, outputs=outputs,
                                fill_rule=fill_rule)


def write_golden(scene: Scene, ref=None, directory=None) -> Path:
    """Write ``golden/<scene>.exr`` from the reference (computed unless given)."""
    ref = ref if ref is not None else reference_for(scene)
    kept = {n: getattr(ref, n) for n in scene.outputs}
    return exr.write_raster(
        golden_path(scene.name, directory), **kept,
        metadata={"scene": scene.name, "scene_hash": scene.hash, "producer": PRODUCER,
                  "fill_rule": FILL_RULE},
    )


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
    if gold.resolution != tuple(scene.resolution):
        return GoldenResult(scene.name, False, f"golden resolution {gold.resolution} != "
                                               f"scene resolution {scene.resolution}")
    missing = [n for n in scene.outputs if getattr(gold, n) is None]
    if missing:
        return GoldenResult(scene.name, False, f"golden lacks outputs {missing}")
    ref = ref if ref is not None else reference_for(scene)
    # Outside the data window the golden is empty by construction: the reference must be
    # too. Inside it, compare stored bits (float32 patterns, ids exactly).
    y0, y1, x0, x1 = gold.window
    outside = int(ref.mask.sum()) - int(ref.mask[y0:y1, x0:x1].sum())
    mismatches = {}
    for name in scene.outputs:
        g = getattr(gold, name)
        r = getattr(ref, name)[y0:y1, x0:x1]
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
