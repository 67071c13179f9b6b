"""The fit-iterations-ab study (glraster/studies/fit_iterations_ab.py) runs its short form (docs/performance.md quotes the long
one): both trees are this one, so only the table's shape is checked, never a timing."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_fit_iterations_benchmark_runs_its_short_form(ctx, capsys, monkeypatch):
    script = REPO / "glraster" / "studies" / "fit_iterations_ab.py"
    monkeypatch.setattr(sys, "argv", [str(script), "--before", str(REPO), "--rounds", "1",
                                      "--iterations", "4", "--size", "16"])
    namespace = runpy.run_path(str(script))
    assert namespace["main"]() == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert [row.split(" | ")[0] for row in rows[1:]] == [
        "| cube 4x4", "| cube 16x16", "| pose 16²", "| texture mip=None, constant tex 16²"]
