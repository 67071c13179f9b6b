"""Fixtures shared by the glraster.torch tests."""

from __future__ import annotations

import pytest

from glraster import validate


@pytest.fixture
def scans(monkeypatch):
    """The names of the arrays validate.finite scanned for NaN / Inf (ran its test on), in
    order: what the finite memory skipped is absent."""
    names, ran = [], []
    test, finite = validate._all_finite, validate.finite
    monkeypatch.setattr(validate, "_all_finite", lambda out: ran.append(1) or test(out))

    def counting(name, arr, out):
        before = len(ran)
        try:
            return finite(name, arr, out)
        finally:
            if len(ran) > before:
                names.append(name)

    monkeypatch.setattr(validate, "finite", counting)
    return names
