# `make run` and `make test` each set everything up on a fresh machine (idempotent, fast the
# second time), then run the main job / the test suite.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
EXTRAS ?= dev,agents,gym,video,mujoco
STAMP := $(VENV)/.jaxnat-installed

.PHONY: setup data run test bench clean

setup: $(STAMP) data

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	$(PY) -m pip install -q --disable-pip-version-check -e '.[$(EXTRAS)]'
	@touch $@

data:
	@bash scripts/install_data.sh

run: setup
	$(PY) -m jaxnat.demo

test: setup
	JAX_PLATFORMS=cpu $(PY) -m pytest -q -n 2

bench: setup
	$(PY) bench/classify_throughput.py

clean:
	rm -rf $(VENV) out .pytest_cache
