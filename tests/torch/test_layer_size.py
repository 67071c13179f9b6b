"""The torch layer's size, which docs/differentiable.md quotes against nvdiffrast's 561-line
``torch/ops.py``: the lines of ``glraster/torch/*.py`` as ``wc -l`` counts them (newlines),
fitting/ (the fits built on the layer) and the ``*baseline.py`` timing references aside.
No GL; prints the figure (``pytest -s``)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
NVDIFFRAST_OPS_LINES = 561   # nvdiffrast/torch/ops.py, the file the layer replaces


def torch_layer_lines() -> int:
    files = [p for p in (REPO / "glraster" / "torch").glob("*.py")
             if not p.name.endswith("baseline.py")]
    return sum(p.read_bytes().count(b"\n") for p in files)


def test_the_torch_layer_is_about_nvdiffrasts_ops_and_the_docs_say_how_much():
    lines = torch_layer_lines()
    quote = f"torch layer {lines} lines vs nvdiffrast ops.py {NVDIFFRAST_OPS_LINES}"
    print(quote)
    doc = re.sub(r"\s+", " ", (REPO / "docs" / "differentiable.md").read_text())
    assert quote in doc, f"docs/differentiable.md must quote {quote!r}"
    # a thin layer over the cores, not a second implementation: within 5% of the file
    # it replaces (it has float64, named errors, torch.compile and inference-mode support)
    assert lines < 1.05 * NVDIFFRAST_OPS_LINES
