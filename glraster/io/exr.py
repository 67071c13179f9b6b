"""Multi-channel float32 EXR files of rasters, through OpenImageIO.

Layout of a glraster EXR (one file, two parts, ZIP compression, lossless):

- part 0, named ``raster``, FLOAT channels ``persp.b0 persp.b1 persp.b2``,
  ``screen.b0 screen.b1 screen.b2`` and ``depth.Z`` (those outputs present);
- part 1, named ``tri_id``, one UINT channel ``tri_id.id`` holding triangle index + 1
  (0 = empty pixel), stored as 32-bit unsigned integers so every id is exact. It is a
  separate part because OpenImageIO's Python binding converts integer data by scaling
  when one part mixes float and integer channels.

Images are written **upright** (file row 0 is the top row, i.e. array row H - 1, since
glraster arrays have row 0 at the bottom); the attribute ``glraster:orientation`` says so.
The data window may be smaller than the display window (the full resolution): pixels
outside it are empty (barycentrics 0, depth 1, id -1). :func:`write_raster` crops to the
covered pixels' bounding box by default, which loses nothing.

Metadata attributes: ``glraster:version``, ``glraster:producer``, ``glraster:scene``,
``glraster:scene_hash``, ``glraster:outputs``, ``glraster:orientation`` plus any extra
``glraster:*`` strings given by the caller.

Writes are atomic: the file is written next to the target under a temporary name and
renamed over it, so a reader never sees a partial file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from glraster.errors import ArgumentError
from glraster.io.atomic import atomic_write, image_write_error

ORIENTATION = "upright: file row 0 is the top row (glraster array row H-1)"
_LAYERS = {"persp": ("persp.b0", "persp.b1", "persp.b2"),
           "screen": ("screen.b0", "screen.b1", "screen.b2"),
           "depth": ("depth.Z",)}
TRI_ID_CHANNEL = "tri_id.id"
EMPTY = {"persp": 0.0, "screen": 0.0, "depth": 1.0}


@dataclass
class ExrRaster:
    """Contents of a glraster EXR, in glraster orientation (row 0 at the bottom).

    resolution : (H, W) display window (the full image)
    window     : (y0, y1, x0, x1) half-open data window in array coordinates
                 (row 0 at the bottom); arrays below cover exactly this window
    persp, screen : (y1-y0, x1-x0, 3) float32 or None
    depth      : (y1-y0, x1-x0) float32 or None
    tri_id     : (y1-y0, x1-x0) int64 or None, -1 = empty
    metadata   : dict of the ``glraster:*`` attributes (prefix removed)
    """

    resolution: tuple
    window: tuple
    persp: np.ndarray | None = None
    screen: np.ndarray | None = None
    depth: np.ndarray | None = None
    tri_id: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(n for n in ("persp", "screen", "depth", "tri_id")
                     if getattr(self, n) is not None)

    def full(self, name: str) -> np.ndarray:
        """Output ``name`` expanded to the full (H, W[, 3]) image, empty values outside the
        data window (0 for barycentrics, 1.0 for depth, -1 for tri_id)."""
        data = getattr(self, name)
        if data is None:
            raise ArgumentError(
                "name", f"this EXR holds no {name!r} output (it has {self.outputs})")
        h, w = self.resolution
        fill = -1 if name == "tri_id" else EMPTY[name]
        out = np.full((h, w) + data.shape[2:], fill, dtype=data.dtype)
        y0, y1, x0, x1 = self.window
        out[y0:y1, x0:x1] = data
        return out


def coverage_window(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Half-open (y0, y1, x0, x1) bounding box of True pixels of an (H, W) mask; a 1x1
    window at the origin when nothing is covered (EXR needs a non-empty data window)."""
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if not len(ys):
        return (0, 1, 0, 1)
    return (int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1)


def _spec(width, height, nchannels, fmt, names, window, resolution, part_name, meta):
    y0, y1, x0, x1 = window
    h, _ = resolution
    spec = oiio.ImageSpec(width, height, nchannels, fmt)
    spec.channelnames = tuple(names)
    # EXR y grows downwards: array rows [y0, y1) from the bottom are file rows [h-y1, h-y0).
    spec.x, spec.y = x0, h - y1
    spec.full_x, spec.full_y = 0, 0
    spec.full_width, spec.full_height = resolution[1], resolution[0]
    spec.attribute("compression", "zip")
    spec.attribute("name", part_name)
    for key, value in meta.items():
        spec.attribute(f"glraster:{key}", str(value))
    return spec


def write_raster(path, raster=None, *, persp=None, screen=None, depth=None, tri_id=None,
                 resolution=None, window="covered", metadata=None) -> Path:
    """Write outputs of a raster to a glraster EXR (atomically). Returns the path.

    Either pass ``raster`` (anything with persp/screen/depth/tri_id attributes, e.g. a
    :class:`glraster.Raster` or reference raster; float64 values are rounded to float32
    once) or the arrays as keywords. Arrays are (H, W, 3) / (H, W), row 0 at the bottom.

    window: "covered" (default: bounding box of pixels with tri_id >= 0, or with depth < 1
    when there is no tri_id), "full", or an explicit (y0, y1, x0, x1) half-open box.
    metadata: extra ``glraster:*`` attributes (str values); ``version`` is always set.
    """
    arrays = {}
    for name, given in (("persp", persp), ("screen", screen), ("depth", depth),
                        ("tri_id", tri_id)):
        value = given if given is not None else (getattr(raster, name, None) if raster is not None else None)
        if value is not None:
            arrays[name] = np.asarray(value)
    if not arrays:
        raise ArgumentError(
            "raster", "write_raster needs at least one of persp, screen, depth, tri_id")
    shapes = {n: a.shape[:2] for n, a in arrays.items()}
    if len(set(shapes.values())) != 1:
        raise ArgumentError("raster", f"outputs must share one (H, W) resolution, got {shapes}")
    h, w = next(iter(shapes.values()))
    if resolution is not None and tuple(resolution) != (h, w):
        raise ArgumentError(
            "resolution", f"resolution {tuple(resolution)} does not match the arrays' {(h, w)}")
    for name, arr in arrays.items():
        want = (h, w, 3) if name in ("persp", "screen") else (h, w)
        if arr.shape != want:
            raise ArgumentError(name, f"{name} must have shape {want}, got {arr.shape}")
    if "tri_id" in arrays:
        ids = arrays["tri_id"]
        if not np.issubdtype(ids.dtype, np.integer):
            raise ArgumentError("tri_id", f"tri_id must have an integer dtype, got {ids.dtype}")
        if ids.size and (ids.min() < -1 or ids.max() >= 2**32 - 1):
            raise ArgumentError("tri_id", "tri_id values must lie in [-1, 2^32 - 2]")

    if isinstance(window, str):
        if window == "full":
            window = (0, h, 0, w)
        elif window == "covered":
            if "tri_id" in arrays:
                mask = arrays["tri_id"] >= 0
            elif "depth" in arrays:
                mask = arrays["depth"] < 1
            else:
                mask = np.ones((h, w), bool)
            window = coverage_window(mask)
        else:
            raise ArgumentError(
                "window", f"window must be 'covered', 'full' or (y0, y1, x0, x1), got {window!r}")
    y0, y1, x0, x1 = (int(v) for v in window)
    if not (0 <= y0 < y1 <= h and 0 <= x0 < x1 <= w):
        raise ArgumentError(
            "window", f"window {window} must be a non-empty box inside (0, {h}, 0, {w})")
    window = (y0, y1, x0, x1)

    from glraster._version import __version__
    meta = {"version": __version__, "orientation": ORIENTATION,
            "outputs": ",".join(arrays)}
    meta.update({str(k): v for k, v in (metadata or {}).items()})

    def upright(a):  # crop, then flip rows so file row 0 is the top
        return np.ascontiguousarray(a[y0:y1, x0:x1][::-1])

    float_names, float_planes = [], []
    for name in ("persp", "screen", "depth"):
        if name in arrays:
            a = upright(arrays[name]).astype(np.float32)
            planes = [a[..., i] for i in range(3)] if a.ndim == 3 else [a]
            float_names += _LAYERS[name]
            float_planes += planes
    parts = []
    ww, hh = x1 - x0, y1 - y0
    if float_planes:
        parts.append((_spec(ww, hh, len(float_planes), oiio.FLOAT, float_names, window,
                            (h, w), "raster", meta),
                      np.ascontiguousarray(np.stack(float_planes, axis=-1))))
    if "tri_id" in arrays:
        ids = (upright(arrays["tri_id"]).astype(np.int64) + 1).astype(np.uint32)
        parts.append((_spec(ww, hh, 1, oiio.UINT, (TRI_ID_CHANNEL,), window, (h, w),
                            "tri_id", meta), ids[..., None]))

    path = Path(path)
    with atomic_write(path, suffix=".exr") as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OSError(f"OpenImageIO cannot write EXR files: {oiio.geterror()}")
        specs = tuple(spec for spec, _ in parts)
        ok = out.open(tmp, specs)
        for i, (spec, data) in enumerate(parts):
            if i:
                ok = ok and out.open(tmp, spec, "AppendSubimage")
            ok = ok and out.write_image(data)
        ok = out.close() and ok
        message = out.geterror()
        if not ok or message:
            raise image_write_error(tmp, message or oiio.geterror(),
                                    sum(data.nbytes for _, data in parts))
    return path


def read_raster(path) -> ExrRaster:
    """Read a glraster EXR written by :func:`write_raster` (any part order).

    Returns an :class:`ExrRaster` in glraster orientation. Raises ValueError when the file
    is not a readable EXR, lacks glraster channels, or its parts disagree on the window.
    """
    path = Path(path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ArgumentError("path", f"{path}: cannot open as an image ({oiio.geterror()})")
    try:
        found: dict = {}
        meta: dict = {}
        geometry = None
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            geo = (spec.x, spec.y, spec.width, spec.height, spec.full_width, spec.full_height)
            if geometry is not None and geo != geometry:
                raise ArgumentError(
                    "path", f"{path}: parts have different data windows {geometry} and {geo}")
            geometry = geo
            for attr in spec.extra_attribs:
                if attr.name.startswith("glraster:"):
                    meta[attr.name[len("glraster:"):]] = attr.value
            names = list(spec.channelnames)
            data = inp.read_image(sub, 0, 0, spec.nchannels, oiio.UNKNOWN)
            if data is None:
                raise ArgumentError("path", f"{path}: reading part {sub} failed ({inp.geterror()})")
            data = np.asarray(data).reshape(spec.height, spec.width, spec.nchannels)
            for i, n in enumerate(names):
                found[n] = data[..., i][::-1]
            sub += 1
    finally:
        inp.close()
    if geometry is None:
        raise ArgumentError("path", f"{path}: no image parts")
    x, y, width, height, full_w, full_h = geometry
    window = (full_h - (y + height), full_h - y, x, x + width)
    result = ExrRaster(resolution=(full_h, full_w), window=window, metadata=meta)
    for name, channels in _LAYERS.items():
        present = [c in found for c in channels]
        if any(present) and not all(present):
            raise ArgumentError("path", f"{path}: layer {name!r} is incomplete (needs {channels})")
        if all(present):
            planes = [np.ascontiguousarray(found[c], dtype=np.float32) for c in channels]
            setattr(result, name, np.stack(planes, -1) if len(planes) == 3 else planes[0])
    if TRI_ID_CHANNEL in found:
        raw = found[TRI_ID_CHANNEL]
        if raw.dtype != np.uint32:
            raise ArgumentError(
                "path", f"{path}: {TRI_ID_CHANNEL} must be a UINT channel, got {raw.dtype}")
        result.tri_id = raw.astype(np.int64) - 1
    if not result.outputs:
        raise ArgumentError("path", f"{path}: no glraster channels (found {sorted(found)})")
    return result
