# dqn_mine — targets a newcomer guesses. Everything runs inside a local virtualenv ($(VENV)).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# The CPU wheel of this torch lies on the dev/CI disk; on a GPU machine the same pin pulls the CUDA build.
TORCH  ?= torch==2.13.0
# The linter is pinned: a new ruff release must not turn a green tree red. Settings: ruff.toml.
RUFF   := ruff==0.17.6
PYTEST_ARGS ?=

.PHONY: install test test-fast lint train bench gpu-check clean

install: $(VENV)/.installed

$(VENV)/.installed: setup.cfg setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q "$(TORCH)"
	$(PY) -m pip install -q -e ".[test]"
	touch $@

test: install
	$(PY) -m pytest $(PYTEST_ARGS)

test-fast: install
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

lint: install
	$(PY) -m pip install -q "$(RUFF)"
	$(VENV)/bin/ruff check dqn_mine tests experiments

train: install
	$(PY) -m dqn_mine.train --preset smoke

bench: install
	$(PY) -m pip install -q -e ".[bench]"
	$(PY) -m dqn_mine.bench --out results/bench.md

# The CUDA check (docs/gpu-check.md): one command on a GPU machine, about 8 minutes, figures in
# results/gpu-check/. Uses the virtualenv when there is one, else python3 (a GPU image with torch).
# Without CUDA it says so in one line and exits 0.
GPU_PY ?= $(if $(wildcard $(PY)),$(PY),python3)
gpu-check:
	$(GPU_PY) -m dqn_mine.bench.gpu_check --out results/gpu-check

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache

# -- experiments (experiments/grids/<GRID>.py; see `python -m experiments list`) ------------------
# SCALE=paper (the study's settings) | quick (about an hour on 2 CPU cores) | smoke (minutes)
# | cpu (the study's full-size task on 2 CPU cores, under 3 hours; exploration and scaling only)
# | auto (the default: paper on a CUDA machine, else quick).
# SEEDS=N runs seeds 0..N-1 (default: the grid's for the scale); JOBS=J runs at a time (never more
# busy processes than cores); CONFIGS="A B" runs only those configurations. Re-running the same
# command skips finished runs and resumes interrupted ones. Output: $(OUT)summary.csv, report.md
# and PNG plots.
GRID  ?= ablation
SCALE ?= auto
SEEDS ?=
CONFIGS ?=
JOBS  ?= 1
OUT   ?= results/$(GRID)/

.PHONY: sweep ablation

sweep: install
	$(PY) -m pip install -q -e ".[plot]"
	$(PY) -m experiments run $(GRID) --scale $(SCALE) --out $(OUT) --jobs $(JOBS) \
		$(if $(SEEDS),--seeds $(SEEDS)) $(if $(CONFIGS),--configs $(CONFIGS))

ablation:
	$(MAKE) sweep GRID=ablation
