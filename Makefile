# The two commands: `make demo` and `make test`. Both set everything up first.
VENV   ?= .venv
PYTHON ?= python3
PY     := $(VENV)/bin/python

.PHONY: demo test setup system-deps bench clean

demo: setup
	$(VENV)/bin/glraster demo

# Import contracts first (pyproject.toml's [tool.importlinter]), then the tests; on a
# machine without Mesa, `$(PY) -m pytest -m "not gl"` runs the CPU half.
test: setup
	$(VENV)/bin/lint-imports --no-cache --no-logo
	$(PY) -m pytest -q

bench: setup
	$(VENV)/bin/glraster bench

setup: system-deps $(VENV)/.installed

# Mesa's EGL and OSMesa libraries (and python3's venv), installed through apt only when missing.
system-deps:
	@PYTHON=$(PYTHON) bash scripts/install-system-deps.sh

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,mesh,torch,service,ray,jax]'
	touch $@

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache
