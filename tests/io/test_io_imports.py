"""glraster.io is a low layer: it imports nothing from glraster above types, validate,
errors and geometry (only those, itself and the version module)."""

import ast
from pathlib import Path

import glraster.io

ALLOWED = ("glraster.io", "glraster._version", "glraster.types", "glraster.validate",
           "glraster.errors", "glraster.geometry")


def test_io_imports_only_lower_layers():
    folder = Path(glraster.io.__file__).parent
    found = {}
    for path in sorted(folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else ["glraster.io"]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                if name == "glraster" or name.startswith("glraster."):
                    found.setdefault(name, []).append(path.name)
    assert found, "expected at least the version import"
    bad = {n: f for n, f in found.items()
           if not any(n == a or n.startswith(a + ".") for a in ALLOWED)}
    assert not bad, f"glraster.io imports higher layers: {bad}"
