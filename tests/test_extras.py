"""Importing a front end whose optional dependency is missing names the pip extra that
installs it (a user following the docs types ``import glraster.torch as dr`` first)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from glraster.errors import needs_extra

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("package, module, extra", [
    ("glraster.torch", "torch", "torch"),
    ("glraster.jax", "jax", "jax"),
])
def test_a_front_end_without_its_framework_names_the_extra(tmp_path, package, module, extra):
    # a stub package that cannot be imported stands for the framework not being installed
    stub = tmp_path / module
    stub.mkdir()
    (stub / "__init__.py").write_text(f"raise ModuleNotFoundError(\"No module named "
                                      f"'{module}'\", name='{module}')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    code = (f"try:\n    import {package}\nexcept ModuleNotFoundError as exc:\n"
            f"    print(exc.name, '|', exc)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == (f"{module} | {package} needs {module}: "
                                     f"pip install 'glraster[{extra}]'")


def test_a_module_no_extra_brings_is_left_as_it_is():
    missing = ModuleNotFoundError("No module named 'nosuchthing'", name="nosuchthing")
    assert needs_extra("glraster.torch", missing) is missing
    optax = needs_extra("glraster.jax", ModuleNotFoundError(name="optax.contrib"))
    assert str(optax) == "glraster.jax needs optax.contrib: pip install 'glraster[jax]'"
    assert optax.name == "optax.contrib"
