"""nvdiffrast's public API, names and parameters, as its documentation lists them: the table
both front ends (glraster.torch, glraster.jax) are checked against.

The names, parameters and defaults below are written out from nvdiffrast's documentation,
the "PyTorch API reference" section of https://nvlabs.github.io/nvdiffrast/ (not from its
code). Each glraster callable must take the documented parameters first, in that order,
positional-or-keyword as documented, with the documented defaults; anything glraster adds
must come after them, keyword-only with a default, so that every call written for
nvdiffrast binds the same way.
"""

from __future__ import annotations

import inspect

__all__ = ["NVDIFFRAST_API", "REQUIRED", "signature_problems"]

REQUIRED = inspect.Parameter.empty

# name -> [(parameter, default or REQUIRED)], nvdiffrast's PyTorch API reference
NVDIFFRAST_API = {
    "RasterizeCudaContext": [("device", None)],
    "RasterizeGLContext": [("output_db", True), ("mode", "automatic"), ("device", None)],
    "RasterizeGLContext.set_context": [],
    "RasterizeGLContext.release_context": [],
    "rasterize": [("glctx", REQUIRED), ("pos", REQUIRED), ("tri", REQUIRED),
                  ("resolution", REQUIRED), ("ranges", None), ("grad_db", True)],
    "DepthPeeler": [("glctx", REQUIRED), ("pos", REQUIRED), ("tri", REQUIRED),
                    ("resolution", REQUIRED), ("ranges", None), ("grad_db", True)],
    "DepthPeeler.rasterize_next_layer": [],
    "interpolate": [("attr", REQUIRED), ("rast", REQUIRED), ("tri", REQUIRED),
                    ("rast_db", None), ("diff_attrs", None)],
    "texture": [("tex", REQUIRED), ("uv", REQUIRED), ("uv_da", None), ("mip_level_bias", None),
                ("mip", None), ("filter_mode", "auto"), ("boundary_mode", "wrap"),
                ("max_mip_level", None)],
    "texture_construct_mip": [("tex", REQUIRED), ("max_mip_level", None),
                              ("cube_mode", False)],
    "antialias": [("color", REQUIRED), ("rast", REQUIRED), ("pos", REQUIRED), ("tri", REQUIRED),
                  ("topology_hash", None), ("pos_gradient_boost", 1.0)],
    "antialias_construct_topology_hash": [("tri", REQUIRED)],
    "get_log_level": [],
    "set_log_level": [("level", REQUIRED)],
}


def signature_problems(module, name: str) -> list[str]:
    """What is wrong with ``module``'s ``name`` (a dotted path for methods) against
    :data:`NVDIFFRAST_API`: an empty list when it has nvdiffrast's parameters."""
    obj = module
    for part in name.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            return [f"{module.__name__} lacks nvdiffrast's {name}"]
    params = list(inspect.signature(obj).parameters.values())
    if "." in name:                     # a method: drop self
        if not params or params[0].name != "self":
            return [f"{name} is not a plain method"]
        params = params[1:]
    documented = NVDIFFRAST_API[name]
    head = [(p.name, p.default) for p in params[:len(documented)]]
    problems = [] if head == documented else [f"{name}: documented {documented}, "
                                              f"glraster has {head}"]
    problems += [f"{name}({p.name}) is {p.kind}" for p in params[:len(documented)]
                 if p.kind != inspect.Parameter.POSITIONAL_OR_KEYWORD]
    problems += [f"{name}: glraster's extra parameter {p.name} must be keyword-only with a "
                 f"default" for p in params[len(documented):]
                 if p.kind != inspect.Parameter.KEYWORD_ONLY or p.default is REQUIRED]
    return problems
