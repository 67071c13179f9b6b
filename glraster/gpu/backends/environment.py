"""The environment variables that decide which OpenGL driver a backend gets, and advice.

Mesa, libglvnd, glcontext and the dynamic loader read these variables when a context is
made; a wrong value makes context creation fail (or, inside some driver libraries, crash:
see :mod:`glraster.gpu.backends.probe`). When no context can be made, :func:`advice` names
the variables that are set, what each does and what to do, so that the error points at a
typo (``GALLIUM_DRIVER=llvmpip``) instead of at installing libraries that are installed.
"""

from __future__ import annotations

import difflib
import os
import re

# What each variable does (shown in errors and in docs/drivers.md).
VARIABLES = {
    "GALLIUM_DRIVER": "picks Mesa's Gallium driver",
    "MESA_LOADER_DRIVER_OVERRIDE": "picks the DRI driver Mesa's loader opens",
    "LIBGL_ALWAYS_SOFTWARE": "asks Mesa for its software rasterizer",
    "MESA_GL_VERSION_OVERRIDE": "changes the OpenGL version Mesa reports",
    "MESA_GLSL_VERSION_OVERRIDE": "changes the GLSL version Mesa reports",
    "LIBGL_DRIVERS_PATH": "is where Mesa looks for its DRI drivers",
    "GLCONTEXT_DEVICE_INDEX": "picks the EGL device glcontext opens",
    "__EGL_VENDOR_LIBRARY_FILENAMES": "lists the EGL vendor libraries libglvnd loads",
    "__EGL_VENDOR_LIBRARY_DIRS": "is where libglvnd looks for EGL vendor libraries",
    "EGL_PLATFORM": "picks Mesa's EGL platform",
    "LD_LIBRARY_PATH": "puts libraries before the system's",
    "LD_PRELOAD": "loads libraries into every process",
}

# Variables whose value is part of the environment a backend verdict is cached for: the
# ones above and every variable of these families (driver options such as LP_NUM_THREADS).
PREFIXES = ("MESA_", "GALLIUM_", "LIBGL_", "EGL_", "__EGL_", "__GLX_", "GLCONTEXT_", "LP_",
            "SOFTPIPE_", "ZINK_", "VK_", "DRI_", "NOUVEAU_", "RADV_", "AMD_", "INTEL_")
OTHER_KEYS = ("LD_LIBRARY_PATH", "LD_PRELOAD", "DISPLAY", "WAYLAND_DISPLAY",
              "__NV_PRIME_RENDER_OFFLOAD", "CUDA_VISIBLE_DEVICES")

# Gallium drivers of Mesa 22-25 (for "did you mean"); the software ones work everywhere.
GALLIUM_DRIVERS = ("llvmpipe", "softpipe", "zink", "virpipe", "d3d12", "swr", "iris",
                   "crocus", "radeonsi", "r600", "r300", "nouveau", "i915", "svga",
                   "asahi", "freedreno", "panfrost", "lima", "v3d", "vc4", "etnaviv")
SOFTWARE_DRIVERS = ("llvmpipe", "softpipe")

DRI_DEVICES = "/dev/dri"


def environment_key(environ=None) -> tuple:
    """The (name, value) pairs of every variable that can change which driver a context
    gets, sorted: what a probe verdict is cached under (with the library files)."""
    environ = os.environ if environ is None else environ
    names = [k for k in environ if k in VARIABLES or k in OTHER_KEYS or k.startswith(PREFIXES)]
    return tuple(sorted((k, environ[k]) for k in names))


def set_variables(environ=None) -> dict:
    """The variables of :data:`VARIABLES` that are set (name -> value)."""
    environ = os.environ if environ is None else environ
    return {k: environ[k] for k in VARIABLES if k in environ}


def dri_devices() -> list[str]:
    """The device nodes under /dev/dri (empty where there is none: no GPU is visible)."""
    try:
        return sorted(os.listdir(DRI_DEVICES))
    except OSError:
        return []


def _about(name: str, value: str) -> str:
    """What to do about one variable that is set, as a clause."""
    shown = f"{name}={value!r} (it {VARIABLES[name]})"
    if name == "GALLIUM_DRIVER":
        low = value.strip().lower()
        if low == "zink":
            return (f"{shown}: OSMesa cannot run zink (it crashes OSMesaCreateContextAttribs in "
                    "Mesa 22.3) and zink needs a Vulkan driver; unset it, or set "
                    "MESA_LOADER_DRIVER_OVERRIDE=zink, which EGL honours and OSMesa ignores")
        if low not in GALLIUM_DRIVERS:
            close = difflib.get_close_matches(low, GALLIUM_DRIVERS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            return (f"{shown}, and Mesa has no Gallium driver {value!r}{hint}: unset it or "
                    f"set one of its software drivers, {' or '.join(SOFTWARE_DRIVERS)}")
        if low not in SOFTWARE_DRIVERS:
            devices = dri_devices()
            seen = f"/dev/dri holds {', '.join(devices)}" if devices else "no /dev/dri"
            return (f"{shown}; {value!r} needs its GPU or host (this machine has {seen}): "
                    f"unset it or set {' or '.join(SOFTWARE_DRIVERS)}")
        return f"{shown}: unset it to let Mesa choose"
    if name == "MESA_GL_VERSION_OVERRIDE":
        match = re.match(r"\s*(\d+)\.(\d+)", value)
        if match and (int(match.group(1)), int(match.group(2))) < (3, 3):
            return (f"{shown}, below the OpenGL 3.3 glraster needs: unset it, or set 3.3 "
                    "(or 4.5) to test an older OpenGL")
        return f"{shown}: unset it to get the driver's own version"
    if name == "MESA_GLSL_VERSION_OVERRIDE":
        return (f"{shown}; glraster's shaders need GLSL 3.30 (4.50 for every method): "
                "unset it")
    if name == "GLCONTEXT_DEVICE_INDEX":
        devices = dri_devices()
        where = ("this machine has no /dev/dri, so EGL finds only Mesa's software device, "
                 "index 0" if not devices else f"/dev/dri holds {', '.join(devices)}")
        return f"{shown}; {where}: unset it or pick a device EGL lists"
    if name in ("LD_LIBRARY_PATH", "LD_PRELOAD"):
        return f"{shown}: check the libEGL / libOSMesa / Mesa drivers it brings"
    return f"{shown}: unset it to see whether it is the cause"


def advice(environ=None) -> str:
    """One sentence naming each driver variable that is set and what to do about it, or,
    when none is set, how to see Mesa's own reason ("" never: there is always a next step)."""
    variables = set_variables(environ)
    if not variables:
        return ("no variable that picks the driver is set; EGL_LOG_LEVEL=debug "
                "glraster info shows Mesa's own reason")
    return "the environment sets " + "; ".join(_about(k, v) for k, v in variables.items())
