"""The shader loader's #include: expansion, file:line in compile errors, cycles and missing
files; and the one GLSL triangle-id encoding against its Python twin."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster.diff import ids
from glraster.gpu.shaders import compile_compute, compile_program, load_source, shader_dir

VERT = "#version 450 core\nvoid main() { gl_Position = vec4(0.0); }\n"


def _write(folder, files: dict[str, str]):
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    return folder


def test_include_is_expanded_between_line_directives(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n#include "lib/a.glsl"\nvoid main() {}\n',
                      "lib/a.glsl": "float a() { return 1.0; }\n"})
    source = load_source(tmp_path / "main.frag", {"X": 2})
    assert source.files == (tmp_path / "main.frag", (tmp_path / "lib/a.glsl").resolve())
    assert source.text.splitlines() == [
        "#version 450 core", "#define X 2", "#line 2 0",
        "#line 1 1", "float a() { return 1.0; }", "#line 3 0", "void main() {}"]


def test_include_resolves_next_to_the_includer_then_in_the_shaders_root(tmp_path):
    _write(tmp_path, {"main.comp": '#version 450\n#include "include/triangle_id.glsl"\n'})
    assert load_source(tmp_path / "main.comp").files[1] == \
        (shader_dir() / "include" / "triangle_id.glsl").resolve()
    _write(tmp_path, {"include/triangle_id.glsl": "// a local file of that name wins\n"})
    assert load_source(tmp_path / "main.comp").files[1] == \
        (tmp_path / "include" / "triangle_id.glsl").resolve()


def test_a_file_included_twice_is_expanded_once(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n#include "a.glsl"\n#include "b.glsl"\n',
                      "a.glsl": '#include "common.glsl"\nfloat a() { return c(); }\n',
                      "b.glsl": '#include "common.glsl"\nfloat b() { return c(); }\n',
                      "common.glsl": "float c() { return 1.0; }\n"})
    source = load_source(tmp_path / "main.frag")
    assert source.text.count("float c()") == 1
    assert [f.name for f in source.files] == ["main.frag", "a.glsl", "common.glsl", "b.glsl"]


def test_an_include_cycle_is_an_error_naming_the_chain(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n#include "a.glsl"\n',
                      "a.glsl": '// a\n#include "b.glsl"\n', "b.glsl": '#include "a.glsl"\n'})
    with pytest.raises(gr.ShaderCompileError, match=r"b\.glsl:1: include cycle: "
                       r".*a\.glsl -> .*b\.glsl -> .*a\.glsl"):
        load_source(tmp_path / "main.frag")


def test_a_file_including_itself_is_a_cycle(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n\n#include "main.frag"\n'})
    with pytest.raises(gr.ShaderCompileError, match=r"main\.frag:3: include cycle"):
        load_source(tmp_path / "main.frag")


def test_a_missing_include_names_the_including_file_and_line(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n// x\n#include "nowhere.glsl"\n'})
    with pytest.raises(gr.ShaderCompileError,
                       match=r'main\.frag:3: #include "nowhere\.glsl": no such file'):
        load_source(tmp_path / "main.frag")


@pytest.mark.parametrize("line, why", [("#include <a.glsl>", "a quoted name"),
                                       ('#include "a.glsl" x', "a quoted name")])
def test_a_malformed_include_is_an_error(tmp_path, line, why):
    _write(tmp_path, {"main.frag": f"#version 450 core\n{line}\n", "a.glsl": "\n"})
    with pytest.raises(gr.ShaderCompileError, match=rf"main\.frag:2: .*{why}"):
        load_source(tmp_path / "main.frag")


def test_an_included_file_must_not_have_a_version_line(tmp_path):
    _write(tmp_path, {"main.frag": '#version 450 core\n#include "a.glsl"\n',
                      "a.glsl": "// lib\n#version 450 core\n"})
    with pytest.raises(gr.ShaderCompileError, match=r"a\.glsl:2: an included file must not"):
        load_source(tmp_path / "main.frag")


def test_a_compile_error_inside_an_include_names_that_file_and_line(ctx, tmp_path):
    _write(tmp_path, {"ok.vert": VERT,
                      "broken.frag": '#version 450 core\nout vec4 color;\n#include "lib.glsl"\n'
                                     "void main() { color = vec4(f()); }\n",
                      "lib.glsl": "// helpers\n\nfloat f() {\n  return 1.0 +;\n}\n"})
    with ctx, pytest.raises(gr.ShaderCompileError) as info:
        compile_program(ctx.mgl, tmp_path / "ok.vert", tmp_path / "broken.frag", {"D": 1})
    assert f"{(tmp_path / 'lib.glsl').resolve()}:4:" in str(info.value)


def test_a_compile_error_after_an_include_keeps_the_includers_line(ctx, tmp_path):
    _write(tmp_path, {"broken.comp": '#version 450\nlayout(local_size_x = 1) in;\n'
                                     '#include "lib.glsl"\n\nvoid main() { g( }\n',
                      "lib.glsl": "float g() {\n  return 1.0;\n}\n"})
    with ctx, pytest.raises(gr.ShaderCompileError) as info:
        compile_compute(ctx.mgl, tmp_path / "broken.comp", {})
    assert f"{tmp_path / 'broken.comp'}:5:" in str(info.value)


def test_defines_reach_the_included_files(ctx, tmp_path):
    _write(tmp_path, {"main.comp": "#version 450\nlayout(local_size_x = 1) in;\n"
                                   "layout(std430, binding = 0) buffer Out { float v[]; };\n"
                                   '#include "value.glsl"\nvoid main() { v[0] = VALUE_OF; }\n',
                      "value.glsl": "#ifdef HALF\n#define VALUE_OF 0.5\n#endif\n"})
    with ctx:
        program = compile_compute(ctx.mgl, tmp_path / "main.comp", {"HALF": None})
        out = ctx.mgl.buffer(reserve=4)
        try:
            out.bind_to_storage_buffer(0)
            program.run(1)
            assert np.frombuffer(out.read(), np.float32)[0] == 0.5
        finally:
            out.release()
            program.release()


def test_every_shipped_shader_expands(tmp_path):
    for path in sorted(shader_dir().rglob("*")):
        if path.suffix in (".vert", ".frag", ".comp"):
            source = load_source(path)
            assert "#include" not in source.text, path
            assert source.text.startswith("#version"), path


ROUND_TRIP = """#version 450
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { int index[]; };
layout(std430, binding = 1) writeonly buffer Enc { float encoded[]; };
layout(std430, binding = 2) readonly buffer Py { float python[]; };
layout(std430, binding = 3) writeonly buffer Dec { int decoded[]; };
uniform uint n;
#include "include/triangle_id.glsl"
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n) return;
    encoded[i] = encode_id(index[i] + 1);
    decoded[i] = decode_id(python[i]) - 1;
}
"""


def test_the_glsl_and_python_id_encodings_agree_bit_for_bit(ctx, tmp_path):
    """include/triangle_id.glsl against glraster.diff.ids, exactly (an integer encoding):
    ids around 2^24, where the two branches meet, and up to the largest finite one."""
    index = np.array([-1, 0, 1, 2**24 - 2, 2**24 - 1, 2**24, 2**24 + 1, 2**29, ids.MAX_ID - 1],
                     np.int32)
    _write(tmp_path, {"round_trip.comp": ROUND_TRIP})
    python = ids.encode_ids(index)
    n = len(index)
    with ctx:
        program = compile_compute(ctx.mgl, tmp_path / "round_trip.comp", {})
        buffers = [ctx.mgl.buffer(index.tobytes()), ctx.mgl.buffer(reserve=4 * n),
                   ctx.mgl.buffer(python.tobytes()), ctx.mgl.buffer(reserve=4 * n)]
        try:
            for k, b in enumerate(buffers):
                b.bind_to_storage_buffer(k)
            program["n"].value = n
            program.run(1)
            encoded = np.frombuffer(buffers[1].read(), np.float32)
            decoded = np.frombuffer(buffers[3].read(), np.int32)
        finally:
            for b in buffers:
                b.release()
            program.release()
    np.testing.assert_array_equal(encoded.view(np.uint32), python.view(np.uint32))
    np.testing.assert_array_equal(decoded, index)
    np.testing.assert_array_equal(ids.decode_ids(encoded), index)
