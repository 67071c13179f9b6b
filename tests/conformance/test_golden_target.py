"""`glraster golden update` writes only where it was told or to the checkout it runs in:
never into an installed package's goldens, nor into another checkout's."""

from __future__ import annotations

import pytest

from glraster.cli import build_parser, exit_codes, main
from glraster.conformance import golden_folder


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """glraster imported from site-packages, its goldens inside the package."""
    package = tmp_path / "site-packages" / "glraster"
    (package / "golden").mkdir(parents=True)
    monkeypatch.setattr(golden_folder, "PACKAGE", package)
    monkeypatch.delenv("GLRASTER_GOLDEN_DIR", raising=False)
    return package


@pytest.fixture
def checkout(tmp_path, monkeypatch):
    """glraster imported from a source checkout with golden/ at its top."""
    package = tmp_path / "checkout-a" / "glraster"
    package.mkdir(parents=True)
    (package.parent / "golden").mkdir()
    monkeypatch.setattr(golden_folder, "PACKAGE", package)
    monkeypatch.delenv("GLRASTER_GOLDEN_DIR", raising=False)
    return package.parent


def test_update_refuses_the_installed_package_folder(installed, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["golden", "update", "basic_triangle"]) == exit_codes.USAGE
    err = capsys.readouterr().err
    target = installed / "golden"
    assert err == (f"glraster golden: error: argument --dir: not writing goldens to {target}: "
                   f"it is the copy "
                   f"installed inside the glraster package ({target}); pass --dir {target} "
                   "to write there anyway, or --dir DIR for another folder\n")
    assert list(target.iterdir()) == []


def test_update_refuses_another_checkout(checkout, tmp_path, monkeypatch, capsys):
    elsewhere = tmp_path / "checkout-b"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["golden", "update", "basic_triangle"]) == exit_codes.USAGE
    err = capsys.readouterr().err
    assert f"the golden folder of the glraster source tree at {checkout}" in err
    assert f"the current directory {elsewhere.resolve()} is not in that tree" in err
    assert list((checkout / "golden").iterdir()) == []


def test_update_may_write_inside_its_own_checkout_or_where_told(checkout, tmp_path,
                                                                 monkeypatch):
    assert golden_folder.unsafe_default(cwd=checkout) is None
    assert golden_folder.unsafe_default(cwd=checkout / "glraster") is None
    assert golden_folder.unsafe_default(directory=tmp_path / "x", cwd=tmp_path) is None
    monkeypatch.setenv("GLRASTER_GOLDEN_DIR", str(tmp_path / "y"))
    assert golden_folder.unsafe_default(cwd=tmp_path) is None


def test_help_names_the_folder_in_use_and_the_rule(installed, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["golden", "update", "--help"])
    out = capsys.readouterr().out
    text = " ".join(out.split())
    # (argparse wraps long paths at their hyphens: compare without whitespace)
    assert f"here:{installed / 'golden'}" in "".join(out.split())
    assert "never into an installed package, nor another checkout" in text
