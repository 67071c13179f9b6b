"""Matplotlib figures: the one setup behind every figure glraster writes.

Every figure (the benchmark's time/error plot, the stress sweeps, the distortion figures,
the check report's summary) is drawn with

    with figures.figure("out/plot.png", figsize=(8, 5), title="...") as fig:
        ax = fig.subplots()
        ...

which gives a :class:`matplotlib.figure.Figure` on the Agg canvas (no pyplot, no global
backend switch, no GUI; safe in threads), with :data:`STYLE` in force while it is drawn
and saved, and on leaving the block saves it with metadata (``Title``, ``Description``,
``Software``: glraster and its version) atomically: the file is written next to the target
under a temporary name and renamed over it, so a failure while drawing writes nothing and
a failure while saving leaves neither a partial file nor the temporary one.

The format follows the suffix (PNG by default; PDF and SVG get the metadata keys their
formats allow).
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from glraster.io.atomic import atomic_write

__all__ = ["STYLE", "PALETTE", "colors", "colormap_lut", "figure", "save"]

#: rcParams in force while a glraster figure is drawn and saved.
STYLE = {
    "figure.facecolor": "white",
    "savefig.facecolor": "white",
    "savefig.dpi": 110,
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "legend.framealpha": 0.9,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.markersize": 5,
    "image.interpolation": "nearest",
    "axes.spines.top": False,
    "axes.spines.right": False,
}

#: Colors given to named series (methods) in order; the same name gets the same color in
#: every figure that is given the same list of names.
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")


def colors(names) -> dict:
    """{name: color} in the order of ``names`` (cycling through :data:`PALETTE`)."""
    return {n: PALETTE[i % len(PALETTE)] for i, n in enumerate(names)}


def colormap_lut(name: str = "viridis", n: int = 256):
    """(n, 3) uint8 lookup table of a matplotlib colormap."""
    import numpy as np
    from matplotlib import colormaps

    return (colormaps[name](np.linspace(0.0, 1.0, n))[:, :3] * 255 + 0.5).astype(np.uint8)


def _metadata(fmt: str, title: str | None, description: str | None) -> dict | None:
    from glraster._version import __version__

    software = f"glraster {__version__}"
    if fmt == "png":
        meta = {"Software": software}
        if title:
            meta["Title"] = title
        if description:
            meta["Description"] = description
        return meta
    if fmt == "pdf":
        return {"Creator": software, "Title": title, "Subject": description}
    if fmt == "svg":
        return {"Creator": software, "Title": title, "Description": description}
    return None


def save(fig, path, *, title: str | None = None, description: str | None = None,
         dpi: float | None = None) -> Path:
    """Save ``fig`` to ``path`` atomically with metadata (see the module doc). Creates the
    parent directory. Returns the path."""
    path = Path(path)
    fmt = path.suffix[1:].lower() or "png"
    with atomic_write(path, suffix=f".{fmt}") as tmp:
        meta = _metadata(fmt, title, description)
        kwargs = {"metadata": {k: v for k, v in meta.items() if v is not None}} if meta else {}
        fig.savefig(tmp, format=fmt, dpi=dpi if dpi is not None else "figure", **kwargs)
    return path


@contextmanager
def figure(path, *, figsize=(8.0, 5.0), dpi: float | None = None, title: str | None = None,
           description: str | None = None, layout: str | None = "constrained"):
    """Context manager yielding a new Agg :class:`~matplotlib.figure.Figure`; on a normal
    exit it is saved to ``path`` (atomically, with metadata). If the block raises, nothing
    is written. ``dpi`` defaults to ``STYLE["savefig.dpi"]``."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context(STYLE):
        dpi = dpi if dpi is not None else STYLE["savefig.dpi"]
        fig = Figure(figsize=figsize, dpi=dpi, layout=layout)
        FigureCanvasAgg(fig)
        yield fig
        save(fig, path, title=title, description=description, dpi=dpi)
