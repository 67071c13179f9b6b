"""`glraster info`: print the OpenGL backend, renderer, GL version and limits.

Create a headless context and print backend, renderer, vendor, GL version, the draw path
and methods that version allows, subpixel bits (GL_SUBPIXEL_BITS), maximum render size and
which backends work on this machine. Without a context: whether a library is missing (with
an install hint) or the driver's OpenGL is too old (which version it offers, which
glraster needs).
"""

from __future__ import annotations

import json
import sys

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument, add_command


def register(subparsers) -> None:
    p = add_command(subparsers, "info", __doc__)
    add_backend_argument(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--ray-resources", action="store_true",
                   help="print the Ray resources this node advertises, one driver:<name> per "
                        "driver whose GL comes up here (for `ray start --resources`)")
    p.set_defaults(func=run)


def gather(backend=None) -> dict:
    """Driver facts for ``backend`` as a dict (raises BackendUnavailable)."""
    from glraster.errors import GLVersionError
    from glraster.gpu import methods
    from glraster.gpu.backends import available_backends
    from glraster.gpu.backends.environment import set_variables
    from glraster.gpu.backends.current import version_text
    from glraster.gpu.context import Context

    ctx = Context(backend=backend)
    try:
        with ctx:
            max_samples = ctx.mgl.info.get("GL_MAX_SAMPLES")
        usable, unavailable = [], {}
        for name, m in methods.METHODS.items():
            try:
                methods.for_context(m, ctx)
                usable.append(name)
            except GLVersionError as exc:
                unavailable[name] = {"needs": version_text(exc.needed), "for": m.needs,
                                     "message": str(exc)}
        hw = methods.for_context("hw", ctx)
        facts = {
            "backend": ctx.backend,
            "renderer": ctx.renderer,
            "vendor": ctx.vendor,
            "gl_version": ctx.gl_version,
            "gl_version_number": ctx.gl_version_number,
            "driver_gl_version_number": ctx.driver_gl_version_number,
            "draw_path": ("vertex attributes (GL 3.3, shaders/raster33)" if hw.vertex_input
                          else "storage buffers (GL 4.5, shaders/raster)"),
            "methods": usable,
            "unavailable_methods": unavailable,
            "subpixel_bits": ctx.subpixel_bits,
            "max_texture_size": ctx.max_texture_size,
            "max_samples": max_samples,
            "fill_rule_modeled": ctx.is_llvmpipe,
        }
    finally:
        ctx.release()
    facts["available_backends"] = available_backends()
    facts["driver_variables"] = set_variables()
    return facts


def unavailable_lines(facts: dict) -> list[str]:
    """One line per OpenGL version a method lacks: "divw, solve4: driver offers GL 3.3;
    glraster needs 4.5 for shader storage buffers, GLSL 4.50"."""
    from glraster.gpu.backends.current import version_text

    groups: dict = {}
    for name, why in facts["unavailable_methods"].items():
        groups.setdefault((why["needs"], why["for"]), []).append(name)
    offered = version_text(facts["gl_version_number"])
    capped = facts["gl_version_number"] < facts["driver_gl_version_number"]
    where = (f"the context is capped at GL {offered} (driver: "
             f"{version_text(facts['driver_gl_version_number'])})" if capped
             else f"driver offers GL {offered}")
    return [f"{', '.join(names)}: {where}; glraster needs {needs} for {what}"
            for (needs, what), names in groups.items()]


def version_number(text: str) -> tuple:
    """"3.3" -> (3, 3)."""
    return tuple(int(part) for part in text.split(".")[:2])


def run(args) -> int:
    from glraster.errors import BackendUnavailable, DriverTooOld, LibraryMissing

    if args.ray_resources:
        from glraster.cluster.runtime import node_resources

        resources = node_resources(backend=args.backend)
        print(json.dumps(resources))
        return exit_codes.OK if resources else exit_codes.NO_BACKEND

    try:
        facts = gather(args.backend)
    except DriverTooOld as exc:
        below = exc.offered is None or version_number(exc.offered) < version_number(exc.needed)
        lead = (f"driver offers GL {exc.offered or 'unknown'}; glraster needs {exc.needed} core "
                "for drawing (4.5 for every method): " if below else "")
        print(f"glraster info: {lead}{exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    except LibraryMissing as exc:
        print(f"glraster info: no OpenGL library: {exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    except (BackendUnavailable, ValueError) as exc:
        print(f"glraster info: {exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    if args.json:
        print(json.dumps(facts, indent=2))
        return exit_codes.OK
    facts = dict(facts, unavailable_methods=unavailable_lines(facts))
    labels = {"backend": "backend", "renderer": "renderer", "vendor": "vendor",
              "gl_version": "GL version", "draw_path": "draw path (method hw)",
              "methods": "methods", "unavailable_methods": "unavailable methods",
              "subpixel_bits": "subpixel bits", "max_texture_size": "max render size",
              "max_samples": "max MSAA samples",
              "fill_rule_modeled": "fill rule modeled exactly",
              "available_backends": "working backends",
              "driver_variables": "driver variables set"}
    for key, label in labels.items():
        value = facts[key]
        if key == "unavailable_methods":  # one line each
            value = ("\n" + " " * 27).join(value) or "none"
        elif isinstance(value, list):
            value = ", ".join(value) or "none"
        elif isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items()) or "none"
        elif isinstance(value, bool):
            value = ("yes (llvmpipe)" if value else
                     "no (edge band used; glraster check detects the driver's rule)")
        print(f"{label + ':':<27}{value}")
    return exit_codes.OK
