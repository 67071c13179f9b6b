"""The HTML report of a check run: a folder with ``index.html`` and ``img/*.png``.

Per scene it shows four images, upright (row 0 of the arrays is at the bottom, so rows are
flipped for display), cropped to the pixels either side covers and reduced to at most
``MAX_IMAGE_PX`` on a side (max-pooling for the error and coverage maps, so no defect
disappears):

- GPU: perspective-correct barycentrics (b0, b1, b2) as RGB; empty pixels dark gray,
  NaN/Inf magenta;
- reference: the same from the float64 reference;
- error heatmap: the largest error/tolerance ratio over persp, screen and depth, log scale
  1e-3 .. 1 (viridis), red above 1 (a failure), dark gray where nothing was compared;
- coverage difference: gray both cover, blue reference only, orange GPU only, yellow a
  difference accepted in the edge band or a depth tie, red both cover with different ids.

It also holds the per-output error statistics, the failures, golden status and timings,
a summary figure (glraster.io.figures) of the worst error/tolerance per scene, and the mutant
table. Nothing is loaded from the network; the page works from ``file://``.
"""

from __future__ import annotations

import html
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from glraster.errors import ArgumentError
from glraster.io import figures
from glraster.io.atomic import atomic_write, staged_error, write_text
from glraster.io.png import EMPTY_RGB, bary_rgb, write_png

MAX_IMAGE_PX = 384


def _crop_window(mask: np.ndarray, margin: int = 2):
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    if not len(ys):
        return (0, min(h, 64), 0, min(w, 64))
    return (max(0, ys[0] - margin), min(h, ys[-1] + 1 + margin),
            max(0, xs[0] - margin), min(w, xs[-1] + 1 + margin))


def _factor(shape) -> int:
    return max(1, int(np.ceil(max(shape[:2]) / MAX_IMAGE_PX)))


def _pool_max(a: np.ndarray, f: int) -> np.ndarray:
    """Max over f x f blocks of an (H, W[, C]) array (edges padded with the minimum)."""
    if f == 1:
        return a
    h, w = a.shape[:2]
    ph, pw = -h % f, -w % f
    pad = [(0, ph), (0, pw)] + [(0, 0)] * (a.ndim - 2)
    fill = a.min() if a.size else 0
    b = np.pad(a, pad, constant_values=fill)
    b = b.reshape(b.shape[0] // f, f, b.shape[1] // f, f, *a.shape[2:])
    return b.max(axis=(1, 3))


def heat_rgb(ratio, compared) -> np.ndarray:
    """(H, W, 3) uint8: log10 error/tolerance from 1e-3 (dark) to 1 (yellow), red above 1."""
    rgb = np.empty(ratio.shape + (3,), np.uint8)
    rgb[:] = EMPTY_RGB
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((np.log10(np.maximum(ratio, 1e-12)) + 3.0) / 3.0, 0.0, 1.0)
    lut = figures.colormap_lut("viridis", 256)
    rgb[compared] = lut[(t[compared] * 255).astype(int)]
    rgb[compared & ~(ratio <= 1)] = (255, 0, 0)
    return rgb


COVERAGE_COLORS = np.array([(0, 0, 0), (110, 110, 110), (255, 230, 0), (40, 110, 255),
                            (255, 140, 0), (255, 0, 0)], np.uint8)


def coverage_codes(gpu_mask, ref_mask, ambiguous, id_mismatch) -> np.ndarray:
    """(H, W) uint8 class per pixel, in increasing severity: 0 empty, 1 both cover,
    2 difference accepted (edge band / depth tie), 3 reference only, 4 GPU only,
    5 both cover with different triangle ids."""
    code = np.zeros(gpu_mask.shape, np.uint8)
    code[gpu_mask & ref_mask] = 1
    differ = gpu_mask != ref_mask
    code[differ & ambiguous] = 2
    code[differ & ~ambiguous & ref_mask] = 3
    code[differ & ~ambiguous & gpu_mask] = 4
    code[id_mismatch] = 5
    return code


def _sample_zero(raster):
    """Sample 0 of a multisampled raster as a single-sample one, with its per-pixel
    barycentrics ("center" / "centroid") or those of sample 0 ("sample")."""
    import copy

    view = copy.copy(raster)
    view.samples = 1
    view.mask = raster.mask[..., 0]
    for name in ("tri_id", "depth", "edge_band", "depth_tie"):
        if getattr(raster, name, None) is not None:
            setattr(view, name, getattr(raster, name)[..., 0])
    if raster.interpolation == "sample":
        for name in ("persp", "screen"):
            if getattr(raster, name) is not None:
                setattr(view, name, getattr(raster, name)[..., 0, :])
    return view


class HtmlReport:
    """Collects scenes during a check run and writes ``directory/index.html``.

    Use ``add_scene(result, artifacts)`` as the ``on_scene`` callback of
    :func:`glraster.conformance.check.run`, then ``finish(check_result)``, inside ``with
    HtmlReport(directory) as report:``. The run's images go to a hidden folder of their own
    in ``directory`` (``img``: its path), which replaces ``img/`` when ``finish`` writes
    ``index.html``; a run that raises or is interrupted before then leaves the report that
    was there as it was, and the ``with`` block removes the run's images.
    """

    def __init__(self, directory):
        self.dir = Path(directory)
        self._made = not self.dir.exists()     # (then discard removes it, if left empty)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.img = Path(tempfile.mkdtemp(prefix=".img.", dir=self.dir))
        self.images: dict[str, dict] = {}

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        stage = self.img
        self.discard()
        if isinstance(exc, OSError):   # (named where the image goes, not its staged copy)
            error = staged_error(exc, stage, self.dir / "img")
            if error is not exc:
                raise error from exc

    def discard(self) -> None:
        """Remove this run's images unless ``finish`` published them."""
        if self.img != self.dir / "img":
            shutil.rmtree(self.img, ignore_errors=True)
            if self._made and not any(self.dir.iterdir()):
                self.dir.rmdir()

    def _publish(self) -> Path | None:
        """Move this run's images to ``img/``; returns where the old ones went (None: none)."""
        final, old = self.dir / "img", None
        if final.exists():
            old = Path(tempfile.mkdtemp(prefix=".img.old.", dir=self.dir))
            os.replace(final, old / "img")
        os.chmod(self.img, 0o755)   # (mkdtemp made it 0700; the images are shared, 0644)
        os.replace(self.img, final)
        self.img = final
        return old

    def add_scene(self, res, art):
        """Write the four images of one scene (nothing when the scene raised)."""
        if art is None:
            return
        gpu, ref, rep = art.gpu, art.ref, art.report
        if getattr(gpu, "samples", 1) > 1:       # the pictures show sample 0
            gpu, ref = _sample_zero(gpu), _sample_zero(ref)
        y0, y1, x0, x1 = _crop_window(gpu.mask | ref.mask)
        f = _factor((y1 - y0, x1 - x0))
        sl = (slice(y0, y1), slice(x0, x1))
        names = {}

        def save(kind, rgb, pooled=None):
            if f > 1:
                rgb = pooled if pooled is not None else rgb[::f, ::f]
            fname = f"{res.name}_{kind}.png"
            write_png(self.img / fname, rgb)
            names[kind] = fname

        gpu_b = gpu.persp if gpu.persp is not None else gpu.screen
        ref_b = ref.persp if ref.persp is not None else ref.screen
        save("gpu", bary_rgb(gpu_b[sl] if gpu_b is not None else None, gpu.mask[sl]))
        save("ref", bary_rgb(ref_b[sl] if ref_b is not None else None, ref.mask[sl]))
        ratio = np.zeros((y1 - y0, x1 - x0))
        for name in rep.maps.outputs:
            ratio = np.maximum(ratio, np.nan_to_num(rep.maps.ratio(name)[sl], nan=np.inf))
        compared = gpu.mask[sl] & ref.mask[sl]
        heat = heat_rgb(ratio, compared)
        save("error", heat, _pool_heat(ratio, compared, f) if f > 1 else None)
        amb = ref.ambiguous[sl]
        idm = np.zeros_like(compared)
        if gpu.tri_id is not None:
            idm = compared & (gpu.tri_id[sl] != ref.tri_id[sl]) & ~amb
        codes = coverage_codes(gpu.mask[sl], ref.mask[sl], amb, idm)
        save("coverage", COVERAGE_COLORS[_pool_max(codes, f)])
        self.images[res.name] = {"files": names, "crop": (y0, y1, x0, x1), "factor": f}

    def add_images(self, name: str, info: dict, files: dict) -> None:
        """Add the images of scene ``name`` made elsewhere (another process or machine ran
        :meth:`add_scene`): ``info`` is its entry of ``images``, ``files`` {file name: PNG
        bytes}."""
        for fname, data in files.items():
            if Path(fname).name != fname:
                raise ArgumentError(
                    "files", f"files: image name {fname!r} must be a bare file name")
            with atomic_write(self.img / fname) as tmp:
                Path(tmp).write_bytes(data)
        self.images[name] = info

    def _summary_figure(self, result) -> str | None:
        scenes = [s for s in result.scenes if s.report is not None]
        if not scenes:
            return None
        fname = "summary.png"
        with figures.figure(self.img / fname, figsize=(12, max(4, 0.22 * len(scenes) + 1)),
                            dpi=80, title="glraster check: worst error/tolerance per scene",
                            description=f"{result.renderer} via {result.backend}") as fig:
            ax, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 1]})
            y = np.arange(len(scenes))
            for k, (name, color) in enumerate((("persp", "#1f77b4"), ("screen", "#ff7f0e"),
                                               ("depth", "#2ca02c"))):
                vals = [max(s.report.values[name].worst_ratio, 1e-4)
                        if name in s.report.values else np.nan for s in scenes]
                ax.barh(y + (k - 1) * 0.27, vals, height=0.27, color=color, label=name)
            ax.axvline(1.0, color="red", lw=1)
            ax.set_xscale("log")
            ax.set_xlim(1e-4, max(10.0, ax.get_xlim()[1]))
            ax.set_yticks(y, [s.name for s in scenes], fontsize=8)
            ax.invert_yaxis()
            ax.set_xlabel("worst error / per-pixel tolerance (fails above 1)")
            ax.legend(loc="lower right", fontsize=8)
            ax2.barh(y, [s.seconds for s in scenes], color="#888")
            ax2.set_yticks(y, [""] * len(scenes))
            ax2.invert_yaxis()
            ax2.set_xlabel("seconds")
            fig.suptitle(f"{result.renderer} via {result.backend}", fontsize=10)
        return fname

    def finish(self, result) -> Path:
        """Write index.html and put this run's images in ``img/`` (both replace the old
        ones at the end, together); returns index.html's path."""
        fig = self._summary_figure(result)
        e = html.escape
        n_ok = sum(s.ok for s in result.scenes)
        verdict = "PASS" if result.ok else "FAIL"
        parts = [f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>glraster check: {verdict}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 24px; background: #fafafa; color: #222; }}
h1 {{ margin-bottom: 4px; }} .meta {{ color: #555; margin-bottom: 16px; }}
.verdict {{ display: inline-block; padding: 2px 10px; border-radius: 4px; color: #fff; }}
.PASS {{ background: #2a7d2a; }} .FAIL, .ERROR {{ background: #c62828; }}
table {{ border-collapse: collapse; margin: 8px 0 16px; font-size: 13px; }}
th, td {{ border: 1px solid #ccc; padding: 3px 8px; text-align: right; white-space: nowrap; }}
td.wrap {{ white-space: normal; min-width: 360px; }}
th {{ background: #eee; }} td.l, th.l {{ text-align: left; }}
tr.fail td {{ background: #fde0e0; }}
section.scene {{ background: #fff; border: 1px solid #ddd; border-radius: 6px; padding: 12px 16px; margin: 16px 0; }}
.figs {{ display: flex; flex-wrap: wrap; gap: 12px; }}
figure {{ margin: 0; }} figure img {{ width: 256px; image-rendering: pixelated; border: 1px solid #999; background: #202020; }}
figcaption {{ font-size: 12px; color: #444; text-align: center; }}
.legend span {{ display: inline-block; width: 12px; height: 12px; vertical-align: middle; margin: 0 3px 0 10px; }}
.bar {{ display: inline-block; width: 200px; height: 12px; vertical-align: middle;
  background: linear-gradient(to right, #440154, #3b528b, #21918c, #5ec962, #fde725); }}
ul.fail {{ color: #b00; }}
</style></head><body>
<h1>glraster check <span class="verdict {verdict}">{verdict}</span></h1>
<div class="meta">backend <b>{e(result.backend)}</b> &middot; {e(result.renderer)} &middot;
GL {e(result.gl_version)} &middot; method <b>{e(result.method)}</b> &middot; {n_ok}/{len(result.scenes)} scenes pass &middot;
{result.seconds:.1f} s</div>
{_rules_html(result, e)}
<p class="legend">Error heatmap: error / tolerance
<span class="bar" style="width:200px;margin-left:6px"></span> 1e-3 &rarr; 1,
<span style="background:#f00"></span>above 1 (failure).
Coverage: <span style="background:#6e6e6e"></span>both
<span style="background:#286eff"></span>reference only
<span style="background:#ff8c00"></span>GPU only
<span style="background:#ffe600"></span>accepted (edge band / depth tie)
<span style="background:#f00"></span>different triangle.</p>
"""]
        if fig:
            parts.append(f'<img src="img/{fig}" alt="worst error/tolerance per scene" '
                         f'style="max-width:100%">')
        parts.append("<h2>Scenes</h2><table><tr><th class=l>scene</th><th>HxW</th>"
                     "<th>samples</th><th>triangles</th><th>covered</th>"
                     "<th>coverage mismatches</th>"
                     "<th>id mismatches</th><th>persp err/tol</th><th>screen err/tol</th>"
                     "<th>depth err/tol</th><th>golden</th><th>s</th><th>status</th></tr>")
        for s in result.scenes:
            rep = s.report
            h, w = s.resolution

            def r(n):
                return f"{rep.values[n].worst_ratio:.3f}" if rep and n in rep.values else "-"
            gold = "-" if s.golden is None else ("bit-exact" if s.golden.ok else "DIFFERS")
            status = s.status.upper() + (f" (waived {sum(s.waived.values())} px)"
                                         if s.waived else "")
            parts.append(
                f'<tr class="{"" if s.ok else "fail"}"><td class=l><a href="#{e(s.name)}">'
                f'{e(s.name)}</a></td><td>{h}x{w}</td><td>{e(s.sampling)}</td>'
                f'<td>{s.triangles}</td>'
                f'<td>{rep.covered_gpu if rep else "-"}</td>'
                f'<td>{rep.coverage_mismatch if rep else "-"}</td>'
                f'<td>{rep.tri_id_mismatch if rep else "-"}</td><td>{r("persp")}</td>'
                f'<td>{r("screen")}</td><td>{r("depth")}</td><td>{gold}</td>'
                f'<td>{s.seconds:.2f}</td><td class=l>{status}</td></tr>')
        parts.append("</table>")
        if result.mutants is not None:
            parts.append("<h2>Fault injection</h2><table><tr><th class=l>mutant</th>"
                         "<th class=l>fault</th><th class=l>caught by</th><th>scenes tried</th>"
                         "<th class=l>how</th></tr>")
            for m in result.mutants:
                who = m.caught_by or ("error: " + m.error if m.error else "ESCAPED")
                parts.append(f'<tr class="{"" if m.caught else "fail"}"><td class=l>'
                             f'{e(m.name)}</td><td class="l wrap">{e(m.fault)}</td><td class=l>'
                             f'{e(who)}</td><td>{m.scenes_tried}</td><td class="l wrap">'
                             f'{e(m.reason[:160])}</td></tr>')
            ctrl = ("no false alarm" if not result.control_failures
                    else "FALSE ALARM on " + ", ".join(result.control_failures))
            parts.append(f"</table><p>Control (real shaders through the mutant path): "
                         f"{e(ctrl)}</p>")
        parts.append("<h2>Details</h2>")
        for s in result.scenes:
            parts.append(self._scene_html(s))
        parts.append("</body></html>\n")
        index = self.dir / "index.html"
        with atomic_write(index) as tmp:
            Path(tmp).write_text("\n".join(parts), encoding="utf-8")
            old = self._publish()
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return index

    def _scene_html(self, s) -> str:
        e = html.escape
        h, w = s.resolution
        out = [f'<section class="scene" id="{e(s.name)}"><h3>{e(s.name)} '
               f'<span class="verdict {s.status.upper()}">{s.status.upper()}</span></h3>',
               f"<p>{e(s.description)} &mdash; {h}x{w} (HxW), {s.triangles} "
               f"triangle{'' if s.triangles == 1 else 's'}, samples {e(s.sampling)}</p>"]
        info = self.images.get(s.name)
        if info:
            y0, y1, x0, x1 = info["crop"]
            caps = {"gpu": "GPU (persp b0,b1,b2 as RGB)", "ref": "reference",
                    "error": "error / tolerance", "coverage": "coverage difference"}
            out.append('<div class="figs">')
            for kind, fname in info["files"].items():
                out.append(f'<figure><img src="img/{e(fname)}" alt="{e(s.name)} {kind}">'
                           f"<figcaption>{caps[kind]}</figcaption></figure>")
            out.append("</div>")
            note = f"pixels x {x0}..{x1 - 1}, y {y0}..{y1 - 1}"
            if info["factor"] > 1:
                note += f", reduced {info['factor']}x (max-pooled maps)"
            out.append(f'<p style="font-size:12px;color:#666">{note}</p>')
        if s.failures:
            out.append('<ul class="fail">' + "".join(f"<li>{e(f)}</li>" for f in s.failures)
                       + "".join(f"<li>explained by probe {e(n)}: {e(d)}</li>"
                                 for n, d in getattr(s, "explained_by", ()))
                       + "</ul>")
        rep = s.report
        if rep is not None:
            out.append("<table><tr><th class=l>output</th><th>pixels</th><th>max</th>"
                       "<th>p99.9</th><th>mean</th><th>&gt; tol</th><th>err/tol</th></tr>")
            for n, v in rep.values.items():
                out.append(f"<tr><td class=l>{n}</td><td>{v.pixels}</td><td>{v.max:.3e}</td>"
                           f"<td>{v.p999:.3e}</td><td>{v.mean:.3e}</td><td>{v.over_tolerance}"
                           f"</td><td>{v.worst_ratio:.3f}</td></tr>")
            out.append("</table>")
            out.append(f"<p>covered: GPU {rep.covered_gpu}, reference {rep.covered_ref}; "
                       f"coverage mismatches {rep.coverage_mismatch} "
                       f"(+{rep.coverage_mismatch_in_band} accepted); id mismatches "
                       f"{rep.tri_id_mismatch}</p>")
        if s.waived:
            out.append("<p>not judged (documented driver deviation, see the error model): "
                       f"{e(', '.join(f'{k}: {v} px' for k, v in s.waived.items()))}</p>")
        if s.golden is not None:
            out.append(f"<p>golden: {e(s.golden.message)}; max |GPU &minus; golden| "
                       f"{s.golden_max_error:.3g}</p>")
        if s.timings:
            out.append("<p style='font-size:12px;color:#666'>"
                       + ", ".join(f"{k} {v:.3f} s" for k, v in s.timings.items()) + "</p>")
        out.append("</section>")
        return "\n".join(out)


def _rules_html(result, e) -> str:
    """The detected rules and the probes (glraster.conformance.rules, probes) for the
    report header; empty when they were not run."""
    parts = []
    if getattr(result, "rules", None) is not None:
        parts.append(f'<div class="meta">{e(result.rules.summary())}</div>')
    probes = getattr(result, "probes", None) or []
    if probes:
        rows = "".join(
            f"<li><b>{e(p.name)}</b> {e(p.status.upper())}: {e(p.expectation)}"
            + (f" &rarr; {e(p.diagnosis)}" if p.diagnosis else "")
            + (f" (explains {e(', '.join(p.explains))})" if p.explains else "") + "</li>"
            for p in probes)
        cls = "" if all(p.ok for p in probes) else ' class="fail"'
        parts.append(f"<ul{cls}>{rows}</ul>")
    return "\n".join(parts)


def _pool_heat(ratio, compared, f):
    """Heatmap reduced by f with the worst ratio of each block."""
    r = _pool_max(np.where(compared, ratio, -1.0), f)
    return heat_rgb(np.maximum(r, 0), r >= 0)


def write_driver_matrix(directory, columns, nodes=(), missing=None, seconds=0.0) -> Path:
    """``directory/index.html``: the verdict of every scene on every driver (and method).

    columns : [(label, href of that run's report, CheckResult)], one column each; a cell
        links to ``href#scene``
    nodes   : [(driver, node name, GL up, renderer or error)], the fleet's actors
    missing : {driver: why no node ran it}
    Returns the path (written atomically).
    """
    e = html.escape
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    missing = missing or {}
    ok = bool(columns) and not missing and all(r.ok for _, _, r in columns)
    verdict = "PASS" if ok else "FAIL"
    names = []
    for _, _, r in columns:
        names += [s.name for s in r.scenes if s.name not in names]
    parts = [f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>glraster fleet check: {verdict}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 24px; background: #fafafa; color: #222; }}
table {{ border-collapse: collapse; font-size: 13px; margin: 8px 0 16px; }}
th, td {{ border: 1px solid #ccc; padding: 3px 8px; white-space: nowrap; }}
th {{ background: #eee; }} td.l {{ text-align: left; }}
td.pass {{ background: #dff0df; }} td.fail, td.error {{ background: #fde0e0; }}
td a {{ color: inherit; }}
.verdict {{ display: inline-block; padding: 2px 10px; border-radius: 4px; color: #fff; }}
.PASS {{ background: #2a7d2a; }} .FAIL {{ background: #c62828; }}
</style></head><body>
<h1>glraster fleet check <span class="verdict {verdict}">{verdict}</span></h1>
<p>{len(columns)} driver run(s), {len(names)} scenes, {seconds:.1f} s.</p>
<h2>Driver matrix</h2><table><tr><th>scene</th>"""]
    for label, href, r in columns:
        n_ok = sum(s.ok for s in r.scenes)
        parts.append(f'<th><a href="{e(href)}">{e(label)}</a><br><small>{e(r.renderer)}<br>'
                     f"{n_ok}/{len(r.scenes)} pass</small></th>")
    parts.append("</tr>")
    for name in names:
        parts.append(f"<tr><td class=l>{e(name)}</td>")
        for label, href, r in columns:
            s = next((s for s in r.scenes if s.name == name), None)
            if s is None:
                parts.append("<td>-</td>")
                continue
            tip = e("; ".join(s.failures)[:300])
            parts.append(f'<td class="{s.status}" title="{tip}"><a id="{e(label)}-{e(name)}" '
                         f'href="{e(href)}#{e(name)}">{s.status.upper()}</a></td>')
        parts.append("</tr>")
    parts.append("</table>")
    if missing:
        parts.append("<h2>Drivers not run</h2><ul>" + "".join(
            f"<li><b>{e(d)}</b>: {e(why)}</li>" for d, why in missing.items()) + "</ul>")
    if nodes:
        parts.append("<h2>Nodes</h2><table><tr><th>driver</th><th>node</th><th>GL</th>"
                     "<th>renderer / error</th></tr>")
        for driver, node, up, text in nodes:
            parts.append(f'<tr><td class=l>{e(driver)}</td><td class=l>{e(node)}</td>'
                         f'<td class="{"pass" if up else "fail"}">{"up" if up else "DOWN"}</td>'
                         f"<td class=l>{e(text)}</td></tr>")
        parts.append("</table>")
    parts.append("</body></html>\n")
    path = directory / "index.html"
    write_text(path, "\n".join(parts))
    return path
