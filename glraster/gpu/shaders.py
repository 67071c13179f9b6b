"""GLSL files: locating them, ``#include``, variants with ``#define``s, and compile errors.

The shaders live in ``shaders/`` at the top of the source tree; the wheel ships them as
``glraster/shaders``. Shared code lives in ``shaders/include/``.

``#include "name.glsl"`` (a line of its own) is resolved by this loader, since GLSL has no
include: relative to the including file's folder first, then to the ``shaders/`` root. The
file's text replaces the line, between ``#line`` directives that give every file its own
source-string number (GLSL 4.50 section 3.3: ``#line line source-string-number``), so the
driver's ``N:line`` messages are mapped back to ``file:line``. A file is included once per
shader (a second ``#include`` of it is an empty line), an include cycle or a missing file
is a :class:`ShaderCompileError` naming the including file and line. Only the top-level
file has a ``#version`` line; the includes are expanded textually before the GLSL
preprocessor runs, so an ``#include`` inside an inactive ``#ifdef`` is still read.

A variant is the expanded text with ``#define`` lines inserted after its ``#version``
line, followed by ``#line 2 0`` so that the driver's line numbers stay those of the file.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path

from glraster.errors import ShaderCompileError

_PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # glraster/


@functools.cache  # found once: every dispatch names its shader
def shader_dir() -> Path:
    """The folder holding the GLSL files (wheel install or source checkout)."""
    for candidate in (_PACKAGE_ROOT / "shaders", _PACKAGE_ROOT.parent / "shaders"):
        if (candidate / "raster" / "raster.vert").is_file():
            return candidate
    raise FileNotFoundError(f"glraster's shaders/ folder was not found next to {_PACKAGE_ROOT}")


@functools.lru_cache(maxsize=256)  # resolved once per name: every dispatch names its shader
def shader_path(name: str) -> Path:
    """Path of a shader file given by name (``"raster/raster.frag"``) or path."""
    path = Path(name)
    return path if path.is_absolute() or path.exists() else shader_dir() / name


@dataclass(frozen=True)
class ShaderSource:
    """One stage's GLSL with its includes expanded.

    text  : the source handed to the driver (``#version`` first, ``#line`` directives)
    files : the file of each source-string number (``files[0]`` is the top-level file)
    """

    text: str
    files: tuple[Path, ...]


_INCLUDE = re.compile(r'\s*#\s*include\s+"([^"]+)"\s*(//.*)?$')
_DIRECTIVE = re.compile(r"\s*#\s*include\b")


def _resolve(name: str, including: Path, lineno: int) -> Path:
    """The file ``#include "name"`` on line ``lineno`` of ``including`` names."""
    root = shader_dir()
    for folder in (including.parent, root):
        candidate = folder / name
        if candidate.is_file():
            return candidate.resolve()
    raise ShaderCompileError(f'{including}:{lineno}: #include "{name}": no such file '
                             f"(looked in {including.parent} and {root})")


def _expand(path: Path, stack: list[Path], files: list[Path], out: list[str]) -> None:
    """Append the lines of ``path`` to ``out``, includes expanded (``stack``: the resolved
    files being expanded, outermost first; ``files``: every file met so far, by number)."""
    number = len(files)
    files.append(path)
    stack.append(path.resolve())
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise ShaderCompileError(f"cannot read the shader {path}: {exc.strerror}") from None
    for lineno, line in enumerate(lines, 1):
        if number > 0 and line.lstrip().startswith("#version"):
            raise ShaderCompileError(f"{path}:{lineno}: an included file must not have a "
                                     "#version line (only the including shader has one)")
        if not _DIRECTIVE.match(line):
            out.append(line)
            continue
        match = _INCLUDE.match(line)
        if match is None:
            raise ShaderCompileError(f'{path}:{lineno}: write #include "file.glsl" (a quoted '
                                     f"name, alone on its line), got {line.strip()!r}")
        target = _resolve(match.group(1), path, lineno)
        if target in stack:
            chain = " -> ".join(str(p) for p in stack[stack.index(target):] + [target])
            raise ShaderCompileError(f"{path}:{lineno}: include cycle: {chain}")
        if target in (f.resolve() for f in files):
            out.append(f"// {match.group(1)}: already included")
            continue
        out.append(f"#line 1 {len(files)}")
        _expand(target, stack, files, out)
        out.append(f"#line {lineno + 1} {number}")
    stack.pop()


def load_source(path: str | Path, defines: dict[str, object] | None = None) -> ShaderSource:
    """The GLSL of file ``path`` with its includes expanded and ``defines`` inserted.

    Raises :class:`ShaderCompileError` for a missing file, an include cycle, a malformed
    ``#include`` or a file without a leading ``#version`` line.
    """
    files: list[Path] = []
    out: list[str] = []
    _expand(Path(path), [], files, out)
    return ShaderSource(with_defines("\n".join(out) + "\n", defines or {}), tuple(files))


def with_defines(source: str, defines: dict[str, object]) -> str:
    """``source`` with one ``#define NAME VALUE`` line per entry after its ``#version`` line."""
    lines = source.splitlines(keepends=True)
    if not lines or not lines[0].lstrip().startswith("#version"):
        raise ShaderCompileError("a glraster shader must start with a #version line")
    block = "".join(f"#define {k} {'' if v is None else v}\n" for k, v in sorted(defines.items()))
    return lines[0] + block + "#line 2 0\n" + "".join(lines[1:])


# Mesa: "0:12(5): error: ..."; NVIDIA: "0(12) : error ..."; AMD/ANGLE: "ERROR: 0:12: ...".
# The first number is the source-string number (see ShaderSource.files), the second the line.
_LOG_LINE = re.compile(r"(?:ERROR: )?(\d+)[:(](\d+)[):]?(?:\(\d+\))?\s*:?\s*(.*)")


def describe_compile_error(log: str, sources: dict[str, ShaderSource]) -> str:
    """Rewrite a driver's info log so that every message names ``file:line``.

    ``sources`` maps the stage names moderngl uses ("vertex_shader", "fragment_shader", ...)
    to the source of that stage.
    """
    stage = next((s for s in sources if s in log), None)
    files = sources[stage].files if stage else ()
    out = []
    for raw in log.splitlines():
        match = _LOG_LINE.match(raw.strip())
        number = int(match.group(1)) if match else -1
        if match and number < len(files):
            out.append(f"{files[number]}:{match.group(2)}: {match.group(3)}")
        elif raw.strip():
            out.append(raw.strip())
    return "\n".join(out)


def compile_program(mgl, vert: Path, frag: Path, defines: dict[str, object]):
    """Compile and link a program from two GLSL files with ``defines``.

    Raises :class:`ShaderCompileError` whose message names the failing file and line.
    """
    sources = {"vertex_shader": load_source(vert, defines),
               "fragment_shader": load_source(frag, defines)}
    try:
        return mgl.program(**{stage: s.text for stage, s in sources.items()})
    except Exception as exc:  # moderngl.Error carries the driver's info log
        message = describe_compile_error(str(exc), sources)
        raise ShaderCompileError(
            f"GLSL compile/link error in {vert}, {frag}:\n{message}") from None


def compile_compute(mgl, path: Path, defines: dict[str, object]):
    """Compile the compute shader of one GLSL file with ``defines``.

    Raises :class:`ShaderCompileError` whose message names the failing file and line.
    """
    source = load_source(path, defines)
    try:
        return mgl.compute_shader(source.text)
    except Exception as exc:  # moderngl.Error carries the driver's info log
        message = describe_compile_error(str(exc), {"compute_shader": source})
        raise ShaderCompileError(f"GLSL compile error in {path}:\n{message}") from None
