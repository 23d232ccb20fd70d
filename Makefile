# epoet: every target that needs the environment depends on `install`, so each command in the
# README works on a fresh machine that has only Python 3.11 and make.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install test train gallery bench bench-learning clean-venv

install: $(STAMP)

# Re-runs pip only when the dependency files change; a second `make install` is a no-op.
$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[dev]'
	touch $(STAMP)

test: install
	$(PY) -m pytest -q tests

# The main job (see README): one laptop-scale ePOET run, tracked in ./mlflow.db.
train: install
	$(PY) -m epoet

gallery: install
	$(PY) -m epoet.terrain terrain=cppn n=8 out=gallery

bench: install
	$(PY) bench/env_throughput.py
	$(PY) bench/rollout_throughput.py
	$(PY) bench/es_scaling.py
	$(PY) bench/sac_updates.py
	$(PY) bench/integrators.py
	$(PY) bench/epoet_iteration.py

# Learning per iteration and per second with each integrator (about 15 minutes).
bench-learning: install
	$(PY) bench/integrator_learning.py

clean-venv:
	rm -rf $(VENV)
