"""The files that README's and docs/'s commands write, run from the repository root, are
ignored by git (goldens and docs figures, which those commands also write, are not)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# glraster options whose value is a file or folder the command writes
OUTPUT = re.compile(r"(?:^|\s)(?:-o|--output|--out|--png|--json|--junit|--html|--plot)"
                    r"[ =]([^\s`'\"]+)")
TRACKED_OUTPUTS = ("docs/figures",)   # `glraster fit --out docs/figures`: committed figures


def documented_outputs() -> set[str]:
    found = set()
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for line in doc.read_text().splitlines():
            if "glraster " not in line:
                continue
            for path in OUTPUT.findall(line):
                if "$" in path or path.startswith(("/", "<")) or path.isupper() \
                        or path.rstrip(".,;:)") in ("DIR", "FILE", "PATH", "OUT.exr"):
                    continue  # a placeholder, a CI variable or an absolute path
                path = path.rstrip(".,;:)")
                if not path.startswith(TRACKED_OUTPUTS):
                    found.add(path.replace("*", "1"))
    return found


def ignored(paths) -> set[str]:
    result = subprocess.run(["git", "check-ignore", "--no-index", *paths], cwd=REPO,
                            capture_output=True, text=True, timeout=60)
    return set(result.stdout.split())


@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(),
                    reason="needs git and the repository (an installed copy has neither)")
def test_files_the_documented_commands_write_are_ignored():
    outputs = documented_outputs()
    assert {"torus.exr", "torus.png", "out/junit.xml"} <= outputs  # the parser finds them
    missing = sorted(outputs - ignored(outputs))
    assert not missing, f"add to .gitignore: {missing}"
    keep = ["golden/basic_triangle.exr", "docs/figures/fit_cube.png"]
    assert not ignored(keep), "goldens and docs figures stay tracked"
