"""`glraster info`: what OpenGL driver glraster would use here."""

from __future__ import annotations

import json
import sys

from glraster.cli import exit_codes
from glraster.cli.commands import add_backend_argument


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "info", help="print the OpenGL backend, renderer, GL version and limits",
        description="Create a headless context and print backend, renderer, vendor, GL "
                    "version, subpixel bits (GL_SUBPIXEL_BITS), maximum render size and "
                    "which backends work on this machine.")
    add_backend_argument(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=run)


def gather(backend=None) -> dict:
    """Driver facts for ``backend`` as a dict (raises BackendUnavailable)."""
    from glraster.gpu.backends import available_backends
    from glraster.gpu.context import Context

    ctx = Context(backend=backend)
    try:
        with ctx:
            max_samples = ctx.mgl.info.get("GL_MAX_SAMPLES")
        facts = {
            "backend": ctx.backend,
            "renderer": ctx.renderer,
            "vendor": ctx.vendor,
            "gl_version": ctx.gl_version,
            "subpixel_bits": ctx.subpixel_bits,
            "max_texture_size": ctx.max_texture_size,
            "max_samples": max_samples,
            "fill_rule_modeled": ctx.is_llvmpipe,
        }
    finally:
        ctx.release()
    facts["available_backends"] = available_backends()
    return facts


def run(args) -> int:
    from glraster.errors import BackendUnavailable

    try:
        facts = gather(args.backend)
    except (BackendUnavailable, ValueError) as exc:
        print(f"glraster info: {exc}", file=sys.stderr)
        return exit_codes.NO_BACKEND
    if args.json:
        print(json.dumps(facts, indent=2))
        return exit_codes.OK
    labels = {"backend": "backend", "renderer": "renderer", "vendor": "vendor",
              "gl_version": "GL version",
              "subpixel_bits": "subpixel bits", "max_texture_size": "max render size",
              "max_samples": "max MSAA samples",
              "fill_rule_modeled": "fill rule modeled exactly",
              "available_backends": "working backends"}
    for key, label in labels.items():
        value = facts[key]
        if isinstance(value, list):
            value = ", ".join(value) or "none"
        elif isinstance(value, bool):
            value = "yes (llvmpipe)" if value else "no (edge band used)"
        print(f"{label + ':':<27}{value}")
    return exit_codes.OK
