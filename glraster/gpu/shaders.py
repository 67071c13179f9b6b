"""GLSL files: locating them, building variants with ``#define``s, and compile errors.

The shaders live in ``shaders/`` at the top of the source tree; the wheel ships them as
``glraster/shaders``. A variant is the file with ``#define`` lines inserted after its
``#version`` line, followed by ``#line 2`` so that the driver's line numbers stay those of
the file. A compile error is re-raised as :class:`ShaderCompileError` naming the file and
line.
"""

from __future__ import annotations

import re
from pathlib import Path

from glraster.errors import ShaderCompileError

_PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # glraster/


def shader_dir() -> Path:
    """The folder holding the GLSL files (wheel install or source checkout)."""
    for candidate in (_PACKAGE_ROOT / "shaders", _PACKAGE_ROOT.parent / "shaders"):
        if (candidate / "raster" / "raster.vert").is_file():
            return candidate
    raise FileNotFoundError(f"glraster's shaders/ folder was not found next to {_PACKAGE_ROOT}")


def shader_path(name: str) -> Path:
    """Path of a shader file given by name (``"raster/raster.frag"``) or path."""
    path = Path(name)
    return path if path.is_absolute() or path.exists() else shader_dir() / name


def with_defines(source: str, defines: dict[str, object]) -> str:
    """``source`` with one ``#define NAME VALUE`` line per entry after its ``#version`` line."""
    lines = source.splitlines(keepends=True)
    if not lines or not lines[0].lstrip().startswith("#version"):
        raise ShaderCompileError("a glraster shader must start with a #version line")
    block = "".join(f"#define {k} {'' if v is None else v}\n" for k, v in sorted(defines.items()))
    return lines[0] + block + "#line 2\n" + "".join(lines[1:])


# Mesa: "0:12(5): error: ..."; NVIDIA: "0(12) : error ..."; AMD/ANGLE: "ERROR: 0:12: ...".
_LOG_LINE = re.compile(r"(?:ERROR: )?\d+[:(](\d+)[):]?(?:\(\d+\))?\s*:?\s*(.*)")


def describe_compile_error(log: str, files: dict[str, Path]) -> str:
    """Rewrite a driver's info log so that every message names ``file:line``.

    ``files`` maps the stage names moderngl uses ("vertex_shader", "fragment_shader", ...)
    to the file of that stage.
    """
    stage = next((s for s in files if s in log), None)
    path = files.get(stage) if stage else None
    out = []
    for raw in log.splitlines():
        match = _LOG_LINE.match(raw.strip())
        if match and path is not None:
            out.append(f"{path}:{match.group(1)}: {match.group(2)}")
        elif raw.strip():
            out.append(raw.strip())
    return "\n".join(out)


def compile_program(mgl, vert: Path, frag: Path, defines: dict[str, object]):
    """Compile and link a program from two GLSL files with ``defines``.

    Raises :class:`ShaderCompileError` whose message names the failing file and line.
    """
    sources = {"vertex_shader": vert, "fragment_shader": frag}
    texts = {stage: with_defines(Path(p).read_text(), defines) for stage, p in sources.items()}
    try:
        return mgl.program(**texts)
    except Exception as exc:  # moderngl.Error carries the driver's info log
        message = describe_compile_error(str(exc), sources)
        raise ShaderCompileError(
            f"GLSL compile/link error in {', '.join(str(p) for p in sources.values())}:\n{message}"
        ) from None
