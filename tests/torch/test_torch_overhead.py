"""The torch-overhead study (glraster/studies/torch_overhead.py) runs its short form: docs/performance.md quotes the long one
(tens of minutes on a shared machine). Both trees are this one here, so only the table's
shape is checked, never a timing."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_overhead_benchmark_runs_its_short_form(ctx, capsys):
    from glraster.studies import torch_overhead

    assert torch_overhead.main(["--before", str(REPO), "--sizes", "16", "--rounds", "1",
                                "--calls", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert [row.split(" | ")[0] for row in rows[1:]] == [
        "| rasterize", "| interpolate", "| texture", "| antialias"]
    assert all(len(row.split("|")) == 8 and "| 16² |" in row for row in rows[1:])
